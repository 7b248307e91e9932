"""`lfusd render`: render every view of a rig at one frame, with exact ground-truth passes."""

from __future__ import annotations

from . import args as argtypes


def register(sub) -> None:
    p = sub.add_parser("render", help="render a static light field (all views of a rig at one frame)")
    p.add_argument("stage", help="USD stage with a light-field rig")
    p.add_argument("--frame", type=int, default=None, help="frame (time code) to render (default: the stage's first)")
    argtypes.add_render_options(p, "the RGB image")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..render.job import RenderRequest, render

    req = RenderRequest(frames=None if args.frame is None else [args.frame], **argtypes.render_request_fields(args))
    manifest = render(req)
    print(f"lfusd: {args.out}: rigs {', '.join(manifest['rigs'])}, frames {manifest['frames']}, device {manifest['device']}")
    from .render_video import warn_exposure

    warn_exposure(args.out)
    return 0
