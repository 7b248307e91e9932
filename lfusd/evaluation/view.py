"""`lfusd view OUT`: a dataset in the rerun viewer (rerun-sdk), or saved as a ``.rrd`` recording.

Entity paths, per rig ``<rig>`` (world frame: lfusd's, Z-up, metres; timeline ``frame``: the
dataset's frame numbers)::

    world/<rig>/cam_<RR>_<CC>            Transform3D (the view's cam_to_world) + Pinhole (K, OpenCV RDF)
    world/<rig>/cam_<RR>_<CC>/rgb        Image: the view's sRGB image
    world/<rig>/cam_<RC>_<CC>/depth      DepthImage (centre view; metres)
    world/<rig>/cam_<RC>_<CC>/flow       Image: forward optical flow, Middlebury colour wheel (centre view)
    world/<rig>/cam_<RC>_<CC>/instance   SegmentationImage of instance ids (centre view)
    world/<rig>/cam_<RC>_<CC>/semantic   SegmentationImage of class ids, labelled by the class table
    world/<rig>/points                   Points3D: the centre view's surface points (``position``) in their colours
    world/<rig>/scene_flow               Arrows3D: their scene flow to t+1 (where ``valid_fwd``)

Points and arrows are subsampled on a regular pixel grid to at most ``max_points`` /
``max_arrows``. Keys the dataset lacks (a still render has no motion) are left out. Reads the
dataset through :class:`lfusd.Dataset` only; rerun is imported when a recording starts.
"""

from __future__ import annotations

import logging
import math
import os
from pathlib import Path

import numpy as np

from ..errors import LfusdError

log = logging.getLogger(__name__)

TIMELINE = "frame"
MAX_POINTS = 20_000
MAX_ARROWS = 1_000


def entity(rig: str, view=None, leaf: str | None = None) -> str:
    """The entity path of a rig, one of its cameras, or something under a camera."""
    path = f"world/{rig}"
    if view is not None:
        path += f"/cam_{int(view[0]):02d}_{int(view[1]):02d}"
    return f"{path}/{leaf}" if leaf else path


def grid_step(height: int, width: int, budget: int) -> int:
    """The pixel stride that keeps a regular grid of an image within ``budget`` samples."""
    return max(1, math.ceil(math.sqrt(height * width / max(1, budget))))


def _read(ds, frame, view, key):
    try:
        return ds.read(frame, view, key)
    except (LfusdError, KeyError):  # KeyError: a reader (DatasetLike) that has no such key at all
        return None


def _rr():
    try:
        import rerun as rr
    except ImportError:
        raise LfusdError("lfusd view needs rerun-sdk: install it with 'pip install --no-deps rerun-sdk==0.41.0' "
                         "(scripts/setup.sh does)") from None
    return rr


def _spawn_viewer(rr, rec) -> None:
    """Start the rerun viewer for ``rec``: the one installed beside this Python (a virtual
    environment's bin/ need not be on PATH), or one line saying how to save a recording instead."""
    import sys

    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise LfusdError("no display to open the rerun viewer on (DISPLAY and WAYLAND_DISPLAY are unset); write a recording "
                         "with --save FILE.rrd and open it with 'rerun FILE.rrd' where a display is")
    exe = Path(sys.executable).with_name("rerun")
    try:
        rr.spawn(recording=rec, executable_path=str(exe) if exe.is_file() else None)
    except (RuntimeError, OSError) as e:
        raise LfusdError(f"cannot start the rerun viewer ({str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__}); "
                         "write a recording with --save FILE.rrd and open it with 'rerun FILE.rrd' where a display is") from None


def log_dataset(rec, ds, rig: str, frames: list[int], views: list, max_points: int = MAX_POINTS, max_arrows: int = MAX_ARROWS) -> dict:
    """Log one rig of a dataset to rerun recording ``rec``; returns counts of what was logged."""
    from .preview import colormap, flow_to_color

    rr = _rr()
    centre = tuple(ds.rig.centre_view)
    K = np.asarray(ds.intrinsics(centre), float)
    w, h = ds.resolution
    classes = list(getattr(ds, "classes", []) or [])  # class id = index (0 = unlabelled)
    rec.log(entity(rig, centre, "semantic"), rr.AnnotationContext([(i, str(name)) for i, name in enumerate(classes)]), static=True)
    counts = {"frames": 0, "images": 0, "points": 0, "arrows": 0}
    for t in frames:
        rec.set_time(TIMELINE, sequence=int(t))
        for v in views:
            c2w = np.asarray(ds.cam_to_world(t, v), float)
            rec.log(entity(rig, v), rr.Transform3D(translation=c2w[:3, 3], mat3x3=c2w[:3, :3]))
            rec.log(entity(rig, v), rr.Pinhole(image_from_camera=K, resolution=[w, h], camera_xyz=rr.ViewCoordinates.RDF))
            rec.log(entity(rig, v, "rgb"), rr.Image(ds.read(t, v, "rgb")))
            counts["images"] += 1
        if centre in views:
            rgb = ds.read(t, centre, "rgb")
            depth = _read(ds, t, centre, "depth")
            if depth is not None:
                rec.log(entity(rig, centre, "depth"), rr.DepthImage(np.where(np.isfinite(depth), depth, 0).astype(np.float32), meter=1.0))
            for key in ("instance", "semantic"):
                seg = _read(ds, t, centre, key)
                if seg is not None:
                    rec.log(entity(rig, centre, key), rr.SegmentationImage(np.asarray(seg).astype(np.uint16)))
            flow, valid = _read(ds, t, centre, "flow_fwd"), _read(ds, t, centre, "valid_fwd")
            if flow is not None and valid is not None and np.asarray(valid).any():
                rec.log(entity(rig, centre, "flow"), rr.Image(flow_to_color(flow, valid=np.asarray(valid, bool))))
            # camera effects (docs/CONVENTIONS.md), where the dataset has them
            noisy = _read(ds, t, centre, "rgb_noisy")
            if noisy is not None:
                rec.log(entity(rig, centre, "rgb_noisy"), rr.Image(noisy))
            masks = [_read(ds, t, centre, k) for k in ("transmissive", "mirror", "emissive")]
            if all(m is not None for m in masks):  # label 1 transmissive, 2 mirror-like, 4 emissive, summed
                rec.log(entity(rig, centre, "materials"), rr.SegmentationImage((masks[0] * 1 + masks[1] * 2 + masks[2] * 4).astype(np.uint16)))
            for key in ("blur", "coc"):
                px = _read(ds, t, centre, key)
                if px is not None:
                    rec.log(entity(rig, centre, key), rr.Image(colormap(px, vmin=0.0, valid=np.isfinite(px))))
            pos = _read(ds, t, centre, "position")
            if pos is not None:
                s = grid_step(h, w, max_points)
                p, col = pos[::s, ::s].reshape(-1, 3), rgb[::s, ::s].reshape(-1, 3)
                ok = np.all(np.isfinite(p), axis=-1)
                rec.log(entity(rig, None, "points"), rr.Points3D(p[ok], colors=col[ok]))
                counts["points"] += int(ok.sum())
                sf = _read(ds, t, centre, "scene_flow")
                if sf is not None and valid is not None:
                    s = grid_step(h, w, max_arrows)
                    p, f = pos[::s, ::s].reshape(-1, 3), sf[::s, ::s].reshape(-1, 3)
                    ok = np.asarray(valid, bool)[::s, ::s].reshape(-1) & np.all(np.isfinite(p), -1) & np.all(np.isfinite(f), -1)
                    if ok.any():  # none on the last frame: no t+1
                        rec.log(entity(rig, None, "scene_flow"), rr.Arrows3D(origins=p[ok], vectors=f[ok]))
                        counts["arrows"] += int(ok.sum())
        counts["frames"] += 1
    return counts


def view(out, save=None, rig: str | None = None, views=None, frames=None, every: int = 1,
         max_points: int = MAX_POINTS, max_arrows: int = MAX_ARROWS) -> dict:
    """Show dataset ``out`` in the rerun viewer, or with ``save`` write it to that ``.rrd`` file.

    ``rig``: one rig (default every rig); ``views``: (row, col) views to show (default all);
    ``frames``: frame numbers (default all complete frames); ``every``: keep every N-th of them.
    Returns what was logged per rig (frames, images, points, arrows).
    """
    from ..data.folder import open_datasets

    if every < 1:
        raise LfusdError(f"--every {every}: give a positive step (1 shows every frame)")
    if save is not None:
        save = Path(save)
        if save.suffix != ".rrd":
            raise LfusdError(f"--save {save}: a rerun recording ends in .rrd; name the file e.g. {save.with_suffix('.rrd').name}")
        if save.exists():
            raise LfusdError(f"--save {save} already exists; choose a new file or remove it first")
        if not save.parent.is_dir():
            raise LfusdError(f"--save {save}: folder {save.parent} does not exist; create it first")
    datasets = open_datasets(out, rig)
    plan = []
    for ds in datasets:
        fs = list(ds.frames) if frames is None else [f for f in frames if f in ds.frames]
        if frames is not None and not fs:
            raise LfusdError(f"none of the frames {frames[0]}..{frames[-1]} is rendered in rig {ds.rig_name} (it has "
                             f"{ds.frames[0] if ds.frames else '-'}..{ds.frames[-1] if ds.frames else '-'}); pick frames it has")
        if not fs:
            raise LfusdError(f"rig {ds.rig_name} of {out} has no completely rendered frame yet; finish its render first")
        vs = [tuple(v) for v in ds.views] if views is None else [tuple(v) for v in views]
        bad = [v for v in vs if v not in set(map(tuple, ds.views))]
        if bad:
            raise LfusdError(f"view {bad[0]} is not in rig {ds.rig_name}'s {ds.rig.rows}x{ds.rig.cols} grid; give row,col inside it")
        plan.append((ds, fs[::every], vs))
    rr = _rr()
    rec = rr.RecordingStream(f"lfusd {Path(out).resolve().name}")
    partial = None
    if save is not None:
        partial = save.with_name(f".{save.name}.partial-{os.getpid()}")
        rec.save(str(partial))
    else:
        _spawn_viewer(rr, rec)
    try:
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        result = {ds.rig_name: log_dataset(rec, ds, ds.rig_name, fs, vs, max_points, max_arrows) for ds, fs, vs in plan}
        try:
            rec.flush()
        except RuntimeError as e:  # the viewer went away (closed, or could not open a window)
            raise LfusdError(f"the rerun viewer did not take the recording ({str(e).strip()}); save it with --save FILE.rrd instead") from None
        rec.disconnect()
        log.info("logged %s", "; ".join(f"{rig}: {c}" for rig, c in result.items()))
        if partial is not None:
            partial.rename(save)  # the recording appears only when complete
    finally:
        if partial is not None and partial.exists():
            partial.unlink()
    return result
