"""`lfusd verify OUT`: check a dataset's ground truth against the stage's own geometry."""

from __future__ import annotations

import argparse
import sys

from .flow import open_datasets, parse_frames, parse_views, select


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("verify", help="verify depth, instances, flow and scene flow against Open3D ray casting of the stage")
    p.add_argument("out", help="dataset folder")
    p.add_argument("--frames", help="frames to verify, e.g. 1-3 (default: all)")
    p.add_argument("--views", nargs="+", metavar="R,C", help="views to verify (default: all)")
    p.add_argument("--stage", help="the stage the dataset was rendered from (default: the one its manifest records)")
    p.add_argument("--rig", help="rig to verify (default: every rig of the dataset)")
    p.add_argument("--threshold", nargs="+", metavar="KEY=VALUE", help="override limits, e.g. occlusion_fwd=0.02 flow_fwd=0.1")
    p.set_defaults(func=handler)


def parse_thresholds(items: list[str] | None) -> dict[str, float]:
    """['flow_fwd=0.1'] -> {'flow_fwd': 0.1}; keys are those of lfusd.truth.verify.THRESHOLDS."""
    from ..errors import LfusdError
    from ..truth.verify import THRESHOLDS

    out = {}
    for it in items or []:
        key, _, value = it.partition("=")
        if key not in THRESHOLDS:
            raise LfusdError(f"unknown threshold {key!r}; use one of {', '.join(THRESHOLDS)}")
        try:
            out[key] = float(value)
        except ValueError:
            raise LfusdError(f"threshold {it!r} is not KEY=NUMBER") from None
    return out


def handler(args) -> int:
    from ..truth.verify import verify_dataset

    thresholds = parse_thresholds(getattr(args, "threshold", None))
    ok = True
    for ds in open_datasets(args.out, getattr(args, "rig", None)):
        frames, views = select(ds, parse_frames(args.frames), parse_views(args.views), args.out)
        report = verify_dataset(
            ds, stage_path=args.stage, frames=frames, views=views, thresholds=thresholds,
            progress=lambda f, v: print(f"verifying frame {f} view {v[0]},{v[1]}", file=sys.stderr),
        )
        name = getattr(ds, "rig_name", None)
        if name:
            print(f"rig {name}:")
        print(report.table())
        for line in report.failures():
            print(f"FAIL {line}")
        ok &= report.ok
    if ok:
        print("verify: all checks passed")
    return 0 if ok else 1
