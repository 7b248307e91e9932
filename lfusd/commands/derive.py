"""`lfusd flow OUT`: re-derive the motion ground truth of a dataset from its raw passes."""

from __future__ import annotations

import argparse

from . import args as argtypes


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("flow", help="re-derive optical flow, scene flow, disparity change and masks from raw passes")
    p.add_argument("out", help="dataset folder")
    p.add_argument("--frames", type=argtypes.frames, help="frames to derive, e.g. 1-10,15 (default: all)")
    p.add_argument("--views", nargs="+", type=argtypes.view, metavar="R,C", help="views to derive (default: all)")
    p.add_argument("--rig", help="rig to derive (default: every rig of the dataset)")
    p.set_defaults(func=handler)


def handler(args) -> int:
    from ..truth.derive import derive_dataset

    rigs = None if args.rig in (None, "all") else [args.rig]
    n = derive_dataset(args.out, rigs, args.frames, views=args.views, overwrite=True)
    print(f"lfusd: {args.out}: motion derived for {n} views")
    return 0
