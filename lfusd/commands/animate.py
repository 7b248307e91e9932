"""`lfusd animate add-person`: put a walking or running person on a stage along a path."""

from __future__ import annotations

import sys
import time


def register(sub) -> None:
    anim = sub.add_parser("animate", help="add animated people to a stage")
    asub = anim.add_subparsers(dest="animate_command", metavar="ACTION", required=True)
    add = asub.add_parser(
        "add-person",
        help="add a person (UsdSkel, labelled person) moving along a path over the stage's ground",
        description="Add a person that walks or runs along --path over the stage's supporting surfaces "
        "(road, pavement, ground, grass, floor, bridge, ...), following their height; refuses a path that "
        "would put the person over water, naming the frame.",
    )
    add.add_argument("stage", help="the USD stage or asset (.usda/.usdc/.usdz/.usd); edited in place unless -o is given")
    add.add_argument("-o", "--out", default=None, metavar="NEW.usda",
                     help="write a new layer that sublayers STAGE (left unchanged) and holds the person; needed for .usdz packages")
    add.add_argument("--path", nargs="+", required=True, metavar="X,Y", help="path points (at least two), metres along the stage's horizontal axes (X,Y on a Z-up stage, X,Z on a Y-up one)")
    add.add_argument("--gait", choices=("walk", "run", "idle"), default="walk",
                     help="walk (default), run, or idle (stand at the first point, facing the second)")
    add.add_argument("--speed", type=float, default=None, help="metres per second (default 1.3 walking, 3.5 running)")
    add.add_argument("--start", type=int, default=None, help="frame at which the person sets off (default: the stage's first)")
    add.add_argument("--character", default=None, help="a UsdSkel character file to use instead of lfusd's procedural human")
    add.add_argument("--height", type=float, default=1.75, help="procedural human's stature in metres (default 1.75)")
    add.add_argument("--build", type=float, default=0.5, help="procedural human's build, 0 slim to 1 heavy (default 0.5)")
    add.add_argument("--name", default=None, help="prim path for the person (default /World/People/Person_NN)")
    add.add_argument("--force", action="store_true", help="replace a prim already at --name")
    add.add_argument("--ground", action="append", default=[], metavar="PRIM",
                     help="label PRIM 'ground' so the person walks on it (repeatable), for a stage whose ground has no class label")
    add.add_argument("--frames", type=int, default=None, metavar="N",
                     help="give a stage without a time range the frames 1..N (a walk needs more than one frame)")
    add.set_defaults(func=run_add_person)
    cyc = asub.add_parser("write-cycles", help="write the procedural human's looping idle/walk/run clips (USD)")
    cyc.add_argument("-o", "--out", default="animations", help="folder (default: animations)")
    cyc.add_argument("--height", type=float, default=1.75, help="stature in metres (default 1.75)")
    cyc.add_argument("--build", type=float, default=0.5, help="build, 0 slim to 1 heavy (default 0.5)")
    cyc.set_defaults(func=run_write_cycles)


def run_write_cycles(args) -> int:
    from ..author.gait import write_cycle_library
    from ..author.human import HumanSpec

    for path in write_cycle_library(args.out, HumanSpec(args.height, args.build)):
        print(f"wrote {path}")
    return 0


def run_add_person(args) -> int:
    from ..author.people import add_person_to_file, parse_points

    t0 = time.perf_counter()

    def progress(what: str) -> None:  # on a terminal: a line per phase (a character takes up to a minute)
        if sys.stderr.isatty():
            print(f"lfusd: add-person: {what} ({time.perf_counter() - t0:.1f} s)", file=sys.stderr, flush=True)

    prim, target, speed = add_person_to_file(
        args.stage, parse_points(args.path), args.out, gait=args.gait, speed=args.speed, start=args.start,
        character=args.character, height=args.height, build=args.build, name=args.name, force=args.force,
        ground=args.ground, frames=args.frames, progress=progress)
    how = "standing" if args.gait == "idle" else f"{args.gait} at {speed:g} m/s"
    print(f"added {prim.GetPath()} ({how}) to {target} in {time.perf_counter() - t0:.2f} s")
    return 0
