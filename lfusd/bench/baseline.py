"""Baselines of the benchmark, written as a submission from the public test inputs only
(``public/test/<scene>/cameras.json`` and ``rgb/``): what any method sees.

Baseline (a), ``dis``: per-view OpenCV DIS flow and plane-sweep disparity, composed into scene flow
(lfusd.evaluation.baselines).

Per frame and view: disparity by a plane sweep from that view over the views of its row and
column (``cameras.json``'s disparity range), DIS flow to the same view at t+1, and scene flow and
disparity change from the two disparity maps and the flow (:func:`scene_flow_from`); where the
composition has no value (the flow leaves the image, no positive disparity) it predicts zero
motion and zero change, so every pixel is predicted.

Baseline (b), ``rayflow``: the ray flow of Ma, Smith & Gupta (ECCV 2018; lfusd.evaluation.rayflow).
Per frame and view: the same plane-sweep disparity, then the 3-D motion of every pixel's point
from the light-field gradients of every view at t and t+1 (``local`` or ``global`` solver),
composed into flow, disparity change and world scene flow with the cameras of both frames. It
needs the disparity at t only, which no earlier frame pair swept (unlike (a), whose t+1 sweep is the
next pair's t); what it shares is the images' work, once per frame pair for every reference view
(:class:`lfusd.evaluation.rayflow.LightFieldPair`).
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


def public_test_scenes(root) -> list[tuple[str, Path]]:
    """(scene, its ``public/test/<scene>`` folder) for every test scene of benchmark ``root``: where a
    method outside lfusd (flow/predict_sceneflow.py --bench) reads the inputs every method sees."""
    from .make import read_record

    root = Path(root)
    return [(scene, root / layout.BENCH_PUBLIC / "test" / scene) for scene in read_record(root)["splits"]["test"]]


def public_inputs(scene_dir) -> tuple[dict, callable]:
    """(``cameras.json`` as a dict, ``rgb(frame, view)`` -> the stored image) of one public test scene."""
    return _inputs(Path(scene_dir))


def write_prediction(sub, scene: str, frame: int, view, arrays: dict) -> Path:
    """Write one submission file (``flow``, ``disparity``, ``disparity_change``, ``scene_flow``) atomically; its path."""
    from ..files import atomic_write
    from .score import _savez, submission_path

    path = submission_path(Path(sub), scene, frame, view)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, lambda tmp: _savez(tmp, arrays), suffix=".npz")
    return path


METHODS = ("dis", "rayflow")


def _check_parallel_rig(cams: dict) -> None:
    """Ray flow works in one camera frame for every view: the views of a frame must share one
    rotation and sit at their offsets (x right, y down, in baselines) in its image plane."""
    b = float(cams["baseline"])
    for f, per_view in cams["cam_to_world"].items():
        mats = {k: np.asarray(m, np.float64) for k, m in per_view.items()}
        k0, m0 = next(iter(mats.items()))
        for k, m in mats.items():
            step = np.subtract(cams["offsets"][k], cams["offsets"][k0]) * b
            expected = m0[:3, 3] + m0[:3, :3] @ np.array([step[0], step[1], 0.0])
            if np.abs(m[:3, :3] - m0[:3, :3]).max() > 1e-5 or np.abs(m[:3, 3] - expected).max() > 1e-4 * max(b, 1e-9):
                raise LfusdError(f"frame {f}: view {k} is not where a planar, parallel rig puts it; ray flow needs one (use --method dis)")


def predict_scene_rayflow(scene_dir: Path, n_planes: int = 48, window: int = 9, device=None, solver: str = "global"):
    """Yield (frame, view, arrays of a submission file) for every scored frame and view of one public
    test scene with baseline (b), ray flow (lfusd.evaluation.rayflow)."""
    from ..evaluation.baselines import plane_sweep_disparity
    from ..evaluation.rayflow import LightFieldPair, compose, ray_flow
    from ..layout import view_key

    cams, rgb = _inputs(scene_dir)
    _check_parallel_rig(cams)
    views = [tuple(v) for v in cams["views"]]
    offsets = {v: tuple(cams["offsets"][view_key(v)]) for v in views}
    K = np.asarray(cams["intrinsics"], np.float64)
    rng = tuple(cams["disparity_range"])
    frames = cams["frames"]
    pair, last = None, None
    for f in cams["scored_frames"]:
        nxt = frames[frames.index(f) + 1]
        i0 = {v: rgb(f, v) for v in views}
        i1 = {v: rgb(nxt, v) for v in views}
        # the image-only work (pyramids, splines, gradients) once per frame pair for every reference
        # view; the previous pair's t+1 is this pair's t when the scored frames follow each other
        pair = LightFieldPair(i0, i1, previous=pair if last == f else None)
        last = nxt
        for v in views:
            group = {u: i0[u] for u in views if u[0] == v[0] or u[1] == v[1]}
            d0 = plane_sweep_disparity(group, offsets, offsets[v], rng, n_planes, window, device=device)
            motion = ray_flow(i0, i1, offsets, v, K, d0, solver=solver, pair=pair)
            c0 = np.asarray(cams["cam_to_world"][str(f)][view_key(v)], np.float64)
            c1 = np.asarray(cams["cam_to_world"][str(nxt)][view_key(v)], np.float64)
            flow, dchange, sf = compose(d0, motion, K, cams["baseline"], c0, c1)
            yield f, v, {"flow": flow.astype(np.float32), "disparity": np.asarray(d0, np.float32),
                         "disparity_change": dchange.astype(np.float32), "scene_flow": sf.astype(np.float32)}


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


def write_baseline(root, sub, n_planes: int = 48, window: int = 9, device=None, method: str = "dis", solver: str = "global") -> int:
    """Run a baseline (``method`` 'dis': (a); 'rayflow': (b), with ``solver``) on every public test
    scene of benchmark ``root``; write the submission into ``sub``."""
    from ..files import atomic_write
    from .make import read_record
    from .score import _savez, submission_path

    from ..evaluation.baselines import check_window

    if method not in METHODS:
        raise LfusdError(f"unknown baseline {method!r}; use one of {', '.join(METHODS)}")
    check_window(window)  # before anything is written
    root, sub = Path(root), Path(sub)
    rec = read_record(root)
    if method == "rayflow":  # refuse before anything is written
        for scene in rec["splits"]["test"]:
            _check_parallel_rig(_inputs(root / layout.BENCH_PUBLIC / "test" / scene)[0])
    n = 0
    for scene in rec["splits"]["test"]:
        (sub / scene).mkdir(parents=True, exist_ok=True)
        scene_dir = root / layout.BENCH_PUBLIC / "test" / scene
        preds = (predict_scene(scene_dir, n_planes, window, device) if method == "dis"
                 else predict_scene_rayflow(scene_dir, n_planes, window, device, solver))
        for f, v, arrays in preds:
            atomic_write(submission_path(sub, scene, f, v), lambda tmp, a=arrays: _savez(tmp, a), suffix=".npz")
            n += 1
        log.info("baseline: scene %s done", scene)
    return n
