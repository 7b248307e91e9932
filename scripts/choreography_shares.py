"""Choreography goal shares of a dynamic template over seeds, as tests/author/test_choreography.py
measures them (reference 9x9 rigs, 24 frames, 2 rigs, measured at 32 px across), optionally with
catalogues drawn in:

    python scripts/choreography_shares.py street [--seeds 10] [--catalogue FILE.json ...]

Prints per rig whether it sees a mover pass behind a static object, then the shares: rigs with
that occlusion, rigs whose nearest surface gives >= 150 px per step at the reference rig, and the
rigs short of the motion/person goal.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from lfusd.author.choreography import DISPARITY_GOAL, GOAL_FRAMES, GOAL_PERSON, rig_footage
from lfusd.author.scenes import generate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("template")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--catalogue", type=Path, action="append", default=[])
    args = ap.parse_args()
    occluded, disparity, short = [], [], []
    t0 = time.time()
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seeds):
            stage = generate(args.template, Path(tmp) / f"s{seed}.usda", seed, frames=24, rigs=2, grid=(9, 9),
                             resolution=(64, 64), dynamic=True, catalogues=args.catalogue)
            for name, f in sorted(rig_footage(stage, width=32).items()):
                occluded.append(bool(f.occluded.any()))
                disparity.append(f.reference_disparity()[1])
                if f.in_view < GOAL_FRAMES or f.person_in_view < GOAL_PERSON:
                    short.append(f"seed {seed} {name}")
                print(f"seed {seed} {name}: occlusion {occluded[-1]}, {disparity[-1]:.0f} px per step at the reference rig")
    d = np.array(disparity)
    print(f"{args.template}: {np.mean(occluded):.0%} of {len(occluded)} rigs see a mover pass behind a static object; "
          f"{np.mean(d >= DISPARITY_GOAL[0]):.0%} >= {DISPARITY_GOAL[0]:.0f} px; short of the goal: {short or 'none'} "
          f"({time.time() - t0:.0f} s)")


if __name__ == "__main__":
    main()
