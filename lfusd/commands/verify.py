"""`lfusd verify OUT`: check a dataset's ground truth against the stage's own geometry;
`lfusd verify OUT --integrity`: check every view's files against its completion record only."""

from __future__ import annotations

import argparse
import sys

from . import args as argtypes


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("verify", help="verify depth, instances, flow and scene flow against Open3D ray casting of the stage")
    p.add_argument("out", help="dataset folder")
    p.add_argument("--frames", type=argtypes.frames, help="frames to verify, e.g. 1-3 or 1-5,8 (default: all)")
    p.add_argument("--views", nargs="+", type=argtypes.view, metavar="R,C", help="views to verify (default: all)")
    p.add_argument("--stage", help="the stage the dataset was rendered from (default: the one its manifest records)")
    argtypes.add_rig_option(p, "every")
    p.add_argument("--threshold", nargs="+", type=argtypes.threshold, metavar="KEY=VALUE",
                   help="override limits, e.g. occlusion_fwd=0.02 flow_fwd=0.1")
    p.add_argument("--integrity", action="store_true",
                   help="only check every view's files against its completion record (sizes and checksums), no ray casting")
    p.set_defaults(func=run)


def progress(frame: int, view: tuple[int, int]) -> None:
    """With -v: one line per view as it is verified."""
    print(f"verifying frame {frame} view {view[0]},{view[1]}", file=sys.stderr)


def show(reports: dict) -> int:
    """Print each rig's table and failures; the exit code: 0 all passed, 1 a check failed."""
    for name, report in reports.items():
        if name:
            print(f"rig {name}:")
        print(report.table())
        for line in report.failures():
            print(f"FAIL {line}")
    ok = all(r.ok for r in reports.values())
    if ok:
        compared = [n for r in reports.values() for n in r.compared().values()]
        print(f"verify: all checks passed ({sum(compared)} px compared over {len(compared)} key checks)")
    return 0 if ok else 1


def integrity(out: str, rig: str | None) -> int:
    """Print one FAIL line per view whose files do not match its record; 0 when all match, else 1."""
    from ..data.integrity import check_dataset

    checked, problems = check_dataset(out, rig)
    for p in problems:
        print(f"FAIL {p}")
    if problems:
        views = len({(p.rig, p.frame, p.view) for p in problems})
        print(f"verify --integrity: {views} of {checked} views damaged or incomplete; rerun the render command to repair them "
              "('lfusd derive' for motion.npz alone)")
        return 1
    print(f"verify --integrity: all {checked} views match their records")
    return 0


def run(args) -> int:
    from ..truth.verify import verify

    if args.integrity:
        return integrity(args.out, args.rig)

    # a line per view only when asked (-v): a 9x9 grid of 150 frames would print 12150 lines
    reports = verify(args.out, stage=args.stage, rig=args.rig, frames=args.frames, views=args.views,
                     thresholds=dict(args.threshold or []), progress=progress if getattr(args, "verbose", 0) else None)
    return show(reports)
