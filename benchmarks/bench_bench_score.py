"""Time `lfusd bench score`'s work per view and frame on a rendered dataset, and extrapolate to a
benchmark's test split (default: preview's, from its definition).

    PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_bench_score.py DATASET [--bench preview]

Scores the dataset's own ground truth as the prediction (the oracle) with lfusd.bench.score's
per-view tally and angular consistency, as `bench score` does (reading included), and prints
seconds per view-frame at the dataset's resolution, scaled by pixels to the benchmark's.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lfusd.bench import score  # noqa: E402
from lfusd.bench.make import load_definition  # noqa: E402
from lfusd.data.dataset import Dataset  # noqa: E402


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("dataset")
    p.add_argument("--bench", default="preview")
    a = p.parse_args()
    ds = Dataset(a.dataset)
    n = 0
    t0 = time.perf_counter()
    for f in ds.frames[:-1]:
        truths, preds = {}, {}
        for v in ds.views:
            truths[v] = score._truth(ds, f, v)
            preds[v] = {"flow": np.nan_to_num(truths[v]["flow_fwd"]), "disparity": truths[v]["disparity"],
                        "disparity_change": np.nan_to_num(truths[v]["disparity_change"]), "scene_flow": np.nan_to_num(truths[v]["scene_flow"])}
            score.view_tally(preds[v], truths[v])
            n += 1
        score.angular(ds, f, truths, preds)
    dt = time.perf_counter() - t0
    d = load_definition(a.bench)
    test = d.split("test")
    w, h = d.recipe.resolution
    views = d.recipe.grid[0] * d.recipe.grid[1]
    total = sum((s.frames - 1) * views for s in test)
    scale = (w * h) / (ds.rig.width * ds.rig.height)
    print(f"{n} view-frames of {ds.rig.width}x{ds.rig.height} in {dt:.1f} s: {dt / n:.3f} s each")
    print(f"{a.bench} test split: {total} view-frames of {w}x{h}: about {total * dt / n * scale / 60:.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())
