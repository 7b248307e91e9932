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
        attrs = {"baseline_m": float(ds.rig.baseline), "focal_px": float(ds.rig.focal_px), "frame": int(t), "range": "rgb in [0, 1]"}
        rgb = light_field(ds, t)
        formats.write_lf_h5(p, rgb.astype(np.float32) / np.float32(np.iinfo(rgb.dtype).max), matlab=matlab, attrs=attrs)
        out.append(p)
    return out
