"""`lfusd view OUT [--save FILE.rrd]`: the dataset's cameras, images, point clouds and scene flow in rerun."""

from __future__ import annotations

from . import args as argtypes


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "view", help="show a dataset in the rerun viewer (or save a .rrd recording)",
        description="Show dataset OUT in rerun: every camera posed with its image, the centre view's depth as a coloured "
                    "point cloud with scene-flow arrows, flow and segmentation images, on a timeline over frames.")
    p.add_argument("out", help="dataset folder (output of `lfusd render` / `lfusd render-video`)")
    p.add_argument("--save", default=None, metavar="FILE.rrd", help="write a recording to this new file instead of opening the viewer")
    argtypes.add_rig_option(p, "every")
    p.add_argument("--views", type=argtypes.view, nargs="+", default=None, metavar="ROW,COL", help="views to show (default: all)")
    p.add_argument("--frames", type=argtypes.frames, default=None, help="frames to show: N, A-B or a list 1-5,8 (default: all)")
    p.add_argument("--every", type=int, default=1, metavar="N", help="show every N-th of those frames (default 1)")
    p.add_argument("--max-points", type=int, default=20000, help="most points of the centre view's cloud per frame (default 20000)")
    p.add_argument("--max-arrows", type=int, default=1000, help="most scene-flow arrows per frame (default 1000)")
    p.add_argument("--arrow-scale", type=float, default=None, metavar="X",
                   help="draw scene-flow arrows X times their length (default: one scale per rig that makes them visible, printed)")
    p.add_argument("--lossless", action="store_true", help="log the images as raw pixels instead of JPEG (a recording several times larger)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..evaluation.view import view

    result = view(args.out, save=args.save, rig=args.rig, views=args.views, frames=args.frames, every=args.every,
                  max_points=args.max_points, max_arrows=args.max_arrows, arrow_scale=args.arrow_scale, lossless=args.lossless)
    for rig, c in result.items():
        arrows = f", drawn at {c['arrow_scale']:g}x their length" if c["arrows"] else ""
        print(f"{rig}: {c['frames']} frames, {c['images']} images, {c['points']} points, {c['arrows']} scene-flow arrows{arrows}")
    if args.save:
        print(f"recording written to {args.save}; open it with: rerun {args.save}")
    return 0
