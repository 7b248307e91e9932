"""`lfusd render`: render every view of a rig at one frame, with exact ground-truth passes."""

from __future__ import annotations

from pathlib import Path

from ..render.request import DEVICES


def register(sub) -> None:
    p = sub.add_parser("render", help="render a static light field (all views of a rig at one frame)")
    p.add_argument("stage", help="USD stage with a light-field rig")
    p.add_argument("-o", "--out", required=True, help="dataset folder to write (created; reruns resume)")
    p.add_argument("--rig", default=None, help="rig name, or 'all' (default: the stage's only rig)")
    p.add_argument("--frame", type=int, default=None, help="frame (time code) to render (default: the stage's first)")
    p.add_argument("--samples", type=int, default=16, help="Cycles samples for the RGB image (default 16)")
    p.add_argument("--device", default="auto", choices=DEVICES, help="Cycles device (default auto: OptiX, CUDA, else CPU)")
    p.add_argument("--workers", type=int, default=1, help="Blender worker processes (default 1)")
    p.add_argument("--overwrite", action="store_true", help="replace an lfusd dataset rendered with other settings (only lfusd's own files)")
    p.add_argument("--force", action="store_true", help="render even when the estimated size exceeds the free disk space or memory")
    p.add_argument("--quiet", action="store_true", help="log lines instead of a progress bar")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..render.job import RenderRequest, render

    req = RenderRequest(
        stage=Path(args.stage), out=Path(args.out), rig=args.rig,
        frames=None if args.frame is None else [args.frame], samples=args.samples, device=args.device,
        workers=args.workers, overwrite=args.overwrite, force=args.force, quiet=args.quiet,
    )
    manifest = render(req)
    print(f"lfusd: {args.out}: rigs {', '.join(manifest['rigs'])}, frames {manifest['frames']}, device {manifest['device']}")
    return 0
