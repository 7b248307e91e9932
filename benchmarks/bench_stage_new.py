"""Generation time per scene and `lfusd check` of every generated scene (seeds across templates).

    .venv/bin/python benchmarks/bench_stage_new.py [--scenes 50] [--dynamic] [--out DIR]

Scene k uses template TEMPLATES[k % len(TEMPLATES)] with seed k and the defaults of `lfusd stage new`
(150 frames, 10 rigs of 9x9 views at 1024x1024). Prints per-template and overall times and the
number of scenes that pass the check; exits 1 if any fails. ``--dynamic`` generates the dynamic
variants (goal: <= 5 s per scene) and also measures every rig's centre view from the stage
(lfusd.author.choreography, 32 pixels across, every frame): the fraction of rigs that meet the
motion goal (moving objects over 5 % of the view in >= 90 % of the frames, a person in >= 50 %).

Generation is single-threaded work: run one scene per core (a dataset recipe runs scenes in
parallel processes); BLAS threads are limited to one here (OPENBLAS_NUM_THREADS, unless set), as
two BLAS threads per process on a shared 2-core machine spin against each other.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before NumPy loads

import argparse  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from pxr import Usd  # noqa: E402

from lfusd.author.choreography import rig_footage  # noqa: E402
from lfusd.author.rules import Checker, usd_validation  # noqa: E402
from lfusd.author.scenes import TEMPLATES, generate  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", type=int, default=50)
    ap.add_argument("--dynamic", action="store_true", help="the dynamic variants, with the motion goal per rig")
    ap.add_argument("--out", default=None, help="folder for the stages (default: a temporary one)")
    args = ap.parse_args()
    out = Path(args.out or tempfile.mkdtemp(prefix="lfusd_bench_"))
    gen, chk, failures = {t: [] for t in TEMPLATES}, [], []
    rigs_total, rigs_ok, worst = 0, 0, []
    generate("room", out / "warm_up.usda", 0, frames=2, rigs=1, dynamic=args.dynamic)  # imports and first-use caches, not timed
    for k in range(args.scenes):
        template = list(TEMPLATES)[k % len(TEMPLATES)]
        path = out / f"{template}_{k:02d}.usda"
        t0 = time.perf_counter()
        generate(template, path, k, dynamic=args.dynamic)
        gen[template].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        stage = Usd.Stage.Open(str(path))
        problems = [v.line() for v in Checker(stage).check()] + usd_validation(stage)
        chk.append(time.perf_counter() - t0)
        if problems:
            failures.append((path, problems))
            print(f"FAIL {path}: {problems[:3]}", flush=True)
        if args.dynamic:
            for foot in rig_footage(stage, width=32).values():
                rigs_total += 1
                rigs_ok += foot.meets_goal()
                worst.append((foot.in_view, foot.person_in_view, f"{path.name} {foot.line()}"))
        print(f"{path.name}: {gen[template][-1]:.2f} s", flush=True)
    every = [t for v in gen.values() for t in v]
    kind = "dynamic" if args.dynamic else "static"
    for t in TEMPLATES:
        if gen[t]:
            print(f"stage new {kind} {t:7s}: {len(gen[t]):2d} scenes, mean {statistics.mean(gen[t]):.2f} s, max {max(gen[t]):.2f} s")
    print(f"stage new {kind} all    : {len(every)} scenes, mean {statistics.mean(every):.2f} s, max {max(every):.2f} s")
    print(f"check            : mean {statistics.mean(chk):.2f} s, max {max(chk):.2f} s")
    print(f"passed check     : {len(every) - len(failures)}/{len(every)}")
    if args.dynamic:
        print(f"motion goal      : {rigs_ok}/{rigs_total} rigs")
        for in_view, person, line in sorted(worst)[:3]:
            print(f"  weakest: {line}")
    return 1 if failures or (args.dynamic and rigs_ok < rigs_total) else 0


if __name__ == "__main__":
    sys.exit(main())
