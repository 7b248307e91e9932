"""Generation time per scene and `lfusd check` of every generated scene (seeds across templates).

    .venv/bin/python benchmarks/bench_stage_new.py [--scenes 50] [--out DIR]

Scene k uses template TEMPLATES[k % 4] with seed k and the defaults of `lfusd stage new`
(150 frames, 10 rigs of 9x9 views at 1024x1024). Prints per-template and overall times and the
number of scenes that pass the check; exits 1 if any fails.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

from pxr import Usd

from lfusd.author.rules import Checker, usd_validation
from lfusd.author.scenes import TEMPLATES, generate


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", type=int, default=50)
    ap.add_argument("--out", default=None, help="folder for the stages (default: a temporary one)")
    args = ap.parse_args()
    out = Path(args.out or tempfile.mkdtemp(prefix="lfusd_bench_"))
    gen, chk, failures = {t: [] for t in TEMPLATES}, [], []
    for k in range(args.scenes):
        template = TEMPLATES[k % len(TEMPLATES)]
        path = out / f"{template}_{k:02d}.usda"
        t0 = time.perf_counter()
        generate(template, path, k)
        gen[template].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        stage = Usd.Stage.Open(str(path))
        problems = [v.line() for v in Checker(stage).check()] + usd_validation(stage)
        chk.append(time.perf_counter() - t0)
        if problems:
            failures.append((path, problems))
            print(f"FAIL {path}: {problems[:3]}", flush=True)
    every = [t for v in gen.values() for t in v]
    for t in TEMPLATES:
        if gen[t]:
            print(f"stage new {t:7s}: {len(gen[t]):2d} scenes, mean {statistics.mean(gen[t]):.2f} s, max {max(gen[t]):.2f} s")
    print(f"stage new all    : {len(every)} scenes, mean {statistics.mean(every):.2f} s, max {max(every):.2f} s")
    print(f"check            : mean {statistics.mean(chk):.2f} s, max {max(chk):.2f} s")
    print(f"passed check     : {len(every) - len(failures)}/{len(every)}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
