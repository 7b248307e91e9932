"""`lfusd assets add|list|check`: the asset catalogue (lfusd.author.catalogue)."""

from __future__ import annotations

from ..author.bake import MAX_TRIANGLES
from . import args as argtypes


def register(sub) -> None:
    p = sub.add_parser("assets", help="catalogue USD assets that generated scenes draw by class",
                       description="Keep a catalogue of USD assets (a JSON file) that `lfusd stage new --catalogue` and "
                                   "recipes draw objects from by semantic class, instead of lfusd's procedural ones.")
    asub = p.add_subparsers(dest="assets_command", metavar="ACTION")
    a = asub.add_parser("add", help="check assets and add them to a catalogue",
                        description="Read a USD asset (or every asset of a folder), check it (a mesh asset with a class, "
                                    "non-empty bounds, no implicit shapes or broken meshes) and record its class, "
                                    "bounds, units, up axis, ground contact, licence and content hash in the catalogue. "
                                    "A refused asset is one line (exit 2) and nothing is written.")
    a.add_argument("target", metavar="FOLDER|FILE", help="a .usd/.usda/.usdc/.usdz asset, or a folder of them")
    a.add_argument("--catalogue", metavar="FILE",
                   help="the catalogue file (.json; made when missing); default: catalogue.json in the asset's folder")
    a.add_argument("--class", dest="cls", metavar="CLASS",
                   help="the assets' semantic class (default: their UsdSemantics 'class' label)")
    a.add_argument("--licence", "--license", dest="licence", metavar="TEXT",
                   help="the assets' licence (default: the one in their metadata, e.g. customLayerData 'license')")
    a.set_defaults(func=run_add)
    ls = asub.add_parser("list", help="list a catalogue's assets and lfusd's procedural generators",
                         description="One line per asset: name, class, size, units, up axis, triangles, licence, file; "
                                     "then lfusd's procedural generators, which templates use for classes no catalogue "
                                     "asset has.")
    ls.add_argument("catalogue", nargs="?", help="the catalogue file or its folder (default: only the procedural entries)")
    ls.set_defaults(func=run_list)
    c = asub.add_parser("check", help="read every asset of a catalogue again",
                        description="Check every asset of the catalogue again: one line per asset that is missing, "
                                    "refused, or changed since it was added; exit 1 if any.")
    c.add_argument("catalogue", help="the catalogue file or its folder")
    c.set_defaults(func=run_check)
    b = asub.add_parser("bake", help="make an asset with a generator (Infinigen) and add it to a catalogue",
                        description="Run a generator's asset factory in its own environment (Infinigen: "
                                    ".venv-infinigen, made by the opt-in scripts/setup_infinigen.sh), export the asset "
                                    "to USD with the generator's exporter, fix what that export gets wrong (its lights, "
                                    "texture colour spaces, normal maps, glass, grounding, repeated copies as instances) "
                                    "and add the result to the catalogue. An asset over the triangle budget is refused, "
                                    "not decimated. Errors are one line (exit 2), and nothing is left behind.")
    b.add_argument("factory", metavar="FACTORY", help="the generator's factory class, e.g. ChairFactory, TableDiningFactory")
    b.add_argument("--generator", required=True, choices=("infinigen",), help="the generator that makes the asset")
    b.add_argument("--seed", type=int, required=True, help="the seed the factory makes its asset with")
    b.add_argument("--catalogue", required=True, metavar="FILE", help="the catalogue file (.json; made when missing)")
    b.add_argument("-o", "--out", metavar="DIR",
                   help="folder for the asset (it goes into DIR/FACTORY_SEED/; default: the catalogue's folder)")
    b.add_argument("--class", dest="cls", metavar="CLASS",
                   help="the asset's semantic class (default: lfusd's class for the factory, e.g. ChairFactory -> chair)")
    b.add_argument("--python", metavar="PATH",
                   help="the generator's Python (default: $LFUSD_INFINIGEN_PYTHON, else the .venv-infinigen/bin/python "
                        "that scripts/setup_infinigen.sh made in lfusd's project folder; never one of the current folder)")
    b.add_argument("--max-triangles", type=int, default=MAX_TRIANGLES, metavar="N",
                   help=f"refuse an asset with more drawn triangles, every copy counted (default {MAX_TRIANGLES})")
    b.add_argument("--texture-size", type=int, default=1024, metavar="PX", help="baked texture size in pixels (default 1024)")
    b.set_defaults(func=run_bake)
    p.set_defaults(func=argtypes.run_help(p))


def run_add(args) -> int:
    from ..author.catalogue import add_assets

    path, added = add_assets(args.target, args.catalogue, args.cls, args.licence)
    for a in added:
        print(_line(a))
    print(f"added {len(added)} asset{'s' if len(added) != 1 else ''} to {path}")
    return 0


def _line(a) -> str:
    size = " x ".join(f"{hi - lo:.2f}" for lo, hi in zip(*a.bounds))
    return (f"{a.name}: {a.cls}, {size} m, metersPerUnit {a.meters_per_unit:g}, {a.up_axis}-up, ground {a.ground:+.3f} m, "
            f"{a.triangles} triangles, {a.textured_materials} textured materials, licence {a.licence or 'unknown'}, {a.file}")


def run_bake(args) -> int:
    from ..author.bake import bake

    r = bake(args.generator, args.factory, args.seed, args.catalogue, args.out, args.cls, args.python,
             args.max_triangles, args.texture_size)
    print(_line(r.asset))
    print(f"cleaned: {r.report.summary()}")
    print(f"baked {args.factory} seed {args.seed} in {r.seconds:.0f} s and added it to {r.catalogue}")
    return 0


def run_list(args) -> int:
    from ..author.catalogue import builtin_entries, load_catalogue

    if args.catalogue:
        for a in load_catalogue(args.catalogue):
            print(_line(a))
    for e in builtin_entries():
        print(f"{e['name']}: {e['class']}, procedural ({e['source']})")
    return 0


def run_check(args) -> int:
    import sys

    from ..author.catalogue import check_catalogue, load_catalogue

    problems = check_catalogue(args.catalogue)
    for line in problems:
        print(line)
    n = len(load_catalogue(args.catalogue))
    if problems:
        print(f"{args.catalogue}: {len(problems)} of {n} assets need attention", file=sys.stderr)
        return 1
    print(f"{args.catalogue}: {n} assets, all as recorded")
    return 0
