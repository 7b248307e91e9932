"""CPU time of the angular super-resolution network (flow/train_asr.py ASRNet, 2x2 -> 7x7), to size
the CPU preview training of issue 36 item 5, full size beside the --tiny size, in one run:

- one training step (forward, backward, Adam) at train_asr.py's full-size defaults (batch 8 of
  64x64 crops; 64 channels, 4 Distg blocks) and at the --tiny network's width (32 channels, 1 block)
  on the same batch;
- flow/predict_views.py's network pass on the corners of a 7x7 grid of 512x512 views (HCI's size).

    .venv/bin/python benchmarks/bench_asr.py [--size 512] [--threads 2] [--steps 3] [--no-predict]

Random weights (the time does not depend on them) and random views. Prints per configuration the
wall and process CPU seconds, the ratio full / tiny, and how many full-size steps 3 hours of these
cores hold at the measured wall time; the machine's load average is printed too, as a shared
machine's wall time means little.
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
import predict_views  # noqa: E402
import train_asr  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser()
    net_timing.args(ap)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    torch.manual_seed(0)
    full = train_asr.FULL
    n, b, crop = full["n"], full["batch"], full["crop"]
    configs = {"full": {"n": n, "channels": full["channels"], "blocks": full["blocks"]},
               "tiny": {"n": n, "channels": train_asr.TINY["channels"], "blocks": train_asr.TINY["blocks"]}}
    print(f"2x2 -> {n}x{n}; training step: batch {b} of {crop}x{crop} crops; predict: {a.size}x{a.size}; {a.threads} threads; {net_timing.load()}")
    corners = None if a.no_predict else np.random.default_rng(0).random((4, a.size, a.size, 3), dtype=np.float32)
    res = {}
    for name, config in configs.items():
        model = train_asr.build(config)
        x, target = torch.rand(b, 4, 3, crop, crop), torch.rand(b, n * n, 3, crop, crop)
        res[name] = net_timing.measure(model, lambda: (model(x) - target).abs().mean(), a.steps,
                                       None if corners is None else lambda: predict_views.predict(model, corners))
        net_timing.report(name, res[name])
    f, t = res["full"], res["tiny"]
    print(f"full / tiny CPU-s: training step {f['step_cpu'] / t['step_cpu']:.1f}x"
          + ("" if corners is None else f", predict {f['pred_cpu'] / t['pred_cpu']:.1f}x"))
    print(f"full: 3 h on these cores hold about {int(3 * 3600 / f['step_wall'])} steps at this step wall time")
    return 0


if __name__ == "__main__":
    sys.exit(main())
