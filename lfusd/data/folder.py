"""The dataset folder: the one place that opens, creates, locks, resumes and atomically writes it.

Every writer of a dataset folder (the render, the ground-truth derivation, the rig study, a recipe,
the exports) and every reader goes through here:

- :func:`atomic_write`: a file appears whole or not at all (text, bytes, or a writer that takes
  a path), readable like the folder's other files;
- :func:`open_dataset` / :func:`open_datasets`: a reader of one rig / of every rig, with one-line
  errors for a folder that is missing or holds no dataset.

Imports only the standard library and lfusd's base modules at module level (the Blender worker
imports it), never pxr, bpy or torch.
"""

from __future__ import annotations

import functools
import os
import tempfile
from pathlib import Path
from typing import Callable

from ..errors import LfusdError


@functools.cache
def file_mode() -> int:
    """The mode of a new file under the process's umask (0644 under the usual 022): for files
    made with ``tempfile.mkstemp`` (0600), which a shared dataset must not keep."""
    try:  # Linux states the umask; setting it to read it races with threads creating files
        with open("/proc/self/status") as f:
            mask = next(int(ln.split()[1], 8) for ln in f if ln.startswith("Umask:"))
    except (OSError, StopIteration, ValueError):
        mask = os.umask(0o022)
        os.umask(mask)
    return 0o666 & ~mask


def atomic_write(path, content: str | bytes | Callable[[str], object], *, prefix: str | None = None, suffix: str = ".tmp",
                 sync: bool = False) -> Path:
    """Write ``path`` under a temporary name in the same folder, then rename it into place.

    ``content``: text, bytes, or a function that writes the file at the path it is given (an EXR
    or .npz writer). The temporary is ``<prefix><8 random><suffix>`` (default prefix
    ``.<name>.``: the names :mod:`lfusd.data.confined` removes after a killed run); ``sync``
    flushes it to disk before the rename. Returns ``path``.
    """
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}." if prefix is None else prefix, suffix=suffix)
    try:
        if callable(content):
            os.close(fd)
            content(tmp)
            os.chmod(tmp, file_mode())  # mkstemp makes 0600; a dataset is shared like its other files
        else:
            os.fchmod(fd, file_mode())
            with os.fdopen(fd, "w" if isinstance(content, str) else "wb") as f:
                f.write(content)
                if sync:
                    f.flush()
                    os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def open_dataset(path, rig: str | None = None):
    """``lfusd.Dataset(path, rig=rig)`` with a one-line error for a missing folder."""
    p = Path(path)
    if not p.is_dir():
        raise LfusdError(f"dataset folder {p} does not exist; give the output folder of `lfusd render`")
    from .dataset import Dataset

    return Dataset(p) if rig is None else Dataset(p, rig=rig)


def open_datasets(path, rig: str | None = None) -> list:
    """One reader per rig of the dataset in ``path``: just ``rig``, or every rig when it is None or 'all'."""
    if rig not in (None, "all"):
        return [open_dataset(path, rig)]
    from .dataset import read_manifest

    return [open_dataset(path, r) for r in read_manifest(path)["rigs"]]  # the reader's one-line errors
