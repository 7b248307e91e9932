"""Middlebury .flo files (``lfusd export flo``): ``flow_fwd/`` and ``flow_bwd/``, one file per frame and
view named ``<frame:04d>_<row:02d>_<col:02d>.flo``; unknown flow is stored as 1e10 (Middlebury's
UNKNOWN_FLOW)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..data import formats
from ..errors import LfusdError
from .common import frames_of, new_dest, stem, views_for
from .registry import FLAG, VIEW, Option, register

UNKNOWN_FLOW = 1e10


@register("flo", "Middlebury .flo forward and backward flow",
          options=(Option("--view", "view", VIEW, "ROW,COL view (default: the centre view)"),
                   Option("--all-views", "all_views", FLAG, "every view")))
def export_flo(ds, dest, frame: int | None = None, view=None, all_views: bool = False) -> list[Path]:
    """Write forward / backward flow as Middlebury .flo under ``dest/flow_fwd`` and ``dest/flow_bwd``."""
    frames = frames_of(ds, frame)
    views = views_for(ds, view, all_views)
    dest = new_dest(dest)
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
