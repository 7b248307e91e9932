"""Throwaway demo: ``lfusd export npy``, one depth .npy per frame and view."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .common import frames_of, new_dest, stem, views_for
from .registry import FLAG, Option, register


@register("npy", "depth as NumPy .npy per frame and view", options=(Option("--all-views", "all_views", FLAG, "every view"),))
def export_npy(ds, dest, frame: int | None = None, all_views: bool = False) -> list[Path]:
    """Write ``depth/<frame>_<row>_<col>.npy``."""
    dest = new_dest(dest)
    (dest / "depth").mkdir()
    out = []
    for t in frames_of(ds, frame):
        for v in views_for(ds, None, all_views):
            out.append(dest / "depth" / f"{stem(t, v)}.npy")
            np.save(out[-1], ds.read(t, v, "depth"))
    return out
