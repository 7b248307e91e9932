"""Export a dataset (anything with lfusd.Dataset's interface) to the layouts research code reads.

Each layout is the one its benchmark's own readers and preparation scripts consume unchanged
(docs/CONVENTIONS.md, "Exports"):

- ``hci``: one HCI 4D light-field benchmark scene folder per frame: ``parameters.cfg``,
  ``input_Cam000.png`` ... (row-major, Cam000 top-left), ``gt_disp_lowres.pfm`` and
  ``gt_depth_lowres.pfm`` of the view the toolkit takes as centre (camera ``int(nx*ny/2)``;
  bottom-up little-endian PFM), ``valid_mask.png`` (255 where a surface is seen), and with
  ``all_views`` ``gt_disp_lowres_Cam000.pfm`` ... . ``sensor_size_mm`` is the sensor of the larger
  image dimension and ``focus_distance_m`` a finite stand-in for infinity (:data:`HCI_FOCUS_M`),
  so the toolkit's ``disp2depth`` / ``depth2disp`` / ``compute_offset`` give lfusd's values.
- ``kitti``: KITTI 2015 scene-flow layout under ``training/`` for consecutive frame pairs: the
  centre view is the left camera (``image_2``), its right neighbour the right one (``image_3``);
  ``disp_occ_0`` (disparity at t), ``disp_occ_1`` (disparity at t+1 of the point seen at t),
  ``flow_occ`` (forward flow), and their ``noc`` versions holding only points visible in the
  other image(s) (:func:`visible_in_view`). Values are rounded to 1/256 px (disparity) and
  1/64 px (flow), the format's precision.
- ``spring``: the Spring benchmark layout ``train/<scene>/frame_left|right``, ``disp1_*``,
  ``disp2_FW_*``, ``flow_FW_*`` / ``flow_BW_*`` as .dsp5 / .flo5 at twice the image resolution
  (Spring's loaders take every second sample).
- ``flo``: Middlebury ``flow_fwd/`` and ``flow_bwd/`` files; unknown flow is stored as 1e10
  (Middlebury's UNKNOWN_FLOW).
- ``pfm``: ``disparity/``, ``depth/`` and ``disparity_change/`` PFMs.
- ``lfmat``: one HDF5 file per frame holding ``LF`` float32 in [0, 1], [U,V,H,W,3] after
  BasicLFSR's transpose (or a MATLAB v7.3 .mat that MATLAB loads as [U,V,H,W,3]).

Per-view files are named ``<frame:04d>_<row:02d>_<col:02d>.<ext>`` (see :func:`stem`).
"""

from __future__ import annotations

import datetime
import os
import re
import shutil
from pathlib import Path

import numpy as np

from . import formats
from ..errors import LfusdError
from ..keys import get

FORMATS = ("hci", "kitti", "spring", "flo", "pfm", "lfmat", "hf", "webdataset")
UNKNOWN_FLOW = 1e10
# HCI's focus distance for lfusd's unshifted parallel rigs (focus at infinity), finite so that the
# toolkit's formulas (which divide by it) run: its 1/F term changes their depth by under 1e-9
# relative for any depth below 1000 km, below float32 precision.
HCI_FOCUS_M = 1e15
VIS_REL = 1e-3  # relative disparity slack of the visibility test (as lfusd.truth.motion.DEPTH_REL)
EDGE_REL = 0.5  # a relative disparity jump above this between neighbours is a depth edge (no slope across it)


def stem(frame: int, view) -> str:
    """The file stem of one frame and view: ``0001_04_04``."""
    return f"{int(frame):04d}_{int(view[0]):02d}_{int(view[1]):02d}"


def scene_name(ds) -> str:
    return Path(getattr(ds, "root", "scene")).name or "scene"


def _new_dest(dest) -> Path:
    dest = Path(dest)
    if dest.exists():
        raise LfusdError(f"export target {dest} already exists; choose a new folder or remove it first")
    try:
        dest.mkdir(parents=True)
    except OSError as e:
        raise LfusdError(f"cannot create export target {dest} ({e.strerror}): {formats.why_unwritable(dest)}") from None
    return dest


def _frames(ds, frame) -> list[int]:
    if not ds.frames:
        raise LfusdError(f"dataset {getattr(ds, 'root', '')} has no completely rendered frame yet; finish its render first")
    if frame is None:
        return list(ds.frames)
    if frame not in ds.frames:
        raise LfusdError(f"frame {frame} is not in the dataset (it has frames {ds.frames[0]}..{ds.frames[-1]}); pick one of those")
    return [frame]


def _view(ds, view):
    if view is None:
        return tuple(ds.rig.centre_view)
    view = tuple(int(v) for v in view)
    if view not in [tuple(v) for v in ds.views]:
        raise LfusdError(f"view {view} is not in the dataset's {ds.rig.rows}x{ds.rig.cols} grid; give row,col inside it")
    return view


def _check_planar_grid(ds, what: str) -> None:
    rig = ds.rig
    if getattr(rig, "layout", "plane") != "plane" or getattr(rig, "axes", "parallel") != "parallel" or getattr(rig, "spacing", "uniform") != "uniform":
        raise LfusdError(f"{what} needs a uniform planar parallel rig (one disparity for the grid); this dataset's rig is {rig.spacing}/{rig.layout}/{rig.axes}")


# ---- HCI ---------------------------------------------------------------------------------------


def hci_centre_view(ds) -> tuple[int, int]:
    """The view the HCI toolkit takes as centre: camera ``int(num_cams_x * num_cams_y / 2)`` in
    row-major order (the true centre of odd grids; lfusd's centre_view differs on even ones)."""
    return divmod(int(ds.rig.rows * ds.rig.cols / 2), int(ds.rig.cols))


def hci_parameters(ds, frame: int) -> dict:
    """The HCI parameters.cfg values of one frame of a dataset.

    The toolkit converts with f_px = focal_length_mm / sensor_size_mm * max(W, H), so
    ``sensor_size_mm`` is the sensor of the larger image dimension (lfusd's sensor spans the
    width). HCI's disparity is f_px*b*(1/z - 1/F) for focus distance F; lfusd's rigs are unshifted
    (F = infinity, disparity f_px*b/z, which is what the exported images show), and F = 0, as
    HCI's Blender add-on writes such a rig, makes the toolkit divide by zero: F is
    :data:`HCI_FOCUS_M` and ``offset`` = f_px*b/F (the toolkit's compute_offset) is then ~0.
    Pinhole cameras: fstop 100 as HCI.
    """
    rig = ds.rig
    centre = hci_centre_view(ds)
    disp_c = ds.read(frame, centre, "disparity")
    fin = disp_c[np.isfinite(disp_c) & np.isfinite(ds.read(frame, centre, "depth"))]
    all_d = [fin]
    for v in ds.views:
        d = ds.read(frame, tuple(v), "disparity")
        all_d.append(d[np.isfinite(d)])
    frustum = np.concatenate(all_d)
    c2w = np.asarray(ds.cam_to_world(frame, centre), float)
    rx, ry, rz = formats.blender_euler_xyz(c2w)
    baseline_mm = float(rig.baseline) * 1000.0
    return {
        "focal_length_mm": float(rig.focal_length_mm),
        "image_resolution_x_px": int(rig.width),
        "image_resolution_y_px": int(rig.height),
        "sensor_size_mm": float(rig.sensor_mm) * max(rig.width, rig.height) / rig.width,
        "fstop": 100.0,
        "num_cams_x": int(rig.cols),
        "num_cams_y": int(rig.rows),
        "baseline_mm": baseline_mm,
        "focus_distance_m": HCI_FOCUS_M,
        "center_cam_x_m": float(c2w[0, 3]),
        "center_cam_y_m": float(c2w[1, 3]),
        "center_cam_z_m": float(c2w[2, 3]),
        "center_cam_rx_rad": rx,
        "center_cam_ry_rad": ry,
        "center_cam_rz_rad": rz,
        "offset": float(rig.focal_px) * float(rig.baseline) / HCI_FOCUS_M,
        "scene": f"{scene_name(ds)}_f{frame:04d}",
        "category": "lfusd",
        "date": datetime.date.today().isoformat(),
        "version": "1.0",
        "authors": ["lfusd"],
        "contact": "none",
        "cycles_seed": 0,
        "disp_min": float(fin.min()) if fin.size else 0.0,
        "disp_max": float(fin.max()) if fin.size else 0.0,
        "frustum_disp_min": float(frustum.min()) if frustum.size else 0.0,
        "frustum_disp_max": float(frustum.max()) if frustum.size else 0.0,
        "depth_map_scale": 1.0,
    }


def export_hci(ds, dest, frame: int | None = None, all_views: bool = False) -> list[Path]:
    """Write one HCI scene folder per frame under ``dest``; returns the folders."""
    _check_planar_grid(ds, "the HCI layout")
    frames = _frames(ds, frame)
    dest = _new_dest(dest)
    folders = []
    centre = hci_centre_view(ds)
    for t in frames:
        sd = dest / f"{scene_name(ds)}_f{t:04d}"
        sd.mkdir()
        formats.write_hci_config(sd / "parameters.cfg", hci_parameters(ds, t))
        for i, (r, c) in enumerate(sorted(tuple(v) for v in ds.views)):  # row-major: Cam000 top-left
            formats.write_png(sd / f"input_Cam{i:03d}.png", ds.read(t, (r, c), "rgb"))
            if all_views:
                formats.write_pfm(sd / f"gt_disp_lowres_Cam{i:03d}.pfm", ds.read(t, (r, c), "disparity"))
        disp = ds.read(t, centre, "disparity")
        depth = ds.read(t, centre, "depth")
        formats.write_pfm(sd / "gt_disp_lowres.pfm", disp)
        formats.write_pfm(sd / "gt_depth_lowres.pfm", depth)
        # three equal channels: DistgDisp's loader reads channel 2 of valid_mask.png
        valid = np.where(np.isfinite(depth) & np.isfinite(disp), 255, 0).astype(np.uint8)
        formats.write_png(sd / "valid_mask.png", np.repeat(valid[..., None], 3, axis=-1))
        folders.append(sd)
    return folders


# ---- KITTI -------------------------------------------------------------------------------------


def _one_sided_slopes(d: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """(towards lower index, towards higher index) differences of ``d`` along ``axis``; NaN across a
    depth edge (relative jump above EDGE_REL) or off the image."""
    a, b = (d[:, :-1], d[:, 1:]) if axis == 1 else (d[:-1], d[1:])
    g = np.where(np.abs(b - a) <= EDGE_REL * np.minimum(a, b), b - a, np.nan)
    lower, higher = np.full(d.shape, np.nan), np.full(d.shape, np.nan)
    if axis == 1:
        higher[:, :-1], lower[:, 1:] = g, g
    else:
        higher[:-1], lower[1:] = g, g
    return lower, higher


def visible_in_view(x, y, d_expected, disparity_other) -> np.ndarray:
    """Whether points seen elsewhere are visible in another view of a planar parallel rig.

    A point lands at (x, y) in the other view (sub-pixel) with disparity ``d_expected`` there
    (disparity = f_px*b/z, so depth and disparity are one test). It is visible when (x, y) lies
    inside the image and the pixel nearest (x, y) does not see a nearer surface: that pixel's
    disparity, extrapolated to (x, y) with its one-sided slopes (never across a depth edge; exact
    on planes), is the point's own (within :data:`VIS_REL`) or smaller (a surface behind the point,
    which then sits on a silhouette). A nearer surface there hides it. Decided within half a pixel of
    the other view's depth edges and creases.
    """
    D = np.nan_to_num(np.asarray(disparity_other, np.float64), nan=0.0, posinf=0.0)  # no surface: disparity 0
    h, w = D.shape
    x, y, de = (np.asarray(a, np.float64) for a in (x, y, d_expected))
    with np.errstate(invalid="ignore"):
        inside = (x >= -0.5) & (x <= w - 0.5) & (y >= -0.5) & (y <= h - 0.5) & (de > 0)
    x, y = np.where(inside, x, 0.0), np.where(inside, y, 0.0)
    xi = np.clip(np.rint(x), 0, w - 1).astype(np.int64)
    yi = np.clip(np.rint(y), 0, h - 1).astype(np.int64)
    dx, dy = x - xi, y - yi
    with np.errstate(invalid="ignore"):
        left, right = _one_sided_slopes(D, 1)
        up, down = _one_sided_slopes(D, 0)
    # the slope on the side of the point, else the other side's, else flat
    gx = np.where(dx >= 0, right[yi, xi], left[yi, xi])
    gx = np.nan_to_num(np.where(np.isnan(gx), np.where(dx >= 0, left[yi, xi], right[yi, xi]), gx))
    gy = np.where(dy >= 0, down[yi, xi], up[yi, xi])
    gy = np.nan_to_num(np.where(np.isnan(gy), np.where(dy >= 0, up[yi, xi], down[yi, xi]), gy))
    tol = VIS_REL * de
    seen = D[yi, xi] + dx * gx + dy * gy  # what the pixel's surface has at (x, y)
    return inside & (seen <= de + tol)  # the point's own surface, or one behind it


def stereo_visible(ds, frame: int, view, other, flow=None, disparity=None) -> np.ndarray:
    """(H,W) bool: which pixels of ``view`` show a point that ``other`` (same planar parallel rig)
    also sees, at ``frame``; with ``flow`` (H,W,2) and ``disparity`` (H,W), the point moved to
    view pixel (u, v) + flow with that disparity, tested against ``other`` at ``frame``."""
    d = np.asarray(ds.read(frame, view, "disparity") if disparity is None else disparity, np.float64)
    sx0, sy0 = ds.rig.offsets(tuple(view))
    sx1, sy1 = ds.rig.offsets(tuple(other))
    v, u = np.mgrid[0 : d.shape[0], 0 : d.shape[1]].astype(np.float64)
    if flow is not None:
        u, v = u + flow[..., 0], v + flow[..., 1]
    with np.errstate(invalid="ignore"):
        x, y = u - d * (sx1 - sx0), v - d * (sy1 - sy0)  # CONVENTIONS: u - d*sx, v - d*sy
    return visible_in_view(x, y, d, ds.read(frame, other, "disparity")) & np.isfinite(d)


def inside_image(x, y, width: int, height: int) -> np.ndarray:
    """Whether sub-pixel positions (x, y) fall on a pixel of a width x height image (its area,
    [-0.5, W - 0.5) x [-0.5, H - 0.5)); NaN is outside."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    with np.errstate(invalid="ignore"):
        return (x >= -0.5) & (x < width - 0.5) & (y >= -0.5) & (y < height - 0.5)


def kitti_noc(d0, d1, flow, occ_0, occ_1) -> tuple[np.ndarray, np.ndarray]:
    """(noc_0, noc_1) as the KITTI 2015 devkit readme defines 'noc': the pixels of ``occ_0`` /
    ``occ_1`` whose matching correspondences fall inside the image domain. ``noc_0``: the right
    image's (u - d0, v); ``noc_1``: the left image at t+1, (u + du, v + dv), and the right one at
    t+1, (u + du - d1, v + dv). A correspondence that is occluded there still counts (the
    readme's 'occ' and 'noc' differ only by points leaving the image)."""
    h, w = np.shape(d0)
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    d0, d1, flow = (np.asarray(a, np.float64) for a in (d0, d1, flow))
    noc_0 = np.asarray(occ_0, bool) & inside_image(u - d0, v, w, h)
    u1, v1 = u + flow[..., 0], v + flow[..., 1]
    noc_1 = np.asarray(occ_1, bool) & inside_image(u1, v1, w, h) & inside_image(u1 - d1, v1, w, h)
    return noc_0, noc_1


def kitti_masks(ds, t: int, left, right) -> dict[str, np.ndarray]:
    """The KITTI validity masks of frame pair (t, t+1): ``occ_0`` / ``noc_0`` (disparity at t:
    known / its right-image correspondence inside the image), ``occ_fwd`` / ``noc_fwd`` (flow: known
    / also visible in the left image at t+1), ``occ_1`` / ``noc_1`` (disparity at t+1: known / its
    correspondences at t+1 inside both images; :func:`kitti_noc`)."""
    d0 = np.asarray(ds.read(t, left, "disparity"), np.float64)
    occ_0 = np.isfinite(d0) & (d0 > 0) & np.isfinite(ds.read(t, left, "depth"))
    occ_fwd = np.asarray(ds.read(t, left, "valid_fwd"), bool) & occ_0
    noc_fwd = occ_fwd & ~np.asarray(ds.read(t, left, "occlusion_fwd"), bool)
    flow = np.asarray(ds.read(t, left, "flow_fwd"), np.float64)
    d1 = d0 + ds.read(t, left, "disparity_change")
    with np.errstate(invalid="ignore"):
        occ_1 = occ_fwd & np.isfinite(d1) & (d1 > 0)
    noc_0, noc_1 = kitti_noc(d0, d1, flow, occ_0, occ_1)
    return {"occ_0": occ_0, "noc_0": noc_0, "occ_fwd": occ_fwd, "noc_fwd": noc_fwd, "occ_1": occ_1, "noc_1": noc_1}


MOVING_M = 1e-5  # m per frame: above the stored scene flow's rounding (2^-18 m), far below any motion


def kitti_object_map(ds, t: int, view) -> np.ndarray:
    """KITTI's ``obj_map`` of frame pair (t, t+1) in ``view``: uint8, 0 = background, k > 0 the
    k-th object that moves between t and t+1 (capped at 255), the devkit's foreground
    (``evaluate_scene_flow.cpp``: ``O_map`` 0 background, > 0 foreground). An object moves when its
    world pose changes or a pixel of it has scene flow above :data:`MOVING_M` (a skinned body
    moves under a fixed pose)."""
    inst = np.asarray(ds.read(t, view, "instance"))
    moving = set()
    for oid, obj in ds.objects.items():
        poses = getattr(obj, "poses", {})
        if t in poses and t + 1 in poses and np.max(np.abs(np.asarray(poses[t + 1]) - np.asarray(poses[t]))) > MOVING_M:
            moving.add(int(oid))
    sf = np.asarray(ds.read(t, view, "scene_flow"), np.float64)
    ok = np.asarray(ds.read(t, view, "valid_fwd"), bool) & np.all(np.isfinite(sf), axis=-1)
    moving |= {int(i) for i in np.unique(inst[ok & (np.linalg.norm(np.where(ok[..., None], sf, 0.0), axis=-1) > MOVING_M)])}
    moving.discard(0)
    out = np.zeros(inst.shape, np.uint8)
    for k, oid in enumerate(sorted(moving), start=1):
        out[inst == oid] = min(k, 255)
    return out


def export_kitti(ds, dest, frame: int | None = None) -> Path:
    """Write frame pairs (t, t+1) in the KITTI 2015 scene-flow layout; returns ``dest/training``."""
    _check_planar_grid(ds, "the KITTI layout")
    if ds.rig.cols < 2:
        raise LfusdError("the KITTI layout needs a right neighbour of the centre view; render a grid with at least 2 columns")
    rc, cc = ds.rig.centre_view
    left, right = (rc, cc), (rc, cc + 1)
    frames = [t for t in _frames(ds, frame) if t + 1 in ds.frames]
    if not frames:
        raise LfusdError("KITTI pairs need frame t and t+1; pick a frame that has a next frame")
    dest = _new_dest(dest)
    tr = dest / "training"
    for sub in ("image_2", "image_3", "disp_occ_0", "disp_noc_0", "disp_occ_1", "disp_noc_1", "flow_occ", "flow_noc", "obj_map"):
        (tr / sub).mkdir(parents=True)
    for i, t in enumerate(frames):
        name = f"{i:06d}_10.png"
        for sub, view in (("image_2", left), ("image_3", right)):
            formats.write_png(tr / sub / name, ds.read(t, view, "rgb"))
            formats.write_png(tr / sub / f"{i:06d}_11.png", ds.read(t + 1, view, "rgb"))
        m = kitti_masks(ds, t, left, right)
        d0 = ds.read(t, left, "disparity")
        d1 = d0 + ds.read(t, left, "disparity_change")
        flow = ds.read(t, left, "flow_fwd")
        formats.write_kitti_disparity(tr / "disp_occ_0" / name, d0, m["occ_0"])
        formats.write_kitti_disparity(tr / "disp_noc_0" / name, d0, m["noc_0"])
        formats.write_kitti_disparity(tr / "disp_occ_1" / name, d1, m["occ_1"])
        formats.write_kitti_disparity(tr / "disp_noc_1" / name, d1, m["noc_1"])
        formats.write_kitti_flow(tr / "flow_occ" / name, flow, m["occ_fwd"])
        formats.write_kitti_flow(tr / "flow_noc" / name, flow, m["noc_fwd"])
        formats.write_png(tr / "obj_map" / name, kitti_object_map(ds, t, left))
    (dest / "frames.txt").write_text("".join(f"{i:06d} frame {t} -> {t + 1}\n" for i, t in enumerate(frames)))
    return tr


# ---- Spring ------------------------------------------------------------------------------------


def _spring_path(sd: Path, kind: str, cam: str, i: int, ext: str) -> Path:
    """``sd/<kind>_<cam>/<kind>_<cam>_<i:04d>.<ext>`` (Spring's naming), creating the folder."""
    folder = sd / f"{kind}_{cam}"
    folder.mkdir(parents=True, exist_ok=True)
    return folder / f"{kind}_{cam}_{i:04d}.{ext}"


def _spring_gt(a: np.ndarray) -> np.ndarray:
    """Spring's ground truth has twice the image resolution per axis and its loaders take
    ``gt[::2, ::2]``: each pixel's value fills its 2x2 block (lfusd's GT is at pixel centres)."""
    return np.repeat(np.repeat(a, 2, axis=0), 2, axis=1)


def export_spring(ds, dest, frame: int | None = None) -> Path:
    """Write consecutive frames in the Spring layout; returns ``dest/train/<scene>``.

    The centre view is Spring's left camera, its right neighbour the right one; frames are
    renumbered 1, 2, ... (``frames.txt`` maps them). Per camera: ``disp1`` (disparity, positive:
    Spring's loader negates the left camera's), ``disp2_FW`` (disparity at t+1 of the point seen at
    t), ``flow_FW`` / ``flow_BW``; NaN where unknown. lfusd has no backward disparity change, so
    there is no ``disp2_BW``.
    """
    _check_planar_grid(ds, "the Spring layout")
    if ds.rig.cols < 2:
        raise LfusdError("the Spring layout needs a right neighbour of the centre view; render a grid with at least 2 columns")
    frames = _frames(ds, frame)
    if frames != list(range(frames[0], frames[0] + len(frames))):
        raise LfusdError(f"the Spring layout needs consecutive frames, this dataset has {frames}; finish the render or pick one --frame")
    rc, cc = ds.rig.centre_view
    cams = {"left": (rc, cc), "right": (rc, cc + 1)}
    dest = _new_dest(dest)
    sd = dest / "train" / scene_name(ds)
    for i, t in enumerate(frames, start=1):
        for cam, view in cams.items():
            def out(kind: str, ext: str, cam=cam, i=i) -> Path:
                return _spring_path(sd, kind, cam, i, ext)

            formats.write_png(out("frame", "png"), ds.read(t, view, "rgb"))
            d = np.asarray(ds.read(t, view, "disparity"), np.float32)
            known = np.isfinite(d) & (d > 0)
            formats.write_dsp5(out("disp1", "dsp5"), _spring_gt(np.where(known, d, np.nan)))
            for key, step, kind in (("fwd", 1, "FW"), ("bwd", -1, "BW")):
                if t + step not in frames:
                    continue
                flow = np.asarray(ds.read(t, view, f"flow_{key}"), np.float32)
                ok = np.asarray(ds.read(t, view, f"valid_{key}"), bool) & np.all(np.isfinite(flow), axis=-1)
                formats.write_flo5(out(f"flow_{kind}", "flo5"), _spring_gt(np.where(ok[..., None], flow, np.nan)))
                if key == "fwd":
                    d2 = d + np.asarray(ds.read(t, view, "disparity_change"), np.float32)
                    formats.write_dsp5(out("disp2_FW", "dsp5"), _spring_gt(np.where(ok & known, d2, np.nan)))
    (dest / "frames.txt").write_text("".join(f"{i:04d} frame {t}\n" for i, t in enumerate(frames, start=1)))
    return sd


# ---- flo / pfm ---------------------------------------------------------------------------------


def _views_for(ds, view, all_views):
    return [tuple(v) for v in ds.views] if all_views else [_view(ds, view)]


def export_flo(ds, dest, frame: int | None = None, view=None, all_views: bool = False) -> list[Path]:
    """Write forward / backward flow as Middlebury .flo under ``dest/flow_fwd`` and ``dest/flow_bwd``."""
    frames = _frames(ds, frame)
    views = _views_for(ds, view, all_views)
    dest = _new_dest(dest)
    written = []
    for key, step in (("fwd", 1), ("bwd", -1)):
        (dest / f"flow_{key}").mkdir()
        for t in frames:
            if t + step not in ds.frames:
                continue
            for v in views:
                flow = np.array(ds.read(t, v, f"flow_{key}"), np.float32)
                ok = np.asarray(ds.read(t, v, f"valid_{key}"), bool) & np.all(np.isfinite(flow), axis=-1)
                flow[~ok] = UNKNOWN_FLOW
                p = dest / f"flow_{key}" / f"{stem(t, v)}.flo"
                formats.write_flo(p, flow)
                written.append(p)
    if not written:
        raise LfusdError("no frame of this export has a neighbouring frame, so there is no flow; render a video (lfusd render-video) or pick another --frame")
    return written


def export_pfm(ds, dest, frame: int | None = None, view=None, all_views: bool = False, keys=("disparity", "depth", "disparity_change")) -> list[Path]:
    """Write PFMs of ``keys`` under ``dest/<key>/``; motion keys only where their frame t+1 / t-1 exists."""
    frames = _frames(ds, frame)
    views = _views_for(ds, view, all_views)
    dest = _new_dest(dest)
    written = []
    for key in keys:
        for t in frames:
            step = get(key).step
            if step and t + step not in ds.frames:
                continue
            for v in views:
                (dest / key).mkdir(exist_ok=True)
                p = dest / key / f"{stem(t, v)}.pfm"
                formats.write_pfm(p, ds.read(t, v, key))
                written.append(p)
    return written


# ---- HDF5 LF -----------------------------------------------------------------------------------


def light_field(ds, frame: int, key: str = "rgb") -> np.ndarray:
    """All views of one frame as an array [U,V,H,W,...] (U rows, V columns)."""
    rows, cols = ds.rig.rows, ds.rig.cols
    first = np.asarray(ds.read(frame, (0, 0), key))
    lf = np.empty((rows, cols) + first.shape, first.dtype)
    for r in range(rows):
        for c in range(cols):
            lf[r, c] = ds.read(frame, (r, c), key)
    return lf


def export_lfmat(ds, dest, frame: int | None = None, matlab: bool = False) -> list[Path]:
    """Write one ``LF`` file per frame, ``<scene>_f0001.h5`` (or ``.mat``): float32 RGB in [0, 1]
    (their rgb2ycbcr expects it), [U,V,H,W,3] after BasicLFSR's transpose (4,3,2,1,0) and in MATLAB."""
    _check_planar_grid(ds, "the LF array layout")
    frames = _frames(ds, frame)
    dest = _new_dest(dest)
    out = []
    for t in frames:
        p = dest / f"{scene_name(ds)}_f{t:04d}.{'mat' if matlab else 'h5'}"
        attrs = {"baseline_m": float(ds.rig.baseline), "focal_px": float(ds.rig.focal_px), "frame": int(t), "range": "rgb in [0, 1]"}
        rgb = light_field(ds, t)
        formats.write_lf_h5(p, rgb.astype(np.float32) / np.float32(np.iinfo(rgb.dtype).max), matlab=matlab, attrs=attrs)
        out.append(p)
    return out


def export_webdataset(ds, dest, frame: int | None = None, **kw) -> list[Path]:
    """WebDataset tar shards with Croissant metadata (:mod:`lfusd.data.export_hf`)."""
    from .export_hf import export_webdataset as run

    return run(ds, dest, frame=frame, **kw)


def export_hf(ds, dest, frame: int | None = None, **kw) -> list[Path]:
    """The WebDataset export plus a Hugging Face dataset card (:mod:`lfusd.data.export_hf`)."""
    from .export_hf import export_hf as run

    return run(ds, dest, frame=frame, **kw)


def _remove_stale_partials(dest: Path) -> None:
    """Remove the partial folders of exports to ``dest`` that were killed (``.<name>.partial-<pid>``
    of a process no longer running; never a link), so that a rerun leaves nothing behind."""
    pattern = re.compile(rf"\.{re.escape(dest.name)}\.partial-(\d+)")
    for p in dest.parent.iterdir() if dest.parent.is_dir() else ():
        m = pattern.fullmatch(p.name)
        if not m or p.is_symlink() or not p.is_dir():
            continue
        try:
            os.kill(int(m[1]), 0)
        except ProcessLookupError:
            shutil.rmtree(p, ignore_errors=True)
        except (PermissionError, OverflowError):
            pass  # another user's running process, or no pid


def export(ds, fmt: str, dest, frame: int | None = None, **kw):
    """Dispatch to ``export_<fmt>``, writing into a hidden folder beside ``dest`` that is renamed
    to ``dest`` when complete: a failed export leaves nothing that blocks its retry."""
    if fmt not in FORMATS:
        raise LfusdError(f"unknown export format {fmt!r}; use one of {', '.join(FORMATS)}")
    dest = Path(dest)
    if dest.exists():
        raise LfusdError(f"export target {dest} already exists; choose a new folder or remove it first")
    try:
        dest.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise LfusdError(f"cannot create export target {dest} ({e.strerror}): {formats.why_unwritable(dest)}") from None
    _remove_stale_partials(dest)
    tmp = dest.parent / f".{dest.name}.partial-{os.getpid()}"
    try:
        result = globals()[f"export_{fmt}"](ds, tmp, frame=frame, **kw)
        tmp.rename(dest)
    except OSError as e:
        raise LfusdError(f"cannot write export {dest} ({e.strerror or e}): {formats.why_unwritable(tmp / 'x')}") from None
    finally:
        if tmp.is_dir() and not tmp.is_symlink():
            shutil.rmtree(tmp, ignore_errors=True)

    def moved(p):
        return dest / Path(p).relative_to(tmp)

    return [moved(p) for p in result] if isinstance(result, list) else moved(result)
