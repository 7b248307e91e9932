"""CPU time of the disparity networks of flow/train_disparity.py, old (``distg``: the DistgDisp-like
DisparityNet) beside new (``star``: StarDisparityNet, issue 36), in one run:

- flow/predict_disparity.py's network pass on a 9x9 light field of 512x512 views (HCI's size),
  beside the 120 s budget of issue 36 (2 CPU cores);
- one training step (forward, backward, Adam) at the preview recipe's batch and crop
  (train_disparity.py's full-size defaults: batch 8, 64x64 crops of all 81 views).

    .venv/bin/python benchmarks/bench_predict_disparity.py [--size 512] [--configs distg star] [--tile 128 --overlap 32] [--threads 2]

Full-size configurations (train_disparity.FULL_DISTG and FULL), random weights (the time does not
depend on them), random views. Prints per network the wall and process CPU seconds and the ratio
old / new; the machine's load average is printed too, as a shared machine's wall time means little.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "flow"))
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import net_timing  # noqa: E402
import predict_disparity  # noqa: E402
import train_disparity  # noqa: E402

BUDGET_S = 120.0
NET = ("disparities", "channels", "blocks", "cost_channels")


def config_of(name: str, n: int) -> dict:
    c = train_disparity.FULL_DISTG if name == "distg" else train_disparity.FULL
    return {"ang": n, "d_min": -4.4, "d_max": 4.4, "arch": name, **{k: c[k] for k in NET}}


def main() -> int:
    ap = argparse.ArgumentParser()
    net_timing.args(ap)
    ap.add_argument("--configs", nargs="+", default=["distg", "star"], choices=["distg", "star"])
    ap.add_argument("--tile", type=int, default=128)
    ap.add_argument("--overlap", type=int, default=32)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    torch.manual_seed(0)
    n = 9
    rng = np.random.default_rng(0)
    rows, cols = np.divmod(np.arange(n * n), n)
    offsets = np.stack([cols - 4, rows - 4], 1).astype(np.float32)
    views = None if a.no_predict else rng.random((n * n, a.size, a.size, 3), dtype=np.float32)
    b, crop = train_disparity.FULL["batch"], train_disparity.FULL["crop"]
    print(f"{n}x{n} views of {a.size}x{a.size}, tiles {a.tile} + {a.overlap} context; training step: batch {b} of {crop}x{crop} crops; "
          f"{a.threads} threads; {net_timing.load()}")
    res = {}
    for name in a.configs:
        model = train_disparity.build(config_of(name, n))
        x = torch.rand(b, n * n, 3, crop, crop)
        rel = torch.from_numpy(offsets)[None].expand(b, -1, -1).contiguous()
        gt = torch.rand(b, crop, crop) * 8 - 4
        r = res[name] = net_timing.measure(model, lambda: (model(x, rel) - gt).abs().mean(), a.steps,
                                           None if views is None else lambda: predict_disparity.predict(model, views, offsets, a.tile, a.overlap))
        net_timing.report(name, r, "" if views is None else f", wall / budget {r['pred_wall'] / BUDGET_S:5.2f}x")
    if len(res) == 2:
        o, s = res["distg"], res["star"]
        print(f"old / new CPU-s: training step {o['step_cpu'] / s['step_cpu']:.1f}x"
              + ("" if views is None else f", predict {o['pred_cpu'] / s['pred_cpu']:.1f}x"))
    if "star" in res:
        s = res["star"]
        print(f"star: 3 h of training on these cores is about {int(3 * 3600 / s['step_wall'])} steps at this step wall time")
    return 0


if __name__ == "__main__":
    sys.exit(main())
