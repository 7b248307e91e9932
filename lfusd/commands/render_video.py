"""`lfusd render-video`: every frame and view of a rig, with exact motion ground truth."""

from __future__ import annotations

from pathlib import Path

from ..errors import LfusdError
from ..render.request import DEVICES, EXECUTORS


def parse_frames(text: str) -> tuple[int, int]:
    """'1-150' -> (1, 150); a single number is a one-frame range."""
    parts = str(text).split("-")
    try:
        a, b = (int(parts[0]), int(parts[-1])) if len(parts) in (1, 2) else (None, None)
    except ValueError:
        a = b = None
    if a is None or b is None or b < a:
        raise LfusdError(f"--frames {text!r} is not a range A-B with A <= B (e.g. 1-150)")
    return a, b


def register(sub) -> None:
    p = sub.add_parser("render-video", help="render a light-field video with motion ground truth (resumable)")
    p.add_argument("stage", help="USD stage with a light-field rig")
    p.add_argument("-o", "--out", required=True, help="dataset folder (created; rerunning resumes)")
    p.add_argument("--rig", default=None, help="rig name, or 'all' (default: the stage's only rig)")
    p.add_argument("--frames", default=None, help="inclusive range A-B (default: the stage's range)")
    p.add_argument("--samples", type=int, default=16, help="Cycles samples for the RGB images (default 16)")
    p.add_argument("--resolution", default=None, help="override the rig's WIDTHxHEIGHT (e.g. a preview size)")
    p.add_argument("--workers", type=int, default=1, help="Blender worker processes / Ray task slots (default 1)")
    p.add_argument("--executor", default="local", choices=EXECUTORS, help="local process pool or Ray tasks")
    p.add_argument("--ray-address", default=None, help="join this Ray cluster (default: start a local Ray)")
    p.add_argument("--device", default="auto", choices=DEVICES, help="Cycles device (default auto: OptiX, CUDA, else CPU)")
    p.add_argument("--verify", action="store_true", help="run 'lfusd verify' on the result")
    p.add_argument("--overwrite", action="store_true", help="replace a dataset rendered with other settings")
    p.add_argument("--quiet", action="store_true", help="log lines instead of a progress bar")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..camera import parse_resolution
    from ..render.job import RenderRequest, render_video

    frames = None
    if args.frames:
        first, last = parse_frames(args.frames)
        frames = list(range(first, last + 1))
    req = RenderRequest(
        stage=Path(args.stage), out=Path(args.out), rig=args.rig, frames=frames,
        samples=args.samples, device=args.device, workers=args.workers,
        resolution=parse_resolution(args.resolution) if args.resolution else None,
        overwrite=args.overwrite, quiet=args.quiet, executor=args.executor, ray_address=args.ray_address,
    )
    result = render_video(req)
    first, last = result.frames[0], result.frames[-1]
    print(f"lfusd: {args.out}: rig {', '.join(result.rigs)}, frames {first}-{last}, device {result.manifest['device']}, "
          f"motion derived for {result.derived} views")
    if args.verify:
        import argparse

        from .verify import handler

        rig = result.rigs[0] if len(result.rigs) == 1 else "all"
        return handler(argparse.Namespace(out=args.out, rig=rig, frames=f"{first}-{last}", views=None, stage=None))
    return 0
