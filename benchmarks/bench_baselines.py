"""Time the benchmark's baselines (a) DIS + plane sweep and (b) ray flow (global and local) per view
and frame at a benchmark's size (default preview: 5x5 views, 128x128), side by side, and
extrapolate to its test split.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_baselines.py [--bench preview] [--views 3]

The input is a synthetic light-field pair (a textured plane moving in 3-D, ray-traced in closed
form, as in tests/evaluation/test_rayflow.py), so no render is needed; the work per view-frame is
what `lfusd bench baseline` does (the disparity of (a) at t+1 counted: it sweeps both frames).
``--views`` reference views are timed per method (each one's work is independent of which view).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lfusd.bench.make import load_definition  # noqa: E402
from lfusd.evaluation.baselines import dis_flow, plane_sweep_disparity, scene_flow_from  # noqa: E402
from lfusd.evaluation.rayflow import compose, ray_flow  # noqa: E402


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
    a = p.parse_args()
    d = load_definition(a.bench)
    w, h = d.recipe.resolution
    rows, cols = d.recipe.grid
    i0, offsets, k = light_field(rows, cols, w, h, 0)
    i1, _, _ = light_field(rows, cols, w, h, 1)
    rng = (0.5 * 0.9 * w * 0.05 / 2.0, 2.0 * 0.9 * w * 0.05 / 2.0)
    refs = list(offsets)[: a.views]
    eye = np.eye(4)

    def group(v, imgs):
        return {u: imgs[u] for u in offsets if u[0] == v[0] or u[1] == v[1]}

    def run_a(v):
        d0 = plane_sweep_disparity(group(v, i0), offsets, offsets[v], rng, 48, 9, device="cpu")
        d1 = plane_sweep_disparity(group(v, i1), offsets, offsets[v], rng, 48, 9, device="cpu")
        scene_flow_from(d0, d1, dis_flow(i0[v], i1[v]), k, eye, eye, 0.05)

    def run_b(v, solver):
        d0 = plane_sweep_disparity(group(v, i0), offsets, offsets[v], rng, 48, 9, device="cpu")
        compose(d0, ray_flow(i0, i1, offsets, v, k, d0, solver=solver), k, 0.05, eye, eye)

    methods = {"(a) DIS + plane sweep": run_a, "(b) ray flow, global": lambda v: run_b(v, "global"),
               "(b) ray flow, local": lambda v: run_b(v, "local")}
    total = sum((s.frames - 1) * rows * cols for s in d.split("test"))
    times = {}
    for name, fn in methods.items():
        fn(refs[0])  # warm-up: imports, torch's first call
        t0 = time.perf_counter()
        for v in refs:
            fn(v)
        times[name] = (time.perf_counter() - t0) / len(refs)
    base = times["(a) DIS + plane sweep"]
    print(f"{a.bench}: {rows}x{cols} views of {w}x{h}; {total} view-frames in its test split; {len(refs)} views timed, CPU")
    print(f"{'method':<24} {'s / view-frame':>15} {'vs (a)':>8} {'test split, min':>16}")
    for name, t in times.items():
        print(f"{name:<24} {t:>15.2f} {t / base:>7.2f}x {total * t / 60:>16.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
