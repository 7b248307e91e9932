"""Motion coverage of a rendered video, from its flow: how much of a view moves, frame by frame.

A pixel *moves* at frame t when its forward flow is valid and ``|flow_fwd| > threshold`` (0.01 px,
the same rule as the projected measure of lfusd.author.choreography); frames without a next
frame have no forward flow and are left out. ``make demo`` prints :func:`report` of its output.
"""

from __future__ import annotations

import numpy as np

from ..data.dataset import open_datasets

THRESHOLD = 0.01  # px
GOAL_COVERAGE = 0.05  # the goal of issue 16: moving objects over 5 % of the centre view ...


def moving_fractions(ds, view=None, frames=None, threshold: float = THRESHOLD) -> tuple[list[int], np.ndarray]:
    """(frames, fraction of the view's pixels that move) for every frame of ``ds`` (a Dataset)
    that has a next frame; ``view`` defaults to the rig's centre view."""
    view = tuple(view) if view is not None else ds.rig.centre_view
    frames = [int(f) for f in (frames or ds.frames)]
    done = set(ds.frames)
    keep = [f for f in frames if f + 1 in done]
    out = np.zeros(len(keep))
    for k, f in enumerate(keep):
        flow = np.asarray(ds.read(f, view, "flow_fwd"), np.float64)
        valid = np.asarray(ds.read(f, view, "valid_fwd"), bool)
        moving = valid & (np.linalg.norm(flow, axis=-1) > threshold)
        out[k] = moving.sum() / moving.size
    return keep, out


def report(out_dir, rig: str | None = None) -> list[str]:
    """One line per rig of the dataset at ``out_dir``: the fraction of the centre view's frames
    with any moving pixel and with moving objects over GOAL_COVERAGE of the view."""
    lines = []
    for ds in open_datasets(out_dir, rig):
        frames, frac = moving_fractions(ds)
        n = len(frames)
        anyf = float(np.mean(frac > 0)) if n else 0.0
        goal = float(np.mean(frac >= GOAL_COVERAGE)) if n else 0.0
        lines.append(f"rig {ds.rig_name}, centre view {ds.rig.centre_view}: moving objects (|flow_fwd| > {THRESHOLD} px) "
                     f"in {anyf:.0%} of {n} frames, over {GOAL_COVERAGE:.0%} of the view in {goal:.0%}; "
                     f"mean coverage {float(frac.mean()) if n else 0.0:.1%} ({ds.rig.width * ds.rig.height} pixels per frame)")
    return lines
