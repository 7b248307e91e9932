"""Time of flow/predict_disparity.py's network pass on a 9x9 light field of 512x512 views (HCI's size),
beside the 120 s budget of issue 36 (2 CPU cores).

    .venv/bin/python benchmarks/bench_predict_disparity.py [--size 512] [--configs tiny full] [--tile 128 --overlap 32] [--threads 2]

The network is flow/train_disparity.py's DisparityNet at its --tiny and full configurations, with
random weights (the time does not depend on them), on random views. Prints per configuration the
wall and process CPU seconds and wall / budget; the machine's load average is printed too, as a
shared machine's wall time means little.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "flow"))
sys.path.insert(0, str(ROOT))

import predict_disparity  # noqa: E402
import train_disparity  # noqa: E402

BUDGET_S = 120.0


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--configs", nargs="+", default=["tiny", "full"], choices=["tiny", "full"])
    ap.add_argument("--tile", type=int, default=128)
    ap.add_argument("--overlap", type=int, default=32)
    ap.add_argument("--threads", type=int, default=2)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    n = 9
    views = np.random.default_rng(0).random((n * n, a.size, a.size, 3), dtype=np.float32)
    rows, cols = np.divmod(np.arange(n * n), n)
    offsets = np.stack([cols - 4, rows - 4], 1).astype(np.float32)
    print(f"{n}x{n} views of {a.size}x{a.size}, tiles {a.tile} + {a.overlap} context, {a.threads} threads; "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    for name in a.configs:
        c = train_disparity.TINY if name == "tiny" else train_disparity.FULL
        config = {"ang": n, "d_min": -4.4, "d_max": 4.4, **{k: c[k] for k in ("disparities", "channels", "blocks", "cost_channels")}}
        model = train_disparity.build(config).eval()
        t0, c0 = time.time(), time.process_time()
        predict_disparity.predict(model, views, offsets, a.tile, a.overlap)
        wall, cpu = time.time() - t0, time.process_time() - c0
        print(f"{name:5s} {sum(p.numel() for p in model.parameters()):7d} parameters: wall {wall:7.1f} s, CPU {cpu:7.1f} s, "
              f"wall / budget {wall / BUDGET_S:5.2f}x (load average now {os.getloadavg()[0]:.1f})", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
