"""Derive the ground truth of a rendered dataset from its raw passes, store it, and drop the raw passes.

Per view (format version 2, lfusd.layout): the static keys go from Blender's ``passes.exr`` into
``gt.exr``, the motion keys of frame t (from the raw passes of t-1, t and t+1) into
``motion.exr``, each in its stored encoding (lfusd.data.store) and read back and compared bit for
bit with what was encoded before it counts (the pixels compared go into the view's record). Then, unless
the render kept them (``--keep-raw``), the raw passes of frame t are removed once nothing can
need them again: gt.exr of t is written, the motion of t-1, t and t+1 is current, and no frame
within two of t is still to come (inside an animated stage's range but not rendered, or any
frame of a static stage): when t+1 arrives, the motion of t is derived again, from the raw passes
of t-1, t and t+1. Frame t's forward keys need t+1 rendered (backward keys t-1); at the ends of the
rendered range they are masked invalid, as CONVENTIONS.md states. Each motion file is recorded
with the digests of the raw passes it came from (t-1, t, t+1; a removed file's digest stays in
its record), so a frame derived at the end of one range is derived again when its neighbour
arrives with the next: ranges rendered in pieces join without a seam. Format version 1 datasets
(motion.npz, raw passes kept) are derived as they were.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import threading
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from .. import cpu_account
from ..data import integrity, store
from ..processes import derivation_process_init, own_process_group
from ..data.dataset import open_dataset
from ..data.folder import atomic_write
from ..data.dataset import Dataset
from ..camera import View
from ..errors import LfusdError
from ..keys import CAST, KEYS, MOTION, STATIC, RAW, TRANSMISSIVE, stored
from ..layout import GEOMETRY, GT_FILE, MOTION_FILE, MOTION_FILE_V1, PASSES_EXR, RGB_EXR, RGB_PNG, frame_dir, view_key

log = logging.getLogger(__name__)

RUN = 8  # frames of one view per task: its Dataset decodes each raw pass once (the image-space route also the two at its ends)
REACH = 2  # a frame still to come within this many frames keeps a view's raw passes (see the module docstring)


def derive_view(ds: Dataset, frame: int, view: View) -> dict[str, np.ndarray]:
    """All motion keys of one view at one frame, from its raw passes and its neighbours'."""
    from ..errors import LfusdError
    from .motion import derive_motion
    from .visibility import memo_for

    frames = set(ds.record.frames)
    try:
        nxt = ds.raw_passes(frame + 1, view) if frame + 1 in frames else None
        prv = ds.raw_passes(frame - 1, view) if frame - 1 in frames else None
        occluders = {key: occluders_of(ds, g, view) for key, g, other in (("next", frame + 1, nxt), ("prev", frame - 1, prv))
                     if other is not None}
        occluders["here"] = occluders_of(ds, frame, view)
        cur = ds.raw_passes(frame, view)
        memo = memo_for((str(ds.root), ds.rig_name, tuple(view)), *cur.shape) if occluders["here"] is not None else None
        keys = derive_motion(cur, nxt, prv, baseline=ds.baseline, occluders=occluders, memo=memo)
        shutter = ds.record.settings.get("shutter")
        if shutter:  # --shutter: the blur key (lfusd.truth.blur)
            from .blur import blur_extent

            keys["blur"] = blur_extent(cur, nxt, prv, float(shutter))
        return keys
    except LfusdError as e:
        raise LfusdError(f"{ds.root} frame {frame} view {view[0]},{view[1]}: {e}") from None


def occluders_of(ds: Dataset, frame: int, view: View):
    """The rendered triangles of ``frame`` (its view's geometry.npz) for exact occlusion; None for a
    dataset rendered before lfusd wrote them (its occlusion is then the image-space test)."""
    from .visibility import Occluders

    path = frame_dir(ds.root, ds.rig_name, frame) / view_key(view) / GEOMETRY
    if not path.is_file():
        return None
    try:
        with cpu_account.phase("occluders"):
            return Occluders.load(path)
    except (OSError, ValueError, KeyError) as e:
        raise LfusdError(f"{path} is unreadable ({e}); rerun the render command to repair it") from None


def _passes_of(ds: Dataset, frame: int, view: View) -> dict[str, Path | None]:
    """The raw-pass files a derivation of (frame, view) reads: {"prev", "cur", "next"}; None where the
    dataset has no such frame (as :func:`derive_view` decides)."""
    frames = set(ds.record.frames)
    return {k: frame_dir(ds.root, ds.rig_name, g) / view_key(view) / PASSES_EXR if k == "cur" or g in frames else None
            for k, g in (("prev", frame - 1), ("cur", frame), ("next", frame + 1))}


def _wanted(ds: Dataset) -> tuple[str, ...]:
    """The keys the dataset's render asked for (every key for a format version 1 dataset)."""
    return ds.keys if ds.keys is not None else tuple(KEYS)


def wants_motion(ds: Dataset) -> bool:
    """Whether the dataset holds motion keys: rendered by render-video with motion keys asked for."""
    return ds.record.settings.motion and any(KEYS[k].stage == MOTION for k in _wanted(ds))


def write_motion(ds: Dataset, frame: int, view: View) -> Path:
    """Derive and store the motion keys of one view, atomically, and record them with their inputs.

    Format version 2: motion.exr holds the keys asked for, read back and compared bit for bit before it is
    recorded. Version 1: motion.npz (np.savez)."""
    return _write_motion(ds, frame, view)[0]


def _write_motion(ds: Dataset, frame: int, view: View) -> tuple[Path, int]:
    """:func:`write_motion`, and the pixels compared when reading it back."""
    inputs = integrity.motion_inputs(_passes_of(ds, frame, view))
    keys = derive_view(ds, frame, view)
    d = ds.view_dir(frame, view)
    if ds.version == 1:
        atomic_write(d / MOTION_FILE_V1, lambda tmp: np.savez(tmp, **keys), prefix=".motion.", suffix=".npz")
        integrity.record_motion(d, inputs)
        return d / MOTION_FILE_V1, 0
    keep = {k: v for k, v in keys.items() if k in _wanted(ds)}
    path, checked = store.write_checked(d / MOTION_FILE, keep)
    integrity.record_motion(d, inputs, {"checked": checked})
    log.debug("%s: motion keys read back as written (%d pixels compared)", path, checked)
    return path, checked


def write_static(ds: Dataset, frame: int, view: View) -> int:
    """Format version 2: store the static keys of one view from its raw passes (gt.exr, checked by
    reading it back), and its image as asked for (rgb.png for ``rgb`` alone, rgb.exr dropped when no
    image key is asked for). Returns the pixels compared."""
    d = ds.view_dir(frame, view)
    keep = stored(_wanted(ds))
    rec = integrity.read_record(d)
    add, remove, annotate, checked = {}, [], {}, 0
    if _pixels_unrecorded(rec):
        # recorded before chunk digests (integrity.file_entry): the neighbours' motion records name
        # these passes by their pixels (a re-render keeps them)
        annotate[PASSES_EXR] = {"pixels": integrity.pixels_digest(ds._raw(str(d)))}
    gt_keys = [k for k in keep if KEYS[k].file == GT_FILE and KEYS[k].stage in (RAW, STATIC, CAST)]
    if gt_keys and not integrity.present(rec, GT_FILE):
        raw = ds._raw(str(d))
        missing = [k for k in gt_keys if KEYS[k].stage == RAW and k not in raw]
        if missing:
            raise LfusdError(f"{d / PASSES_EXR} has no {missing[0]} pass; rerun the render command to repair the view")
        arrays = {k: raw[k] if KEYS[k].stage != CAST else CAST_KEYS[k](ds, frame, view, raw) for k in gt_keys}
        path, checked = store.write_checked(d / GT_FILE, arrays)
        add[GT_FILE] = {"checked": checked}
        log.debug("%s: static keys read back as written (%d pixels compared)", path, checked)
    if integrity.present(rec, RGB_EXR):
        if "rgb" in keep and not integrity.present(rec, RGB_PNG):
            from ..data.formats import write_png
            from ..data.passes import linear_to_srgb8, read_rgb

            with cpu_account.phase("read"):
                rgb = read_rgb(d / RGB_EXR)  # half: linear_to_srgb8 looks each value up
            with cpu_account.phase("encode"):
                write_png(d / RGB_PNG, linear_to_srgb8(rgb))
            add[RGB_PNG] = {}
        if "rgb_linear" not in keep:
            remove.append(RGB_EXR)
    if add or remove or annotate:
        integrity.record_files(d, add, tuple(remove), annotate)
        for name in remove:
            (d / name).unlink(missing_ok=True)
    return checked


def depth_behind(ds: Dataset, frame: int, view: View, raw: dict[str, np.ndarray]) -> np.ndarray:
    """The ``depth_behind`` key of one view: ``depth`` where the first surface is not transmissive, and
    where it is, the planar depth of the first non-transmissive triangle of the frame (geometry.npz, each
    triangle's material flags) on the ray through the pixel centre; inf where that ray leaves the scene."""
    from ..camera import ray_directions
    from .visibility import _scene

    import open3d as o3d

    out = np.array(raw["depth"], np.float32)
    transmissive = raw.get("transmissive")
    if transmissive is None or not transmissive.any():
        return out
    path = frame_dir(ds.root, ds.rig_name, frame) / view_key(view) / GEOMETRY
    try:
        with np.load(path) as z:
            vertices, triangles, flags = z["vertices"], z["triangles"], z["material"]
    except (OSError, KeyError, ValueError) as e:
        raise LfusdError(f"{path} holds no triangles with material flags ({e}); rerun 'lfusd render-video --materials' to repair it") from None
    with cpu_account.phase("layers"):
        scene = _scene(vertices, triangles[(flags & TRANSMISSIVE) == 0])
        v, u = np.nonzero(transmissive)
        cam = ds.camera(frame, view)  # through the view's lens, if it has one
        dirs = ray_directions(u.astype(np.float64), v.astype(np.float64), cam)  # camera-frame z = 1: the ray parameter is planar depth
        origins = np.broadcast_to(cam.world_to_cam()[1], dirs.shape)
        rays = np.ascontiguousarray(np.concatenate([origins, dirs], axis=-1), np.float32)
        out[v, u] = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    return out


CAST_KEYS = {"depth_behind": depth_behind}  # the ray-cast keys of lfusd.keys (stage CAST), by name


def _pixels_unrecorded(rec: dict) -> bool:
    """Whether a view's record names its raw passes without the digest of their pixels (recorded
    before lfusd.data.integrity.file_entry gave one): write_static adds it."""
    return integrity.present(rec, PASSES_EXR) and "pixels" not in rec["files"][PASSES_EXR]


def _static_missing(ds: Dataset, frame: int, view: View) -> bool:
    rec = integrity.read_record(ds.view_dir(frame, view))
    keep = stored(_wanted(ds))
    if _pixels_unrecorded(rec):
        return True
    gt = any(KEYS[k].file == GT_FILE for k in keep) and not integrity.present(rec, GT_FILE)
    image = integrity.present(rec, RGB_EXR) and ("rgb_linear" not in keep or ("rgb" in keep and not integrity.present(rec, RGB_PNG)))
    return gt or image


def derive_if_stale(ds: Dataset, frame: int, view: View) -> bool:
    """Write one view's ground truth (gt.exr) and motion unless current (as :func:`derive_dataset`
    decides); whether it wrote. The overlapped render calls it per view as soon as t-1, t and t+1
    are in place. A neighbour's record without the digest of its raw passes' pixels gets it first
    (with its static keys), so that the motion's record names them as :func:`derive_dataset` would
    (else it would be derived again at the end); a neighbour's static keys are otherwise left to
    its own call, which decodes its passes once for both."""
    wrote = False
    if ds.version >= 2:
        for g in (frame - 1, frame + 1, frame):
            passes = frame_dir(ds.root, ds.rig_name, g) / view_key(view) / PASSES_EXR
            if passes.is_file() and (_static_missing(ds, g, view) if g == frame else _pixels_unrecorded(integrity.read_record(passes.parent))):
                write_static(ds, g, view)
                wrote = wrote or g == frame
    if wants_motion(ds):
        d = ds.view_dir(frame, view)
        if integrity.motion_problem(d, integrity.motion_inputs(_passes_of(ds, frame, view))):
            _write_motion(ds, frame, view)
            wrote = True
    return wrote


def _derive_run(args: tuple[str, str, tuple[int, int], list[int], list[int]]) -> tuple[int, int]:
    from .visibility import forget_memos

    root, rig, view, static, motion = args
    ds = open_dataset(root, rig)
    checked = 0
    try:
        for f in sorted(set(static) | set(motion)):
            if f in static:
                checked += write_static(ds, f, view)
            if f in motion:
                checked += _write_motion(ds, f, view)[1]
    finally:
        # the next task of this process is another view's run, or this view's far away: one memo
        # at a time per process, not one per view in every process of the pool
        forget_memos()
    cpu_account.flush("derive")
    return len(set(static) | set(motion)), checked


def raw_needed(ds: Dataset, frame: int, view: View) -> str | None:
    """Why the raw passes of (frame, view) must stay (None: they may go; see the module docstring)."""
    if ds.version == 1 or ds.record.settings.keep_raw:
        return "the dataset keeps its raw passes"
    d = ds.view_dir(frame, view)
    rec = integrity.read_record(d)
    if any(KEYS[k].file == GT_FILE for k in stored(_wanted(ds))) and "checked" not in (rec or {}).get("files", {}).get(GT_FILE, {}):
        return f"{GT_FILE} is not written"
    if not wants_motion(ds):
        return None
    complete = set(ds.frames)
    first_last = ds.record.settings.stage_frames  # None: a static stage, every frame can come
    for g in range(frame - REACH, frame + REACH + 1):
        if g in complete:
            if abs(g - frame) <= 1 and integrity.motion_problem(ds.view_dir(g, view), integrity.motion_inputs(_passes_of(ds, g, view))):
                return f"the motion of frame {g} is not current"
        elif first_last is None or first_last[0] <= g <= first_last[1]:
            return f"frame {g} may still be rendered"
    return None


def drop_raw(ds: Dataset, frames, views) -> int:
    """Remove the raw passes that nothing needs any more among ``frames`` x ``views``; how many went."""
    if ds.version == 1 or ds.record.settings.keep_raw:
        return 0
    n = 0
    for f in frames:
        for v in views:
            d = frame_dir(ds.root, ds.rig_name, f) / view_key(v)
            if not (d / PASSES_EXR).is_file() or f not in ds.frames or raw_needed(ds, f, v):
                continue
            rec = integrity.read_record(d) or {"files": {}}
            raw = (PASSES_EXR,) + ((GEOMETRY,) if integrity.present(rec, GEOMETRY) else ())
            integrity.record_files(d, remove=raw)  # the record keeps their digests: the neighbours' inputs
            for name in raw:
                (d / name).unlink(missing_ok=True)
            n += 1
    return n


def drop_raw_near(root: str | Path, rigs: list[str], frames) -> int:
    """After an overlapped render (which derived view by view): remove the raw passes nothing needs
    any more around ``frames`` of ``rigs``, as :func:`derive_dataset` does at its end."""
    n = 0
    for rig in rigs:
        ds = open_dataset(root, rig)
        ds.refresh()
        near = sorted({g for f in frames for g in range(f - REACH, f + REACH + 1) if g in ds.frames})
        n += drop_raw(ds, near, ds.views)
    return n


def derive_dataset(
    root: str | Path,
    rigs: list[str] | None = None,
    frames: list[int] | None = None,
    workers: int = 1,
    overwrite: bool = False,
    progress=None,
    views: list[View] | None = None,
    lock: bool = True,
) -> int:
    """:func:`_derive_dataset` holding the dataset's lock (OUT/.lock: one writer per folder, so
    ``lfusd derive`` never writes into a folder a render is writing), after refusing links among
    the folders it writes into (lfusd.data.confined). ``lock=False``: the caller holds it (a render)."""
    if not lock:
        return _derive_dataset(root, rigs, frames, workers, overwrite, progress, views)
    from ..data.folder import output_lock

    with output_lock(root):
        return _derive_dataset(root, rigs, frames, workers, overwrite, progress, views, check_links=True)


def _derive_dataset(
    root: str | Path,
    rigs: list[str] | None = None,
    frames: list[int] | None = None,
    workers: int = 1,
    overwrite: bool = False,
    progress=None,
    views: list[View] | None = None,
    check_links: bool = False,
) -> int:
    """Write gt.exr and the motion keys of every (rig, frame, view) where they are not current (the
    motion of all of them with ``overwrite``), then remove the raw passes nothing needs any more.

    Current: present, matching the view's record, and (motion) derived from the raw passes now at
    t-1, t and t+1. The neighbours of the selected frames are checked too (a frame rendered next
    to them changes their motion). ``rigs``, ``frames`` and ``views`` default to every rig,
    completely rendered frame and view of the dataset. Returns how many views were written.
    """
    from ..data.dataset import open_datasets

    datasets = list(open_datasets(root) if rigs is None else [open_dataset(root, rig) for rig in rigs])
    if check_links:
        from ..data import confined

        confined.check_tree(root, [ds.rig_name for ds in datasets])
    for ds in datasets:
        ds.refresh()  # the frames complete now, not when the manifest was last written
    # lfusd derive (overwrite) derives every frame the manifest lists, and names what it cannot read
    everything = {ds.rig_name: list(ds.record.frames) if overwrite else ds.frames for ds in datasets}
    selected = {ds.rig_name: (set(everything[ds.rig_name] if frames is None else frames), ds.views if views is None else views)
                for ds in datasets}
    # First the static keys (and the pixels digests of new raw passes, which motion records name),
    # then the motion keys that are not current.
    todo = [(str(root), ds.rig_name, tuple(v), [f for f in sorted(selected[ds.rig_name][0]) if _static_missing(ds, f, v)], [])
            for ds in datasets if ds.version >= 2 for v in selected[ds.rig_name][1]]
    written = set()
    checked = _run(todo, workers, progress, written)
    todo = []
    for ds in datasets:
        wanted, vs = selected[ds.rig_name]
        if not wants_motion(ds):
            if overwrite:  # lfusd derive
                raise LfusdError(f"{root} holds no motion keys (rendered by 'lfusd render', or by render-video with --keys naming none); "
                                 "render a video with 'lfusd render-video'")
            continue
        # A neighbour's motion changes when a frame next to it arrives (its t+-1 keys were masked):
        # it is a candidate too, derived again only if its record says it came from other passes.
        candidates = sorted(wanted | {g for f in wanted for g in (f - 1, f + 1) if g in ds.frames})
        if overwrite and ds.version >= 2 and not ds.record.settings.keep_raw:
            gone = [f for f in sorted(wanted) for v in vs if not (ds.view_dir(f, v) / PASSES_EXR).is_file()]
            if gone:
                raise LfusdError(f"{root}: 'lfusd derive' derives the motion keys again from Blender's raw passes, which this dataset removed "
                                 f"once they were derived (frame {gone[0]}: rendered without --keep-raw); render it again with --keep-raw")
        for v in vs:
            # view_dir raises naming a view or frame the dataset lacks
            stale = [f for f in candidates if (overwrite and f in wanted)
                     or integrity.motion_problem(ds.view_dir(f, v), integrity.motion_inputs(_passes_of(ds, f, v)))]
            # Runs of frames of one view: consecutive frames share t+/-1 in the dataset's raw-pass cache.
            todo += [(str(root), ds.rig_name, tuple(v), [], stale[i : i + RUN]) for i in range(0, len(stale), RUN)]
    if todo:
        from .motion import announce_compile

        announce_compile()
    checked += _run(todo, workers, progress, written)
    # Raw passes go in this process, after every derivation: one view's removal depends on its
    # neighbours' motion, which other tasks write.
    dropped = 0
    for ds in datasets:
        wanted, vs = selected[ds.rig_name]
        near = sorted({g for f in wanted for g in range(f - REACH, f + REACH + 1) if g in ds.frames})
        dropped += drop_raw(ds, near, vs)
    if written or dropped:
        log.info("%s: ground truth written for %d views (read back and compared with what was encoded on %d pixels x keys), "
                 "raw passes removed from %d", root, len(written), checked, dropped)
    return len(written)


def _run(todo: list, workers: int, progress, written: set) -> int:
    """Run derivation tasks here or in a pool of ``workers`` processes; the pixels compared.
    ``written`` collects the (rig, view, frame) written."""
    checked = 0
    for item in todo:
        written.update((item[1], item[2], f) for f in set(item[3]) | set(item[4]))
    if workers <= 1 or len(todo) <= 1:
        for item in todo:
            n, c = _derive_run(item)
            checked += c
            progress and progress(n)
        return checked
    # spawn, not fork: forking after numba's or BLAS's threads have run can kill the child.
    # The pool's processes are started (in submit) while this process ignores Ctrl-C, a
    # disposition they inherit through exec (a blocked mask is not: measured) and Python keeps:
    # a Ctrl-C to the process group while they start up must not kill them with a traceback.
    # (Issue 29: ignoring loses a Ctrl-C sent meanwhile, so where it can the pool starts in a
    # process group of its own instead, which a terminal's Ctrl-C does not reach.)
    main = threading.current_thread() is threading.main_thread()  # only it may set handlers
    pool = None
    try:
        with own_process_group() as apart:  # a Ctrl-C held while they start is raised at its end
            handler = signal.signal(signal.SIGINT, signal.SIG_IGN) if main and not apart else None
            try:
                pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                                           initializer=derivation_process_init, initargs=(os.getpid(),))
                futures = [pool.submit(_derive_run, item) for item in todo]
            finally:
                if main and not apart:
                    signal.signal(signal.SIGINT, signal.SIG_DFL if handler is None else handler)
        for f in futures:
            n, c = f.result()
            checked += c
            progress and progress(n)
    except BaseException:
        # Interrupted or failed: stop the pool now rather than let it finish its queue (or, still
        # starting, read what this process is about to remove).
        for p in list((getattr(pool, "_processes", None) or {}).values()):
            p.terminate()
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown(wait=True)
    return checked
