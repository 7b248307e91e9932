"""`lfusd flow OUT`: re-derive the motion ground truth of a dataset from its raw passes."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

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


def open_datasets(path: str, rig: str | None = None) -> list:
    """The dataset of each rig ``rig`` names in the folder (None or 'all': every rig)."""
    if not Path(path).exists():
        raise LfusdError(f"dataset {path} does not exist; give the folder 'lfusd render-video' wrote")
    from lfusd import Dataset  # lazy: pulls in OpenEXR

    if rig not in (None, "all"):
        return [Dataset(path, rig=rig)]
    manifest = Path(path) / "manifest.json"
    if not manifest.is_file():
        return [Dataset(path)]  # raises the reader's own error naming the folder
    return [Dataset(path, rig=r) for r in json.loads(manifest.read_text())["rigs"]]


def select(ds, frames: list[int] | None, views: list[tuple[int, int]] | None, out: str):
    """Frames and views to process, checked against the dataset (LfusdError naming the bad one)."""
    known = [int(f) for f in ds.frames]
    if not known:
        raise LfusdError(f"dataset {out} has no completely rendered frame; finish the render first")
    frames = frames or known
    for f in frames:
        if f not in known:
            raise LfusdError(f"frame {f} is not rendered in dataset {out} (frames {known[0]}-{known[-1]}); pick one of its frames")
    all_views = [tuple(v) for v in ds.views]
    views = views or all_views
    for v in views:
        if tuple(v) not in all_views:
            raise LfusdError(f"view {v[0]},{v[1]} is not in dataset {out}; its views are rows and cols of the rig grid")
    return frames, views


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("flow", help="re-derive optical flow, scene flow, disparity change and masks from raw passes")
    p.add_argument("out", help="dataset folder")
    p.add_argument("--frames", help="frames to derive, e.g. 1-10,15 (default: all)")
    p.add_argument("--views", nargs="+", metavar="R,C", help="views to derive (default: all)")
    p.add_argument("--rig", help="rig to derive (default: every rig of the dataset)")
    p.set_defaults(func=handler)


def handler(args) -> int:
    n = 0
    for ds in open_datasets(args.out, getattr(args, "rig", None)):
        frames, views = select(ds, parse_frames(args.frames), parse_views(args.views), args.out)
        for view in views:
            for f in sorted(frames):
                write_view(ds, f, view)
                n += 1
    print(f"lfusd: {args.out}: motion derived for {n} views")
    return 0


def write_view(ds, frame: int, view: tuple[int, int]) -> None:
    """Derive and store one view's motion keys (motion.npz beside its raw passes)."""
    from ..truth.derive import write_motion

    write_motion(ds, frame, view)
