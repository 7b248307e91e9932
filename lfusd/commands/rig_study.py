"""`lfusd rig-study`: render and score candidate camera arrangements for a stage and a task."""

from __future__ import annotations

import argparse
from pathlib import Path

from .. import layout
from ..camera import AXES, LAYOUTS, SPACINGS
from ..errors import LfusdError
from ..render.request import DEVICES, EXECUTORS
from . import args as argtypes


def _list(kind, what: str):
    def convert(text: str):
        parts = [p.strip() for p in str(text).split(",") if p.strip()]
        try:
            return tuple(kind(p) for p in parts)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{what} {text!r} is not a comma-separated list") from None

    convert.__name__ = what
    return convert


def register(sub) -> None:
    p = sub.add_parser("rig-study", help="compare light-field camera arrangements for a stage and a task (renders tiny views; resumable)")
    p.add_argument("stage", help="the USD stage; its rig(s) give the position, look-at point and lens (never written without --apply)")
    p.add_argument("-o", "--out", required=True, metavar="STUDY", help="study folder (created; rerunning the same command resumes)")
    p.add_argument("--grid", type=argtypes.grid, default="9x9", help="views of every candidate as ROWSxCOLS (default 9x9)")
    p.add_argument("--baselines", type=_list(float, "baselines"), default="0.02,0.05,0.125,0.3", help="metres, comma-separated (default 0.02,0.05,0.125,0.3)")
    p.add_argument("--spacing", type=_list(str, "spacings"), default=",".join(SPACINGS), help=f"any of {','.join(SPACINGS)} (default all)")
    p.add_argument("--layout", type=_list(str, "layouts"), default=",".join(LAYOUTS), help=f"any of {','.join(LAYOUTS)} (default both)")
    p.add_argument("--axes", type=_list(str, "axes"), default=",".join(AXES), help=f"any of {','.join(AXES)} (default both)")
    p.add_argument("--frames", type=argtypes.frames, default=None, help="frames to score, N, A-B or lists (default: the stage's first)")
    p.add_argument("--task", default="disparity", choices=("disparity", "views", "sceneflow"), help="what the ranking serves (default disparity)")
    argtypes.add_rig_option(p, "stage")
    p.add_argument("--resolution", type=argtypes.resolution, default="64x64", help="WIDTHxHEIGHT of the study's views (default 64x64)")
    p.add_argument("--samples", type=int, default=4, help="Cycles samples of the images (default 4; the ground truth is exact at any)")
    p.add_argument("--bands", type=_list(float, "bands"), default="1,3,10,30", help="depth band edges in metres (default 1,3,10,30)")
    p.add_argument("--min-psnr", type=float, default=30.0, help="--task views: held-out PSNR (dB) a view must reach to count as recovered (default 30)")
    p.add_argument("--planes", type=int, default=None, help="planes per sweep (default: about 1 px of parallax per plane, 16-96)")
    p.add_argument("--top", type=int, default=20, help="rows of the terminal table (report.md has all)")
    p.add_argument("--apply", default=None, metavar="NAME", help="write the winning arrangement into the stage as rig NAME (at the stage rig's resolution)")
    p.add_argument("--apply-layer", default=None, metavar="NEW.usda", help="with --apply: write it into a new layer over the stage instead")
    p.add_argument("--workers", type=int, default=1, help="Blender worker processes / Ray task slots (default 1)")
    p.add_argument("--device", default="auto", choices=DEVICES, help="Cycles device (default auto)")
    p.add_argument("--executor", default="local", choices=EXECUTORS, help="local process pool or Ray tasks (large studies)")
    p.add_argument("--ray-address", default=None, help="join this Ray cluster (default: start a local Ray)")
    p.add_argument("--force", action="store_true", help="render even when the estimated size exceeds the free disk space or memory")
    p.add_argument("--quiet", action="store_true", help="log lines instead of progress bars")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..study.report import table
    from ..study.run import StudyRequest, run_study

    if args.top < 1:
        raise LfusdError(f"--top must be a positive integer, got {args.top}")
    req = StudyRequest(
        stage=Path(args.stage), out=Path(args.out), grid=args.grid, baselines=args.baselines, spacings=args.spacing,
        layouts=args.layout, axes=args.axes, frames=args.frames, task=args.task, rig=args.rig, resolution=args.resolution,
        samples=args.samples, bands=args.bands, min_psnr=args.min_psnr, n_planes=args.planes, device=args.device,
        workers=args.workers, executor=args.executor, ray_address=args.ray_address, quiet=args.quiet, force=args.force,
        apply=args.apply, apply_layer=Path(args.apply_layer) if args.apply_layer else None,
    )
    result = run_study(req)
    from rich.console import Console

    Console(width=160).print(table(result.ranked, args.task, args.top))
    best = result.ranked[0]
    print(f"lfusd: best for {args.task}: {best['arrangement']}; {result.candidates} candidates, {result.views} views from "
          f"{result.cameras} distinct cameras, {result.seconds:.0f} s; report {result.out / layout.STUDY_REPORT}")
    for name in result.applied:
        print(f"lfusd: wrote rig {name} ({best['arrangement']}) into {args.apply_layer or args.stage}")
    return 0
