"""Baseline (a) of the benchmark: per-view OpenCV DIS flow and plane-sweep disparity, composed into
scene flow (lfusd.evaluation.baselines), written as a submission from the public test inputs only
(``public/test/<scene>/cameras.json`` and ``rgb/``): what any method sees.

Per frame and view: disparity by a plane sweep from that view over the views of its row and
column (``cameras.json``'s disparity range), DIS flow to the same view at t+1, and scene flow and
disparity change from the two disparity maps and the flow (:func:`scene_flow_from`); where the
composition has no value (the flow leaves the image, no positive disparity) it predicts zero
motion and zero change, so every pixel is predicted.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from .. import layout
from ..errors import LfusdError

log = logging.getLogger(__name__)


def _inputs(scene_dir: Path) -> tuple[dict, callable]:
    from ..data.formats import read_png

    try:
        cams = json.loads((scene_dir / layout.BENCH_CAMERAS).read_text())
    except (OSError, ValueError):
        raise LfusdError(f"{scene_dir / layout.BENCH_CAMERAS} is missing or unreadable; rerun `lfusd bench make`") from None

    def rgb(frame: int, view) -> np.ndarray:
        return read_png(scene_dir / layout.BENCH_RGB / f"{layout.bench_name(frame, view)}.png")

    return cams, rgb


def predict_scene(scene_dir: Path, n_planes: int = 48, window: int = 9, device=None):
    """Yield (frame, view, arrays of a submission file) for every scored frame and view of one public test scene."""
    from ..evaluation.baselines import dis_flow, plane_sweep_disparity, scene_flow_from
    from ..layout import view_key

    cams, rgb = _inputs(scene_dir)
    views = [tuple(v) for v in cams["views"]]
    offsets = {v: tuple(cams["offsets"][view_key(v)]) for v in views}
    K = np.asarray(cams["intrinsics"], np.float64)
    rng = tuple(cams["disparity_range"])
    frames = cams["frames"]
    disp: dict[tuple[int, tuple[int, int]], np.ndarray] = {}

    def disparity(f, v):
        if (f, v) not in disp:
            group = [u for u in views if u[0] == v[0] or u[1] == v[1]]
            imgs = {u: rgb(f, u) for u in group}
            disp[(f, v)] = plane_sweep_disparity(imgs, offsets, offsets[v], rng, n_planes, window, device=device)
        return disp[(f, v)]

    for f in cams["scored_frames"]:
        nxt = frames[frames.index(f) + 1]
        for v in views:
            d0, d1 = disparity(f, v), disparity(nxt, v)
            flow = dis_flow(rgb(f, v), rgb(nxt, v))
            c0 = np.asarray(cams["cam_to_world"][str(f)][view_key(v)], np.float64)
            c1 = np.asarray(cams["cam_to_world"][str(nxt)][view_key(v)], np.float64)
            sf, dchange, ok = scene_flow_from(d0, d1, flow, K, c0, c1, cams["baseline"])
            yield f, v, {"flow": flow.astype(np.float32), "disparity": np.asarray(d0, np.float32),
                         "disparity_change": np.where(ok, dchange, 0.0).astype(np.float32),
                         "scene_flow": np.where(ok[..., None], sf, 0.0).astype(np.float32)}
        for v in views:
            disp.pop((f, v), None)  # frame f is done; t+1's maps are the next frame's t


def write_baseline(root, sub, n_planes: int = 48, window: int = 9, device=None) -> int:
    """Run baseline (a) on every public test scene of benchmark ``root``; write the submission into ``sub``."""
    from ..files import atomic_write
    from .make import read_record
    from .score import _savez, submission_path

    root, sub = Path(root), Path(sub)
    rec = read_record(root)
    n = 0
    for scene in rec["splits"]["test"]:
        (sub / scene).mkdir(parents=True, exist_ok=True)
        for f, v, arrays in predict_scene(root / layout.BENCH_PUBLIC / "test" / scene, n_planes, window, device):
            atomic_write(submission_path(sub, scene, f, v), lambda tmp, a=arrays: _savez(tmp, a), suffix=".npz")
            n += 1
        log.info("baseline: scene %s done", scene)
    return n
