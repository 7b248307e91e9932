"""Export a dataset (anything with lfusd.Dataset's interface) to the layouts research code reads.

- ``hci``: one HCI 4D light-field benchmark scene folder per frame: ``parameters.cfg``,
  ``input_Cam000.png`` ... (row-major, Cam000 top-left), ``gt_disp_lowres.pfm`` and
  ``gt_depth_lowres.pfm`` of the centre view (bottom-up little-endian PFM), ``valid_mask.png``
  (255 where a surface is seen), and with ``all_views`` ``gt_disp_lowres_Cam000.pfm`` ... .
- ``kitti``: KITTI 2015 scene-flow layout under ``training/`` for consecutive frame pairs: the
  centre view is the left camera (``image_2``), its right neighbour the right one (``image_3``);
  ``disp_occ_0`` / ``disp_noc_0`` (disparity at t), ``disp_occ_1`` / ``disp_noc_1`` (disparity at
  t+1 of the point seen at t), ``flow_occ`` / ``flow_noc`` (forward flow); ``noc`` leaves out
  pixels occluded at t+1.
- ``flo``: Middlebury ``flow_fwd/`` and ``flow_bwd/`` files; unknown flow is stored as 1e10
  (Middlebury's UNKNOWN_FLOW).
- ``pfm``: ``disparity/``, ``depth/`` and ``disparity_change/`` PFMs.
- ``lfmat``: one HDF5 file per frame holding ``LF`` [U,V,H,W,3] uint8 (or a MATLAB v7.3 .mat).

Per-view files are named ``<frame:04d>_<row:02d>_<col:02d>.<ext>`` (see :func:`stem`).
"""

from __future__ import annotations

import datetime
import json
import os
import shutil
from pathlib import Path

import numpy as np

from . import formats
from .. import layout
from ..errors import LfusdError
from ..keys import get

FORMATS = ("hci", "kitti", "flo", "pfm", "lfmat")
UNKNOWN_FLOW = 1e10


def stem(frame: int, view) -> str:
    """The file stem of one frame and view: ``0001_04_04``."""
    return f"{int(frame):04d}_{int(view[0]):02d}_{int(view[1]):02d}"


def open_dataset(path, rig: str | None = None):
    """``lfusd.Dataset(path, rig=rig)`` with a one-line error for a missing folder."""
    p = Path(path)
    if not p.is_dir():
        raise LfusdError(f"dataset folder {p} does not exist; give the output folder of `lfusd render`")
    from .. import Dataset

    return Dataset(p) if rig is None else Dataset(p, rig=rig)


def open_datasets(path, rig: str | None = None) -> list:
    """One reader per rig of the dataset in ``path``: just ``rig``, or every rig when it is None or 'all'."""
    if rig not in (None, "all"):
        return [open_dataset(path, rig)]
    manifest = Path(path) / layout.MANIFEST
    if not manifest.is_file():
        return [open_dataset(path)]  # raises the reader's own error naming the folder
    return [open_dataset(path, r) for r in json.loads(manifest.read_text())["rigs"]]


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


def hci_parameters(ds, frame: int) -> dict:
    """The HCI parameters.cfg values of one frame of a dataset.

    Disparity here is f_px * b / z of an unshifted parallel rig (focus at infinity); HCI's Blender
    add-on writes such a rig as focus_distance_m = 0 with offset = 0 (the toolkit's disp->depth
    conversion does not apply to it: use gt_depth_lowres.pfm). Pinhole cameras: fstop 100 as HCI.
    """
    rig = ds.rig
    centre = tuple(rig.centre_view)
    disp_c = ds.read(frame, centre, "disparity")
    fin = disp_c[np.isfinite(disp_c) & np.isfinite(ds.read(frame, centre, "depth"))]
    all_d = [fin]
    for v in ds.views:
        d = ds.read(frame, tuple(v), "disparity")
        all_d.append(d[np.isfinite(d)])
    frustum = np.concatenate(all_d)
    c2w = np.asarray(ds.cam_to_world(frame, centre), float)
    rx, ry, rz = formats.blender_euler_xyz(c2w)
    return {
        "focal_length_mm": float(rig.focal_length_mm),
        "image_resolution_x_px": int(rig.width),
        "image_resolution_y_px": int(rig.height),
        "sensor_size_mm": float(rig.sensor_mm),
        "fstop": 100.0,
        "num_cams_x": int(rig.cols),
        "num_cams_y": int(rig.rows),
        "baseline_mm": float(rig.baseline) * 1000.0,
        "focus_distance_m": 0.0,
        "center_cam_x_m": float(c2w[0, 3]),
        "center_cam_y_m": float(c2w[1, 3]),
        "center_cam_z_m": float(c2w[2, 3]),
        "center_cam_rx_rad": rx,
        "center_cam_ry_rad": ry,
        "center_cam_rz_rad": rz,
        "offset": 0.0,
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
    centre = tuple(ds.rig.centre_view)
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
        formats.write_png(sd / "valid_mask.png", np.where(np.isfinite(depth) & np.isfinite(disp), 255, 0).astype(np.uint8))
        folders.append(sd)
    return folders


# ---- KITTI -------------------------------------------------------------------------------------


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
    for sub in ("image_2", "image_3", "disp_occ_0", "disp_noc_0", "disp_occ_1", "disp_noc_1", "flow_occ", "flow_noc"):
        (tr / sub).mkdir(parents=True)
    for i, t in enumerate(frames):
        name = f"{i:06d}_10.png"
        for sub, view in (("image_2", left), ("image_3", right)):
            formats.write_png(tr / sub / name, ds.read(t, view, "rgb"))
            formats.write_png(tr / sub / f"{i:06d}_11.png", ds.read(t + 1, view, "rgb"))
        d0 = ds.read(t, left, "disparity")
        d1 = d0 + ds.read(t, left, "disparity_change")
        flow = ds.read(t, left, "flow_fwd")
        valid = np.asarray(ds.read(t, left, "valid_fwd"), bool) & np.isfinite(ds.read(t, left, "depth"))
        noc = valid & ~np.asarray(ds.read(t, left, "occlusion_fwd"), bool)
        formats.write_kitti_disparity(tr / "disp_occ_0" / name, d0)
        formats.write_kitti_disparity(tr / "disp_noc_0" / name, d0)
        formats.write_kitti_disparity(tr / "disp_occ_1" / name, d1, valid)
        formats.write_kitti_disparity(tr / "disp_noc_1" / name, d1, noc)
        formats.write_kitti_flow(tr / "flow_occ" / name, flow, valid)
        formats.write_kitti_flow(tr / "flow_noc" / name, flow, noc)
    (dest / "frames.txt").write_text("".join(f"{i:06d} frame {t} -> {t + 1}\n" for i, t in enumerate(frames)))
    return tr


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
    """Write one ``LF`` [U,V,H,W,3] uint8 file per frame: ``<scene>_f0001.h5`` (or ``.mat``)."""
    _check_planar_grid(ds, "the LF array layout")
    frames = _frames(ds, frame)
    dest = _new_dest(dest)
    out = []
    for t in frames:
        p = dest / f"{scene_name(ds)}_f{t:04d}.{'mat' if matlab else 'h5'}"
        attrs = {"baseline_m": float(ds.rig.baseline), "focal_px": float(ds.rig.focal_px), "frame": int(t)}
        formats.write_lf_h5(p, light_field(ds, t), matlab=matlab, attrs=attrs)
        out.append(p)
    return out


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
