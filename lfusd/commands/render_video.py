"""`lfusd render-video`: every frame and view of a rig, with exact motion ground truth."""

from __future__ import annotations

from pathlib import Path

from ..render.request import DEVICES, EXECUTORS
from . import args as argtypes


def register(sub) -> None:
    p = sub.add_parser("render-video", help="render a light-field video with motion ground truth (resumable)")
    p.add_argument("stage", help="USD stage with a light-field rig")
    p.add_argument("-o", "--out", required=True, help="dataset folder (created; rerunning resumes)")
    p.add_argument("--rig", default=None, help="rig name, or 'all' (default: the stage's only rig)")
    p.add_argument("--frames", type=argtypes.frame_range, default=None, help="inclusive range A-B (default: the stage's range)")
    p.add_argument("--samples", type=int, default=16, help="Cycles samples for the RGB images (default 16)")
    p.add_argument("--resolution", type=argtypes.resolution, default=None, help="override the rig's WIDTHxHEIGHT (e.g. a preview size)")
    p.add_argument("--workers", type=int, default=1, help="Blender worker processes / Ray task slots (default 1)")
    p.add_argument("--executor", default="local", choices=EXECUTORS, help="local process pool or Ray tasks")
    p.add_argument("--ray-address", default=None, help="join this Ray cluster (default: start a local Ray)")
    p.add_argument("--device", default="auto", choices=DEVICES, help="Cycles device (default auto: OptiX, CUDA, else CPU)")
    p.add_argument("--verify", action="store_true", help="run 'lfusd verify' on the result")
    p.add_argument("--overwrite", action="store_true", help="replace an lfusd dataset rendered with other settings (only lfusd's own files)")
    p.add_argument("--force", action="store_true", help="render even when the estimated size exceeds the free disk space or memory")
    p.add_argument("--quiet", action="store_true", help="log lines instead of a progress bar")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..render.job import RenderRequest, render_video

    req = RenderRequest(
        stage=Path(args.stage), out=Path(args.out), rig=args.rig,
        frames=list(range(args.frames[0], args.frames[1] + 1)) if args.frames else None,
        samples=args.samples, device=args.device, workers=args.workers, resolution=args.resolution,
        overwrite=args.overwrite, force=args.force, quiet=args.quiet, executor=args.executor, ray_address=args.ray_address,
    )
    result = render_video(req)
    first, last = result.frames[0], result.frames[-1]
    print(f"lfusd: {args.out}: rig {', '.join(result.rigs)}, frames {first}-{last}, device {result.manifest['device']}, "
          f"motion derived for {result.derived} views")
    if args.verify:
        from ..truth.verify import verify
        from .verify import progress, show

        return show(verify(args.out, rig=result.rigs[0] if len(result.rigs) == 1 else "all", frames=result.frames, progress=progress))
    return 0
