"""Export a dataset (anything with lfusd.Dataset's interface) to the layouts research code reads.

Each layout is the one its benchmark's own readers and preparation scripts consume unchanged
(docs/CONVENTIONS.md, "Exports"). One module per format registers its writer, options and reader
(:mod:`lfusd.exports.registry`); adding a format is a module here, its name in the import below and
a test. Per-view files are named ``<frame:04d>_<row:02d>_<col:02d>.<ext>``
(:func:`lfusd.exports.common.stem`).
"""

from __future__ import annotations

from pathlib import Path

from ..data.folder import DatasetLike, new_folder, require_pinhole
from .registry import FORMATS, Format, find_export, get

# The formats, in the order the command line lists them (each module registers itself).
from . import hci, kitti, spring, flo, pfm, lfmat, hf, webdataset, cache  # noqa: E402,F401  the registry import

__all__ = ["FORMATS", "Format", "export", "find_export", "get"]


def export(ds: DatasetLike, fmt: str, dest, frame: int | None = None, **kw):
    """Write ``ds`` in format ``fmt`` (:data:`FORMATS`) into the new folder ``dest``, whole or not at
    all (:func:`lfusd.data.folder.new_folder`): a failed export leaves nothing that blocks its retry.
    A resumable format (``cache``) makes or completes ``dest`` itself."""
    f = get(fmt)
    writer = f.writer
    if f.pinhole:
        lens = ", ".join(n for n, g in sorted(FORMATS.items()) if not g.pinhole)
        require_pinhole(ds, f"the {fmt} format (its cameras are pinholes)", f"export it as one of {lens}, or render it without --lens")
    if f.resumable:  # makes or completes dest itself (the training cache)
        return writer(ds, dest, frame=frame, **kw)
    with new_folder(dest, "export") as tmp:
        result = writer(ds, tmp, frame=frame, **kw)
    dest = Path(dest)

    def moved(p):
        return dest / Path(p).relative_to(tmp)

    return [moved(p) for p in result] if isinstance(result, list) else moved(result)
