"""`lfusd render-video`: every frame and view of a rig, with exact motion ground truth."""

from __future__ import annotations

from ..render.request import EXECUTORS
from . import args as argtypes


def register(sub) -> None:
    p = sub.add_parser("render-video", help="render a light-field video with motion ground truth (resumable)")
    p.add_argument("stage", help="USD stage with a light-field rig")
    p.add_argument("--frames", type=argtypes.frame_range, default=None, help="inclusive range A-B (default: the stage's range)")
    p.add_argument("--resolution", type=argtypes.resolution, default=None, help="override the rig's WIDTHxHEIGHT (e.g. a preview size)")
    p.add_argument("--executor", default="local", choices=EXECUTORS, help="local process pool or Ray tasks")
    p.add_argument("--ray-address", default=None, help="join this Ray cluster (default: start a local Ray)")
    p.add_argument("--verify", action="store_true", help="run 'lfusd verify' on the result")
    argtypes.add_render_options(p, "the RGB images")
    argtypes.add_effect_options(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..render.job import RenderRequest, render_video

    req = RenderRequest(
        frames=list(range(args.frames[0], args.frames[1] + 1)) if args.frames else None, resolution=args.resolution,
        executor=args.executor, ray_address=args.ray_address, **argtypes.effect_fields(args), **argtypes.render_request_fields(args),
    )
    from .verify import progress, show

    result = render_video(req, verify=args.verify, verify_progress=progress if getattr(args, "verbose", 0) else None)
    first, last = result.frames[0], result.frames[-1]
    print(f"lfusd: {args.out}: rig {', '.join(result.rigs)}, frames {first}-{last}, device {result.manifest['device']}, "
          f"motion derived for {result.derived} views")
    warn_exposure(args.out)
    return show(result.reports) if result.reports is not None else 0


def warn_exposure(out) -> None:
    """A warning line per rig whose images are nearly black or overexposed (lfusd.data.exposure)."""
    import sys

    from ..data.exposure import check_folder

    for line in check_folder(out):
        print(f"lfusd: warning: {line}", file=sys.stderr)
