"""`lfusd flow OUT`: re-derive the motion ground truth of a dataset from its raw passes."""

from __future__ import annotations

import argparse

from ..errors import LfusdError


def parse_frames(text: str | None) -> list[int] | None:
    """'1-5,8' -> [1, 2, 3, 4, 5, 8]; None stays None (all frames)."""
    if not text:
        return None
    out: list[int] = []
    for part in text.split(","):
        try:
            a, _, b = part.strip().partition("-")
            out.extend(range(int(a), int(b or a) + 1))
        except ValueError:
            raise LfusdError(f"frames {text!r} is not a list like 1-5,8") from None
    return out


def parse_views(items: list[str] | None) -> list[tuple[int, int]] | None:
    """['4,4', '0,0'] -> [(4, 4), (0, 0)]."""
    if not items:
        return None
    out = []
    for it in items:
        try:
            r, c = (int(x) for x in it.split(","))
        except ValueError:
            raise LfusdError(f"view {it!r} is not ROW,COL (e.g. 4,4)") from None
        out.append((r, c))
    return out


def open_dataset(path: str):
    from pathlib import Path

    if not Path(path).exists():
        raise LfusdError(f"dataset {path} does not exist; give the folder 'lfusd render' wrote")
    from lfusd import Dataset  # lazy: pulls in OpenEXR

    return Dataset(path)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("flow", help="re-derive optical flow, scene flow, disparity change and masks from raw passes")
    p.add_argument("out", help="dataset folder")
    p.add_argument("--frames", help="frames to derive, e.g. 1-10,15 (default: all)")
    p.add_argument("--views", nargs="+", metavar="R,C", help="views to derive (default: all)")
    p.set_defaults(func=handler)


def handler(args) -> int:
    from ..flow import MOTION_KEYS, derive_dataset_view

    ds = open_dataset(args.out)
    frames = parse_frames(args.frames) or [int(f) for f in ds.frames]
    views = parse_views(args.views) or [tuple(v) for v in ds.views]
    known = [int(f) for f in ds.frames]
    for f in frames:
        if f not in known:
            raise LfusdError(f"frame {f} is not in dataset {args.out} (frames {known[0]}-{known[-1]}); pick one of its frames")
    baseline = getattr(ds, "baseline", None)
    n = 0
    for view in views:
        cache: dict = {}
        for f in sorted(frames):
            motion = derive_dataset_view(ds, f, view, baseline=baseline, cache=cache)
            for key in MOTION_KEYS:
                ds.write(f, view, key, motion[key])
            n += 1
    print(f"derived motion for {n} view-frames of {args.out}")
    return 0
