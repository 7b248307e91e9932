"""`lfusd view OUT`: a dataset in the rerun viewer (rerun-sdk), or saved as a ``.rrd`` recording.

Entity paths, per rig ``<rig>`` (world frame: lfusd's, Z-up, metres; timeline ``frame``: the
dataset's frame numbers)::

    world/<rig>/cam_<RR>_<CC>            Transform3D (the view's cam_to_world) + Pinhole (K, OpenCV RDF)
    world/<rig>/cam_<RR>_<CC>/rgb        EncodedImage: the view's sRGB image, JPEG (Image, lossless, with ``lossless``)
    world/<rig>/cam_<RC>_<CC>/depth      DepthImage (centre view; metres)
    world/<rig>/cam_<RC>_<CC>/flow       Image: forward optical flow, Middlebury colour wheel (centre view)
    world/<rig>/cam_<RC>_<CC>/instance   SegmentationImage of instance ids (centre view)
    world/<rig>/cam_<RC>_<CC>/semantic   SegmentationImage of class ids, labelled by the class table
    world/<rig>/points                   Points3D: the centre view's surface points (``position``) in their colours
    world/<rig>/scene_flow               Arrows3D: their scene flow to t+1 (where ``valid_fwd`` and
                                         the point moves), drawn ``arrow_scale`` times its length
    world/<rig>/scene_flow_scale         TextDocument: that scale

Points and arrows are subsampled on a regular pixel grid to at most ``max_points`` /
``max_arrows``. Scene flow is millimetres to centimetres per frame in a scene of metres, so at
true length the arrows are invisible: by default (``arrow_scale`` None) one scale per rig, the same
at every frame, makes the 95th percentile of the moving arrows :data:`ARROW_SHARE` of the point
cloud's extent (rounded down to 1, 2 or 5 times a power of ten); points that do not move get no
arrow. The recording carries a layout (a blueprint): the 3D world beside the light-field grid of
each rig's images as the rig sees them, the timeline open. Keys the dataset lacks (a still
render has no motion) are left out. Reads the dataset through :class:`lfusd.Dataset` only; rerun
is imported when a recording starts.
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
ARROW_SHARE = 0.03  # the default arrow scale draws the 95th percentile moving arrow this share of the scene's extent
STILL_M = 1e-6  # m per frame: a point moving less gets no arrow (the stored scene flow's step is 2^-17 m)
JPEG_QUALITY = 95


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


def nice_scale(x: float) -> float:
    """``x`` rounded down to 1, 2 or 5 times a power of ten (a scale a reader can say)."""
    if not (x > 0 and math.isfinite(x)):
        return 1.0
    p = 10.0 ** math.floor(math.log10(x))
    return max(m * p for m in (1.0, 2.0, 5.0) if m * p <= x * (1 + 1e-12))


def auto_arrow_scale(vectors: list[np.ndarray], points: list[np.ndarray]) -> float:
    """The default arrow scale of a rig (see the module docstring): 1 when nothing moves."""
    moving = np.concatenate([np.linalg.norm(v, axis=-1) for v in vectors]) if vectors else np.zeros(0)
    pts = np.concatenate(points) if points else np.zeros((0, 3))
    if not moving.size or not len(pts):
        return 1.0
    extent = float(np.linalg.norm(pts.max(0) - pts.min(0)))
    return nice_scale(ARROW_SHARE * extent / float(np.percentile(moving, 95)))


def layout(rigs: dict):
    """The recording's blueprint: the 3D world beside each rig's light-field grid (row-major, as
    the rig sees them), the timeline open. ``rigs``: {name: (rows, cols, views shown)}."""
    import rerun.blueprint as rrb

    grids = []
    for rig, (rows, cols, views) in rigs.items():
        shown = set(map(tuple, views))
        cells = [rrb.Spatial2DView(origin=entity(rig, (r, c)), contents=["$origin/rgb"], name=f"{rig} {r},{c}")
                 for r in range(rows) for c in range(cols) if (r, c) in shown]
        grids.append(rrb.Grid(contents=cells, grid_columns=cols, name=f"{rig} light field"))
    return rrb.Blueprint(rrb.Horizontal(rrb.Spatial3DView(origin="world", name="world"), *grids),
                         rrb.TimePanel(state="expanded"), collapse_panels=False)


def log_dataset(rec, ds, rig: str, frames: list[int], views: list, max_points: int = MAX_POINTS, max_arrows: int = MAX_ARROWS,
                arrow_scale: float | None = None, lossless: bool = False) -> dict:
    """Log one rig of a dataset to rerun recording ``rec``; returns counts of what was logged and
    the arrow scale used (``arrow_scale`` None: :func:`auto_arrow_scale`). ``lossless``: the
    images as raw pixels instead of JPEG."""
    from .preview import colormap, flow_to_color, lens_shift

    rr = _rr()
    centre = tuple(ds.rig.centre_view)
    K = np.asarray(ds.intrinsics(centre), float)
    w, h = ds.resolution
    classes = list(getattr(ds, "classes", []) or [])  # class id = index (0 = unlabelled)
    rec.log(entity(rig, centre, "semantic"), rr.AnnotationContext([(i, str(name)) for i, name in enumerate(classes)]), static=True)
    counts = {"frames": 0, "images": 0, "points": 0, "arrows": 0}
    arrows: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # frame -> (origins, scene flow): logged once the scale is known
    clouds = []
    for t in frames:
        rec.set_time(TIMELINE, sequence=int(t))
        for v in views:
            c2w = np.asarray(ds.cam_to_world(t, v), float)
            rec.log(entity(rig, v), rr.Transform3D(translation=c2w[:3, 3], mat3x3=c2w[:3, :3]))
            rec.log(entity(rig, v), rr.Pinhole(image_from_camera=K, resolution=[w, h], camera_xyz=rr.ViewCoordinates.RDF))
            img = rr.Image(ds.read(t, v, "rgb"))
            rec.log(entity(rig, v, "rgb"), img if lossless else img.compress(jpeg_quality=JPEG_QUALITY))
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
            shift = lens_shift(ds, centre)  # --lens: rerun's Pinhole has no distortion; the positions' points are exact
            if shift is not None:
                rec.log(entity(rig, centre, "lens"), rr.Image(colormap(shift, vmin=0.0)))
            pos = _read(ds, t, centre, "position")
            if pos is not None:
                s = grid_step(h, w, max_points)
                p, col = pos[::s, ::s].reshape(-1, 3), rgb[::s, ::s].reshape(-1, 3)
                ok = np.all(np.isfinite(p), axis=-1)
                rec.log(entity(rig, None, "points"), rr.Points3D(p[ok], colors=col[ok]))
                counts["points"] += int(ok.sum())
                clouds.append(p[ok])
                sf = _read(ds, t, centre, "scene_flow")
                if sf is not None and valid is not None:
                    s = grid_step(h, w, max_arrows)
                    p, f = pos[::s, ::s].reshape(-1, 3), sf[::s, ::s].reshape(-1, 3)
                    ok = np.asarray(valid, bool)[::s, ::s].reshape(-1) & np.all(np.isfinite(p), -1) & np.all(np.isfinite(f), -1)
                    ok &= np.linalg.norm(np.where(ok[:, None], f, 0.0), axis=-1) > STILL_M  # a still point: no arrow
                    if ok.any():  # none on the last frame: no t+1
                        arrows[int(t)] = (p[ok], f[ok])
        counts["frames"] += 1
    scale = float(arrow_scale) if arrow_scale is not None else auto_arrow_scale([f for _, f in arrows.values()], clouds)
    for t, (o, f) in arrows.items():
        rec.set_time(TIMELINE, sequence=t)
        rec.log(entity(rig, None, "scene_flow"), rr.Arrows3D(origins=o, vectors=f * scale))
        counts["arrows"] += len(o)
    if arrows:
        rec.log(entity(rig, None, "scene_flow_scale"), rr.TextDocument(f"scene-flow arrows drawn at {scale:g} times their length"), static=True)
    counts["arrow_scale"] = scale
    return counts


def view(out, save=None, rig: str | None = None, views=None, frames=None, every: int = 1,
         max_points: int = MAX_POINTS, max_arrows: int = MAX_ARROWS, arrow_scale: float | None = None,
         lossless: bool = False) -> dict:
    """Show dataset ``out`` in the rerun viewer, or with ``save`` write it to that ``.rrd`` file.

    ``rig``: one rig (default every rig); ``views``: (row, col) views to show (default all);
    ``frames``: frame numbers (default all complete frames); ``every``: keep every N-th of them;
    ``arrow_scale``: scene-flow arrows drawn this many times their length (default: chosen per
    rig, see the module docstring); ``lossless``: raw images instead of JPEG.
    Returns what was logged per rig (frames, images, points, arrows, arrow scale).
    """
    from ..data.dataset import open_datasets

    if every < 1:
        raise LfusdError(f"--every {every}: give a positive step (1 shows every frame)")
    if arrow_scale is not None and not (arrow_scale > 0 and math.isfinite(arrow_scale)):
        raise LfusdError(f"--arrow-scale {arrow_scale}: give a positive factor (1 draws scene flow at its true length)")
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
    blueprint = layout({ds.rig_name: (ds.rig.rows, ds.rig.cols, vs) for ds, _, vs in plan})
    partial = None
    if save is not None:
        partial = save.with_name(f".{save.name}.partial-{os.getpid()}")
        rec.save(str(partial), default_blueprint=blueprint)
    else:
        _spawn_viewer(rr, rec)
        rec.send_blueprint(blueprint)
    try:
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        result = {ds.rig_name: log_dataset(rec, ds, ds.rig_name, fs, vs, max_points, max_arrows, arrow_scale, lossless)
                  for ds, fs, vs in plan}
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
