"""`lfusd export FORMAT OUT DEST`: write a dataset in a research layout (HCI, KITTI, Spring, .flo, PFM, LF HDF5)
or as WebDataset / Hugging Face shards with Croissant metadata. The formats and their options come
from the registry (lfusd.exports.registry)."""

from __future__ import annotations

from . import args as argtypes


def _argparse_settings(kind: str) -> dict:
    from ..exports import registry

    return {registry.FLAG: {"action": "store_true"}, registry.VIEW: {"type": argtypes.view, "default": None},
            registry.TEXT: {"default": None}}[kind]


def register(subparsers) -> None:
    from ..exports import FORMATS

    p = subparsers.add_parser(
        "export",
        help="export a dataset to HCI, KITTI, Spring, .flo, PFM, HDF5 LF layouts or WebDataset / Hugging Face shards",
        description="Export a rendered dataset OUT into DEST (which must not exist yet; cache makes or completes its own DEST).",
    )
    p.add_argument("format", choices=list(FORMATS), help="target layout: " + "; ".join(f"{f.name}: {f.help}" for f in FORMATS.values()))
    p.add_argument("out", help="dataset folder (output of `lfusd render`)")
    p.add_argument("dest", help="new folder to write (cache: a new folder or the cache to complete)")
    p.add_argument("--frame", type=int, default=None, help="export only this frame (default: all)")
    p.add_argument("--exposure", default=None, metavar="auto|GAIN",
                   help="8-bit images from the linear render times one gain for the whole dataset: auto (the brightest 1 %% "
                        "of pixels at 0.9 of white) or a number (default: as rendered)")
    argtypes.add_rig_option(p, "dataset")
    # Each format's options, once per flag; its help names the formats that take it.
    options: dict[str, list] = {}
    for f in FORMATS.values():
        for o in f.options:
            options.setdefault(o.flag, []).append((f.name, o))
    for flag, uses in options.items():
        helps: dict[str, list[str]] = {}
        for name, o in uses:
            helps.setdefault(o.help, []).append(name)
        p.add_argument(flag, dest=uses[0][1].param, **_argparse_settings(uses[0][1].kind),
                       help="; ".join(f"{'/'.join(names)}: {text}" for text, names in helps.items()))
    p.set_defaults(func=run)


def run(args) -> int:
    from .. import exports
    from ..data.dataset import open_dataset

    fmt = exports.get(args.format)
    ds = open_dataset(args.out, args.rig)
    if args.exposure is not None:
        from ..data.exposure import exposed

        ds = exposed(ds, args.exposure)
        print(f"exposure: gain {ds.gain:.4g} on the linear images, the same for every view and frame")
    result = exports.export(ds, fmt.name, args.dest, frame=args.frame, **{o.param: getattr(args, o.param) for o in fmt.options})
    n = len(result) if isinstance(result, list) else 1
    print(f"exported {fmt.name} to {args.dest} ({n} {fmt.unit}{'' if n == 1 else 's'})")
    return 0
