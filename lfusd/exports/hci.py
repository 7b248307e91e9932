"""HCI 4D light-field benchmark layout (``lfusd export hci``).

One scene folder per frame: ``parameters.cfg``, ``input_Cam000.png`` ... (row-major, Cam000
top-left), ``gt_disp_lowres.pfm`` and ``gt_depth_lowres.pfm`` of the view the toolkit takes as
centre (camera ``int(nx*ny/2)``; bottom-up little-endian PFM), ``valid_mask.png`` (255 where a
surface is seen), and with ``all_views`` ``gt_disp_lowres_Cam000.pfm`` ... . ``sensor_size_mm`` is
the sensor of the larger image dimension and ``focus_distance_m`` a finite stand-in for infinity
(:data:`HCI_FOCUS_M`), so the toolkit's ``disp2depth`` / ``depth2disp`` / ``compute_offset`` give
lfusd's values.
"""

from __future__ import annotations

import datetime
from pathlib import Path

import numpy as np

from ..data import formats
from .common import check_planar_grid, frames_of, new_dest, scene_name
from ..errors import LfusdError
from .registry import FLAG, TEXT, Option, register

# HCI's focus distance for lfusd's unshifted parallel rigs (focus at infinity), finite so that the
# toolkit's formulas (which divide by it) run: its 1/F term changes their depth by under 1e-9
# relative for any depth below 1000 km, below float32 precision.
HCI_FOCUS_M = 1e15


def hci_centre_view(ds) -> tuple[int, int]:
    """The view the HCI toolkit takes as centre: camera ``int(num_cams_x * num_cams_y / 2)`` in
    row-major order (the true centre of odd grids; lfusd's centre_view differs on even ones)."""
    return divmod(int(ds.rig.rows * ds.rig.cols / 2), int(ds.rig.cols))


def hci_parameters(ds, frame: int, src=None, shift: int = 0) -> dict:
    """The HCI parameters.cfg values of one frame of a dataset.

    The toolkit converts with f_px = focal_length_mm / sensor_size_mm * max(W, H), so
    ``sensor_size_mm`` is the sensor of the larger image dimension (lfusd's sensor spans the
    width). HCI's disparity is f_px*b*(1/z - 1/F) for focus distance F; lfusd's rigs are unshifted
    (F = infinity, disparity f_px*b/z, which is what the exported images show), and F = 0, as
    HCI's Blender add-on writes such a rig, makes the toolkit divide by zero: F is
    :data:`HCI_FOCUS_M` and ``offset`` = f_px*b/F (the toolkit's compute_offset) is then ~0.
    Pinhole cameras: fstop 100 as HCI. ``src`` (default ``ds``) is what the images are read from:
    with HCI's sensor shift ``shift`` k (:class:`_Shifted`) the images are cropped, the sensor with
    them (f_px stays), and F is the depth of disparity k, f_px*b/k (``offset`` = k).
    """
    rig = ds.rig
    src = ds if src is None else src
    width, height = (src.width, src.height) if shift else (rig.width, rig.height)
    centre = hci_centre_view(ds)
    disp_c = src.read(frame, centre, "disparity")
    fin = disp_c[np.isfinite(disp_c) & np.isfinite(src.read(frame, centre, "depth"))]
    all_d = [fin]
    for v in ds.views:
        d = src.read(frame, tuple(v), "disparity")
        all_d.append(d[np.isfinite(d)])
    frustum = np.concatenate(all_d)
    c2w = np.asarray(ds.cam_to_world(frame, centre), float)
    rx, ry, rz = formats.blender_euler_xyz(c2w)
    baseline_mm = float(rig.baseline) * 1000.0
    return {
        "focal_length_mm": float(rig.focal_length_mm),
        "image_resolution_x_px": int(width),
        "image_resolution_y_px": int(height),
        "sensor_size_mm": float(rig.sensor_mm) * max(width, height) / rig.width,
        "fstop": 100.0,
        "num_cams_x": int(rig.cols),
        "num_cams_y": int(rig.rows),
        "baseline_mm": baseline_mm,
        "focus_distance_m": float(rig.focal_px) * float(rig.baseline) / shift if shift else HCI_FOCUS_M,
        "center_cam_x_m": float(c2w[0, 3]),
        "center_cam_y_m": float(c2w[1, 3]),
        "center_cam_z_m": float(c2w[2, 3]),
        "center_cam_rx_rad": rx,
        "center_cam_ry_rad": ry,
        "center_cam_rz_rad": rz,
        "offset": float(shift) if shift else float(rig.focal_px) * float(rig.baseline) / HCI_FOCUS_M,
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


class _Shifted:
    """A dataset's frame seen through HCI's sensor shift: view (r, c) at grid offset (sx, sy) shifted
    by (k*sx, k*sy) pixels and every view cropped alike (:func:`lfusd.data.augment.refocus`, an exact
    integer crop), so every disparity is d - k; depth is unchanged. Reads like ``ds`` for one frame."""

    def __init__(self, ds, frame: int, k: int):
        from ..data.augment import refocus

        self.ds, self.rig, self.views, self.k = ds, ds.rig, [tuple(v) for v in ds.views], int(k)
        views = self.views
        item = {"views": np.asarray(views), "offsets": np.asarray([ds.rig.offsets(v) for v in views], np.float64),
                "intrinsics": np.stack([ds.rig.intrinsics()] * len(views)),
                "cam_to_world": np.stack([np.asarray(ds.cam_to_world(frame, v), np.float64) for v in views]),
                "rgb": np.stack([np.moveaxis(np.asarray(ds.read(frame, v, "rgb")), -1, 0) for v in views]),
                "disparity": np.stack([np.asarray(ds.read(frame, v, "disparity"), np.float32) for v in views]),
                "depth": np.stack([np.asarray(ds.read(frame, v, "depth"), np.float32) for v in views])}
        self.item = refocus(item, self.k)
        self.height, self.width = self.item["depth"].shape[-2:]

    def read(self, frame, view, key):
        a = self.item[key][self.views.index(tuple(view))]
        return np.moveaxis(a, 0, -1) if key == "rgb" else a


def export_hci(ds, dest, frame: int | None = None, all_views: bool = False, shift: str | int | None = None) -> list[Path]:
    """Write one HCI scene folder per frame under ``dest``; returns the folders. ``shift`` k (pixels
    per view step) applies HCI's sensor shift: every view is shifted by k times its grid offset and
    cropped alike (an exact integer crop, ``2*k*max|offset|`` px narrower), so the disparity is
    d - k (of both signs around the plane at disparity k) and ``focus_distance_m`` is that plane's depth."""
    check_planar_grid(ds, "the HCI layout")
    k = _shift(shift)
    frames = frames_of(ds, frame)
    dest = new_dest(dest)
    folders = []
    centre = hci_centre_view(ds)
    for t in frames:
        src = _Shifted(ds, t, k) if k else ds
        sd = dest / f"{scene_name(ds)}_f{t:04d}"
        sd.mkdir()
        formats.write_hci_config(sd / "parameters.cfg", hci_parameters(ds, t, src, k))
        for i, (r, c) in enumerate(sorted(tuple(v) for v in ds.views)):  # row-major: Cam000 top-left
            formats.write_png(sd / f"input_Cam{i:03d}.png", src.read(t, (r, c), "rgb"))
            if all_views:
                formats.write_pfm(sd / f"gt_disp_lowres_Cam{i:03d}.pfm", src.read(t, (r, c), "disparity"))
        disp = src.read(t, centre, "disparity")
        depth = src.read(t, centre, "depth")
        formats.write_pfm(sd / "gt_disp_lowres.pfm", disp)
        formats.write_pfm(sd / "gt_depth_lowres.pfm", depth)
        # three equal channels: DistgDisp's loader reads channel 2 of valid_mask.png
        valid = np.where(np.isfinite(depth) & np.isfinite(disp), 255, 0).astype(np.uint8)
        formats.write_png(sd / "valid_mask.png", np.repeat(valid[..., None], 3, axis=-1))
        folders.append(sd)
    return folders


def _shift(shift) -> int:
    """``--shift``'s integer k (pixels per view step); 0 when not given."""
    if shift is None or shift == "":
        return 0
    try:
        k = float(shift)
    except (TypeError, ValueError):
        k = float("nan")
    if not np.isfinite(k) or k != int(k):
        raise LfusdError(f"--shift must be a whole number of pixels per view step (HCI's sensor shift, an exact crop), got {shift!r}")
    return int(k)


register("hci", "one HCI 4D light-field benchmark scene folder per frame",
         options=(Option("--all-views", "all_views", FLAG, "also per-view disparity PFMs"),
                  Option("--shift", "shift", TEXT, "HCI's sensor shift: K whole pixels per view step; views are shifted by K times their "
                         "grid offset and cropped alike, so the disparity is d - K (both signs; a `things` scene's design: "
                         "shift_px in its record)")), pinhole=True)(export_hci)
