"""Light-field arrays (``lfusd export lfmat``): one HDF5 file per frame holding ``LF`` float32 in [0, 1],
[U,V,H,W,3] after BasicLFSR's transpose (or a MATLAB v7.3 .mat that MATLAB loads as [U,V,H,W,3])."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..data import formats
from .common import check_planar_grid, frames_of, new_dest, scene_name
from .registry import FLAG, Option, register

def light_field(ds, frame: int, key: str = "rgb") -> np.ndarray:
    """All views of one frame as an array [U,V,H,W,...] (U rows, V columns)."""
    rows, cols = ds.rig.rows, ds.rig.cols
    first = np.asarray(ds.read(frame, (0, 0), key))
    lf = np.empty((rows, cols) + first.shape, first.dtype)
    for r in range(rows):
        for c in range(cols):
            lf[r, c] = ds.read(frame, (r, c), key)
    return lf


def lens_attrs(ds) -> dict:
    """A distorted dataset's lens models (render-video --lens) as an attribute: ``distortion`` [rows, cols, 5],
    each view's OpenCV distCoeffs (k1, k2, p1, p2, k3); nothing for pinholes."""
    if not getattr(ds, "distorted", False):
        return {}
    return {"distortion": np.array([[ds.distortion((r, c)).coeffs for c in range(ds.rig.cols)] for r in range(ds.rig.rows)], np.float64)}


@register("lfmat", "one HDF5 light-field array LF [U,V,H,W,3] per frame",
          options=(Option("--matlab", "matlab", FLAG,
                          "write MATLAB v7.3 .mat files instead of .h5 (both: LF [U,V,H,W,3] in [0,1] as BasicLFSR reads it)"),))
def export_lfmat(ds, dest, frame: int | None = None, matlab: bool = False) -> list[Path]:
    """Write one ``LF`` file per frame, ``<scene>_f0001.h5`` (or ``.mat``): float32 RGB in [0, 1]
    (their rgb2ycbcr expects it), [U,V,H,W,3] after BasicLFSR's transpose (4,3,2,1,0) and in MATLAB."""
    check_planar_grid(ds, "the LF array layout")
    frames = frames_of(ds, frame)
    dest = new_dest(dest)
    out = []
    for t in frames:
        p = dest / f"{scene_name(ds)}_f{t:04d}.{'mat' if matlab else 'h5'}"
        attrs = {"baseline_m": float(ds.rig.baseline), "focal_px": float(ds.rig.focal_px), "frame": int(t), "range": "rgb in [0, 1]",
                 **lens_attrs(ds)}
        rgb = light_field(ds, t)
        formats.write_lf_h5(p, rgb.astype(np.float32) / np.float32(np.iinfo(rgb.dtype).max), matlab=matlab, attrs=attrs)
        out.append(p)
    return out
