"""`lfusd preview OUT`: colour-wheel flow, disparity/depth maps, segmentation overlays, a contact sheet and an MP4."""

from __future__ import annotations

from pathlib import Path

from . import args as argtypes


def register(subparsers) -> None:
    p = subparsers.add_parser("preview", help="write preview pictures and a video of a dataset", description="Write preview images of dataset OUT (default into OUT/preview).")
    p.add_argument("out", help="dataset folder (output of `lfusd render`)")
    p.add_argument("-o", "--dest", default=None, help="folder for the pictures (default: OUT/preview)")
    p.add_argument("--frame", type=int, default=None, help="frame for the still pictures (default: the first)")
    p.add_argument("--no-video", action="store_true", help="skip the MP4 of the centre view over time")
    p.add_argument("--fps", type=float, default=12.0, help="video frame rate")
    argtypes.add_rig_option(p, "dataset")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..data.dataset import open_dataset
    from ..evaluation.preview import preview

    ds = open_dataset(args.out, args.rig)
    dest = Path(args.dest) if args.dest else Path(args.out) / "preview"
    files = preview(ds, dest, frame=args.frame, video=not args.no_video, fps=args.fps)
    for f in files:
        print(f)
    return 0
