"""Export a dataset (anything with lfusd.Dataset's interface) to the layouts research code reads.

Each layout is the one its benchmark's own readers and preparation scripts consume unchanged
(docs/CONVENTIONS.md, "Exports"). One module per format registers its writer, options and reader
(:mod:`lfusd.exports.registry`); adding a format is a module here, its name in the import below and
a test. Per-view files are named ``<frame:04d>_<row:02d>_<col:02d>.<ext>``
(:func:`lfusd.exports.common.stem`).
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

from ..data import formats
from ..errors import LfusdError
from .registry import FORMATS, Format, find_export, get

# The formats, in the order the command line lists them (each module registers itself).
from . import hci, kitti, spring, flo, pfm, lfmat, hf, webdataset  # noqa: E402,F401  the registry import

__all__ = ["FORMATS", "Format", "export", "find_export", "get"]


def _remove_stale_partials(dest: Path) -> None:
    """Remove the partial folders of exports to ``dest`` that were killed (``.<name>.partial-<pid>``
    of a process no longer running; never a link), so that a rerun leaves nothing behind."""
    pattern = re.compile(rf"\.{re.escape(dest.name)}\.partial-(\d+)")
    for p in dest.parent.iterdir() if dest.parent.is_dir() else ():
        m = pattern.fullmatch(p.name)
        if not m or p.is_symlink() or not p.is_dir():
            continue
        try:
            os.kill(int(m[1]), 0)
        except ProcessLookupError:
            shutil.rmtree(p, ignore_errors=True)
        except (PermissionError, OverflowError):
            pass  # another user's running process, or no pid


def export(ds, fmt: str, dest, frame: int | None = None, **kw):
    """Write ``ds`` in format ``fmt`` (:data:`FORMATS`), writing into a hidden folder beside ``dest`` that is renamed
    to ``dest`` when complete: a failed export leaves nothing that blocks its retry."""
    writer = get(fmt).writer
    dest = Path(dest)
    if dest.exists():
        raise LfusdError(f"export target {dest} already exists; choose a new folder or remove it first")
    try:
        dest.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise LfusdError(f"cannot create export target {dest} ({e.strerror}): {formats.why_unwritable(dest)}") from None
    _remove_stale_partials(dest)
    tmp = dest.parent / f".{dest.name}.partial-{os.getpid()}"
    try:
        result = writer(ds, tmp, frame=frame, **kw)
        tmp.rename(dest)
    except OSError as e:
        raise LfusdError(f"cannot write export {dest} ({e.strerror or e}): {formats.why_unwritable(tmp / 'x')}") from None
    finally:
        if tmp.is_dir() and not tmp.is_symlink():
            shutil.rmtree(tmp, ignore_errors=True)

    def moved(p):
        return dest / Path(p).relative_to(tmp)

    return [moved(p) for p in result] if isinstance(result, list) else moved(result)
