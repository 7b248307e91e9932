"""`lfusd export FORMAT OUT DEST`: write a dataset in a research layout (HCI, KITTI, Spring, .flo, PFM, LF HDF5)
or as WebDataset / Hugging Face shards with Croissant metadata."""

from __future__ import annotations

from . import args as argtypes


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "export",
        help="export a dataset to HCI, KITTI, Spring, .flo, PFM, HDF5 LF layouts or WebDataset / Hugging Face shards",
        description="Export a rendered dataset OUT into DEST (which must not exist yet).",
    )
    p.add_argument("format", choices=["hci", "kitti", "spring", "flo", "pfm", "lfmat", "hf", "webdataset"],
                   help="target layout (hf, webdataset: tar shards of one sample per frame and view, Croissant metadata.json; hf adds a dataset card)")
    p.add_argument("out", help="dataset folder (output of `lfusd render`)")
    p.add_argument("dest", help="new folder to write")
    p.add_argument("--frame", type=int, default=None, help="export only this frame (default: all)")
    p.add_argument("--view", type=argtypes.view, default=None, help="ROW,COL view for flo/pfm (default: the centre view)")
    p.add_argument("--all-views", action="store_true", help="flo/pfm: every view; hci: also per-view disparity PFMs")
    p.add_argument("--matlab", action="store_true", help="lfmat: write MATLAB v7.3 .mat files instead of .h5 (both: LF [U,V,H,W,3] in [0,1] as BasicLFSR reads it)")
    argtypes.add_rig_option(p, "dataset")
    p.add_argument("--license", default=None, help="hf/webdataset: the data's license (SPDX id or URL) for the metadata (default: none claimed)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..data import export as ex

    ds = ex.open_dataset(args.out, args.rig)
    kw = {}
    if args.format in ("flo", "pfm"):
        kw = {"view": args.view, "all_views": args.all_views}
    elif args.format == "hci":
        kw = {"all_views": args.all_views}
    elif args.format == "lfmat":
        kw = {"matlab": args.matlab}
    elif args.format in ("hf", "webdataset"):
        kw = {"license": args.license}
    result = ex.export(ds, args.format, args.dest, frame=args.frame, **kw)
    n = len(result) if isinstance(result, list) else 1
    what = "shard" if args.format in ("hf", "webdataset") else "item"
    print(f"exported {args.format} to {args.dest} ({n} {what}{'' if n == 1 else 's'})")
    return 0
