"""PFM files (``lfusd export pfm``): ``disparity/``, ``depth/`` and ``disparity_change/``, one file per
frame and view named ``<frame:04d>_<row:02d>_<col:02d>.pfm``."""

from __future__ import annotations

from pathlib import Path

from ..data import formats
from ..keys import get
from .common import frames_of, new_dest, stem, views_for
from .registry import FLAG, VIEW, Option, register


@register("pfm", "PFM disparity, depth and disparity change",
          options=(Option("--view", "view", VIEW, "ROW,COL view (default: the centre view)"),
                   Option("--all-views", "all_views", FLAG, "every view")))
def export_pfm(ds, dest, frame: int | None = None, view=None, all_views: bool = False, keys=("disparity", "depth", "disparity_change")) -> list[Path]:
    """Write PFMs of ``keys`` under ``dest/<key>/``; motion keys only where their frame t+1 / t-1 exists."""
    frames = frames_of(ds, frame)
    views = views_for(ds, view, all_views)
    dest = new_dest(dest)
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
