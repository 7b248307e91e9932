"""Time the benchmark's baselines (a) DIS + plane sweep and (b) ray flow (global and local) per view
and frame at a benchmark's size (default preview: 5x5 views, 128x128), an older revision's
implementation beside this tree's, and extrapolate to its test split.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_baselines.py [--bench preview] [--views 3] [--before main]

The input is a synthetic light-field pair (a textured plane moving in 3-D, ray-traced in closed
form, as in tests/evaluation/test_rayflow.py), so no render is needed; the work per view-frame is
what `lfusd bench baseline` does (lfusd/bench/baseline.py): (a) one plane sweep (the one at t+1; t's
is the previous pair's t+1), DIS flow and the composition; (b) the plane sweep at t, the ray flow and
the composition, plus a 1/(rows x cols) share of the frame pair's image-only work
(rayflow.LightFieldPair, built once per frame for every view; timed apart) where the revision has it.
``--views`` reference views are timed per method (each one's work is independent of which view).

``--before REV``: lfusd/evaluation/baselines.py and rayflow.py as committed at REV (``git show``),
loaded as modules of this tree's lfusd.evaluation package, so the two differ only in those files.
Both run in one process, interleaved per method (before, after), each the best of ``--repeat``.
Prints per implementation wall seconds and CPU seconds (process time: every thread counted) per
view-frame, the ratio before / after, and the test split's minutes at that rate (wall). On a
shared machine the CPU seconds are the steadier figure.
"""

from __future__ import annotations

import argparse
import inspect
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lfusd.bench.make import load_definition  # noqa: E402
from lfusd.evaluation import baselines, rayflow  # noqa: E402
from revisions import module_at  # noqa: E402  (benchmarks/revisions.py)


def light_field(rows: int, cols: int, w: int, h: int, t: int) -> tuple[dict, dict, np.ndarray]:
    f, b, z0 = 0.9 * w, 0.05, 2.0
    motion = np.array([0.02, -0.015, 0.05])
    k = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])
    rng = np.random.default_rng(1)
    waves = [(rng.uniform(-1, 1, 2) / rng.uniform(0.02, 0.1), rng.uniform(0, 6.3)) for _ in range(24)]
    offsets = {(r, c): (c - (cols - 1) / 2, r - (rows - 1) / 2) for r in range(rows) for c in range(cols)}
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    z = z0 + t * motion[2]
    imgs = {}
    for view, (sx, sy) in offsets.items():
        X = b * sx + (u - k[0, 2]) / f * z - t * motion[0]
        Y = b * sy + (v - k[1, 2]) / f * z - t * motion[1]
        chans = [0.5 + sum(0.06 * np.sin(2 * np.pi * (q[0] * X + q[1] * Y) + p) for q, p in waves[c * 8:(c + 1) * 8]) for c in range(3)]
        imgs[view] = (np.clip(np.stack(chans, -1), 0, 1) * 255).round().astype(np.uint8)
    return imgs, offsets, k


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--bench", default="preview")
    p.add_argument("--views", type=int, default=3)
    p.add_argument("--before", default=None, help="a git revision whose baselines.py / rayflow.py to time beside this tree's")
    p.add_argument("--repeat", type=int, default=1)
    p.add_argument("--only", default="a,global,local", help="methods to time: a, global, local")
    a = p.parse_args()
    d = load_definition(a.bench)
    w, h = d.recipe.resolution
    rows, cols = d.recipe.grid
    i0, offsets, k = light_field(rows, cols, w, h, 0)
    i1, _, _ = light_field(rows, cols, w, h, 1)
    rng = (0.5 * 0.9 * w * 0.05 / 2.0, 2.0 * 0.9 * w * 0.05 / 2.0)
    refs = list(offsets)[: a.views]
    eye = np.eye(4)
    impls = ([(f"before ({a.before})", module_at(a.before, "lfusd.evaluation", "baselines"), module_at(a.before, "lfusd.evaluation", "rayflow"))] if a.before else []) + [("after (this tree)", baselines, rayflow)]

    def group(v, imgs):
        return {u: imgs[u] for u in offsets if u[0] == v[0] or u[1] == v[1]}

    def run_a(bl, rf, v, pair):
        d1 = bl.plane_sweep_disparity(group(v, i1), offsets, offsets[v], rng, 48, 9, device="cpu")
        bl.scene_flow_from(d1, d1, bl.dis_flow(i0[v], i1[v]), k, eye, eye, 0.05)  # d1 stands in for t's (the previous pair's t+1)

    def run_b(bl, rf, v, pair, solver):
        d0 = bl.plane_sweep_disparity(group(v, i0), offsets, offsets[v], rng, 48, 9, device="cpu")
        extra = {"pair": pair} if pair is not None else {}
        rf.compose(d0, rf.ray_flow(i0, i1, offsets, v, k, d0, solver=solver, **extra), k, 0.05, eye, eye)

    methods = {"a": ("(a) DIS + plane sweep", run_a), "global": ("(b) ray flow, global", lambda *x: run_b(*x, "global")),
               "local": ("(b) ray flow, local", lambda *x: run_b(*x, "local"))}
    total = sum((s.frames - 1) * rows * cols for s in d.split("test"))
    n = rows * cols
    times = {}
    for key in a.only.split(","):
        name, fn = methods[key]
        for label, bl, rf in impls:
            has_pair = hasattr(rf, "LightFieldPair") and "pair" in inspect.signature(rf.ray_flow).parameters
            make_pair = (lambda: rf.LightFieldPair(i0, i1)) if has_pair and key != "a" else (lambda: None)
            fn(bl, rf, refs[0], make_pair())  # warm-up: imports, torch's first call, numba's compilation or cache
            best = (float("inf"), float("inf"))
            for _ in range(a.repeat):
                w0, c0 = time.perf_counter(), time.process_time()
                pair = make_pair()
                wp, cp = time.perf_counter() - w0, time.process_time() - c0  # once per frame pair: 1/n of it per view-frame
                w0, c0 = time.perf_counter(), time.process_time()
                for v in refs:
                    fn(bl, rf, v, pair)
                wall = (time.perf_counter() - w0) / len(refs) + wp / n
                cpu = (time.process_time() - c0) / len(refs) + cp / n
                best = (min(best[0], wall), min(best[1], cpu))
            times[(name, label)] = best
    print(f"{a.bench}: {rows}x{cols} views of {w}x{h}; {total} view-frames in its test split; {len(refs)} views timed, CPU, best of {a.repeat}")
    print(f"{'method':<24} {'implementation':<26} {'wall s/vf':>10} {'CPU s/vf':>9} {'before/after wall':>18} {'CPU':>7} {'test split, min':>16}")
    after = impls[-1][0]
    for (name, label), (wall, cpu) in times.items():
        if label == after and len(impls) > 1:
            before = times[(name, impls[0][0])]
            rs = f"{before[0] / wall:>17.2f}x {before[1] / cpu:>6.2f}x"
        else:
            rs = f"{'':>18} {'':>7}"
        print(f"{name:<24} {label:<26} {wall:>10.2f} {cpu:>9.2f} {rs} {total * wall / 60:>16.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
