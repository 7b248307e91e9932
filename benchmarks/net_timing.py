"""Timing shared by the benchmarks of flow/'s networks (bench_asr.py, bench_predict_disparity.py).

Per network, ``measure`` times one training step (forward, backward, Adam on one fixed batch; one
untimed step first, then the mean of ``steps``) and, when given, one prediction pass in eval mode, in
wall and process CPU seconds; ``report`` prints them on one line with the machine's load average, as a
shared machine's wall time means little. ``args`` adds the options these benchmarks share.
"""

from __future__ import annotations

import argparse
import os
import time

import torch


def args(ap: argparse.ArgumentParser) -> None:
    """--size (views' side), --threads, --steps and --no-predict."""
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--steps", type=int, default=3, help="training steps timed (after one untimed)")
    ap.add_argument("--no-predict", action="store_true", help="time the training step only")


def load() -> str:
    """The machine's load average beside its CPU count."""
    return f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs"


def timed(fn) -> tuple[float, float]:
    """(wall, process CPU) seconds of ``fn()``."""
    t0, c0 = time.time(), time.process_time()
    fn()
    return time.time() - t0, time.process_time() - c0


def measure(model: torch.nn.Module, loss, steps: int, predict=None) -> dict:
    """{params, step_wall, step_cpu[, pred_wall, pred_cpu]}: the mean training step of ``loss()`` (the
    model's loss on a fixed batch) over ``steps`` after an untimed one, and ``predict()`` once in eval mode."""
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)

    def step():
        value = loss()
        opt.zero_grad()
        value.backward()
        opt.step()

    model.train()
    step()
    w, c = timed(lambda: [step() for _ in range(steps)])
    r = {"params": sum(p.numel() for p in model.parameters()), "step_wall": w / steps, "step_cpu": c / steps}
    if predict is not None:
        model.eval()
        r["pred_wall"], r["pred_cpu"] = timed(predict)
    return r


def report(name: str, r: dict, extra: str = "") -> None:
    """One line of ``measure``'s result (``extra`` after the prediction's times) and the load average now."""
    line = f"{name:5s} {r['params']:7d} parameters: train step wall {r['step_wall']:6.2f} s, CPU {r['step_cpu']:6.2f} s"
    if "pred_wall" in r:
        line += f"; predict wall {r['pred_wall']:7.1f} s, CPU {r['pred_cpu']:7.1f} s{extra}"
    print(line + f" (load average now {os.getloadavg()[0]:.1f})", flush=True)
