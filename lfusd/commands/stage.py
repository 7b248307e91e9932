"""`lfusd stage new TEMPLATE -o STAGE --seed N`: generate a scene from the template library."""

from __future__ import annotations

import time
from pathlib import Path

from ..errors import LfusdError
from . import args as argtypes


def register(sub) -> None:
    from ..author.scenes import TEMPLATES

    p = sub.add_parser("stage", help="generate scene stages from templates")
    ssub = p.add_subparsers(dest="stage_command", metavar="ACTION")
    n = ssub.add_parser("new", help="write a new stage from a template",
                        description=f"Generate a deterministic scene. Templates: {', '.join(TEMPLATES)}.")
    n.add_argument("template", help=f"one of: {', '.join(TEMPLATES)}")
    n.add_argument("-o", "--output", required=True, help="the .usda file to write (textures go to textures/ beside it)")
    n.add_argument("--seed", type=int, default=0, help="random seed (same seed, same stage, on every machine)")
    n.add_argument("--frames", type=int, default=150, help="stage range 1..N (default 150)")
    n.add_argument("--rigs", type=int, default=10, help="rig placements rig_00.. (0-10, default 10)")
    n.add_argument("--grid", type=argtypes.grid, default="9x9", help="views per rig, ROWSxCOLS (default 9x9)")
    n.add_argument("--resolution", type=argtypes.resolution, default="1024x1024", help="image size WIDTHxHEIGHT (default 1024x1024)")
    n.add_argument("--force", action="store_true", help="replace an existing stage file; allow grids and resolutions beyond the limits")
    n.add_argument("--dynamic", action="store_true",
                   help="add walking/running people, drifting boats, driving cars, swinging doors over the frames")
    n.add_argument("--catalogue", action="append", default=[], metavar="FILE",
                   help="an asset catalogue (`lfusd assets add`) whose assets replace the procedural objects of their "
                        "class (repeatable)")
    n.set_defaults(func=run_new)
    t = ssub.add_parser("templates", help="list the templates")
    t.set_defaults(func=run_templates)
    p.set_defaults(func=argtypes.run_help(p))


def run_templates(args) -> int:
    from ..author.scenes import TEMPLATES

    print("\n".join(TEMPLATES))
    return 0


def run_new(args) -> int:
    from ..author.scenes import generate

    t0 = time.perf_counter()
    from ..data.formats import why_unwritable
    from ..camera import check_rig_size

    out = Path(args.output)
    if not str(out).endswith((".usda", ".usdc", ".usd")):
        raise LfusdError(f"output {out} must end in .usda, .usdc or .usd")
    if out.exists() and not args.force:
        raise LfusdError(f"stage {out} already exists; choose another -o file or pass --force to replace it")
    if out.is_dir():
        raise LfusdError(f"output {out} is a folder; give a .usda/.usdc/.usd file")
    if args.rigs:
        check_rig_size(args.grid, args.resolution, args.force)
    try:
        generate(args.template, out, args.seed, frames=args.frames, rigs=args.rigs, grid=args.grid, resolution=args.resolution,
                 dynamic=args.dynamic, catalogues=args.catalogue)
    except OSError as e:
        raise LfusdError(f"cannot write stage {out} ({e.strerror or e}): {why_unwritable(out)}") from None
    except Exception as e:  # pxr reports an unwritable layer as Tf.ErrorException
        if type(e).__name__ != "ErrorException":
            raise
        raise LfusdError(f"cannot write stage {out}: {why_unwritable(out)}") from None
    kind = ", dynamic" if args.dynamic else ""
    print(f"wrote {args.output} ({args.template}{kind}, seed {args.seed}, frames 1-{args.frames}, {args.rigs} rigs) "
          f"in {time.perf_counter() - t0:.2f} s")
    return 0
