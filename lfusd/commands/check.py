"""`lfusd check STAGE`: semantic constraints at every frame, plus USD's own validators."""

from __future__ import annotations

import logging
import sys
import time

log = logging.getLogger(__name__)


def register(sub) -> None:
    p = sub.add_parser("check", help="check a stage's semantic constraints and USD validity",
                       description="Evaluate every constraint (default rulebook, rules file, stage rules) at every "
                                   "frame of the stage's range and run USD's validators; one line per violation. "
                                   "Then, per rig, what its centre view sees move (ray cast at 64 pixels across): the "
                                   "fraction of frames with moving objects over 5%% of the view, their mean and "
                                   "minimum coverage, the fraction with a person in view, the fraction in which a mover passes "
                                   "behind a static object, and the disparity range per baseline step, at the rig's own "
                                   "size and at the reference rig (9x9 views, 0.125 m, 1024x1024, 39 mm lens) at the "
                                   "same pose, so a preview-size stage states what its full-size render would give.")
    p.add_argument("stage", help="the .usda/.usdc/.usd stage")
    p.add_argument("--rules", metavar="FILE", help="extra rules (JSON or TOML) overriding the default rulebook")
    p.add_argument("--no-usd-validation", action="store_true", help="skip pxr.UsdValidation's validators")
    p.add_argument("--no-coverage", action="store_true",
                   help="skip the per-rig report of motion in view and disparity range (ray casting every frame)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..author.rules import Checker, load_rules_file, usd_validation
    from ..author.stage import frame_range, open_stage

    t0 = time.perf_counter()
    stage = open_stage(args.stage)
    from ..author.geometry import StageGeometry, check_geometry

    # a broken mesh is one line (exit 2), before any rule evaluates it; implicit shapes are reported
    # as violations below, with everything else checked
    check_geometry(StageGeometry(stage), implicit=False)
    file_rules = load_rules_file(args.rules) if args.rules else None
    checker = Checker(stage, file_rules)
    if not checker.labelled:
        log.warning("stage %s has no class labels (UsdSemantics LabelsAPI, taxonomy 'class'); "
                    "the label rulebook cannot apply, checking the rest", args.stage)
    violations = checker.check()
    lines = [v.line() for v in violations]
    if not args.no_usd_validation:
        lines += usd_validation(stage)
    for line in lines:
        print(line)
    if not args.no_coverage:
        from ..author.choreography import rig_footage

        for footage in rig_footage(stage).values():
            print(footage.line())
    first, last = frame_range(stage)
    n_rules = sum(len([k for k in r.rules if k not in ("draft", "tolerance")]) for r in checker.rules)
    summary = (f"{args.stage}: {len(checker.labelled)} labelled objects, {n_rules} rules, frames {first}-{last}"
               f" ({time.perf_counter() - t0:.1f} s)")
    if lines:
        print(f"{summary}: {len(lines)} violation{'s' if len(lines) != 1 else ''}", file=sys.stderr)
        return 1
    print(f"{summary}: all constraints hold" + ("" if args.no_usd_validation else ", USD validation clean"))
    return 0
