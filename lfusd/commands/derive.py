"""`lfusd derive OUT`: derive every motion key of a dataset again from its raw passes.

``lfusd flow`` is the old name, kept as an alias that says so on stderr.
"""

from __future__ import annotations

import logging

from . import args as argtypes

log = logging.getLogger(__name__)
DEPRECATED = {"flow": "derive"}  # old command name -> new


def register(sub) -> None:
    p = sub.add_parser("derive", aliases=list(DEPRECATED),
                       help="derive the motion keys (optical flow, scene flow, disparity change, masks) again from raw passes")
    p.add_argument("out", help="dataset folder")
    p.add_argument("--frames", type=argtypes.frames, help="frames to derive, e.g. 1-10,15 (default: all)")
    p.add_argument("--views", nargs="+", type=argtypes.view, metavar="R,C", help="views to derive (default: all)")
    argtypes.add_rig_option(p, "every")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..truth.derive import derive_dataset

    if args.command in DEPRECATED:
        log.warning("'lfusd %s' is deprecated; use 'lfusd %s' (same arguments)", args.command, DEPRECATED[args.command])
    rigs = None if args.rig in (None, "all") else [args.rig]
    n = derive_dataset(args.out, rigs, args.frames, views=args.views, overwrite=True)
    print(f"lfusd: {args.out}: motion derived for {n} views")
    return 0
