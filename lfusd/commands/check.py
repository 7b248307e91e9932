"""`lfusd check STAGE`: semantic constraints at every frame, plus USD's own validators."""

from __future__ import annotations

import sys


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
    from ..author.rules import check_stage

    found = check_stage(args.stage, args.rules, usd=not args.no_usd_validation, coverage=not args.no_coverage)
    for line in found.problems + found.footage:
        print(line)
    if found.problems:
        print(found.summary(), file=sys.stderr)
        return 1
    print(found.summary())
    return 0
