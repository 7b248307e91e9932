"""The one atomic file write of lfusd (a file appears whole or not at all), and a file's sha256.

A base module (standard library only) so that every layer uses it: the dataset folder
(:mod:`lfusd.data.folder` re-exports it), the Blender worker, authoring (stages, catalogues).
"""

from __future__ import annotations

import functools
import hashlib
import os
import tempfile
from pathlib import Path
from typing import Callable


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


def sha256_of(path) -> str:
    """The hex sha256 of the file at ``path``, read in blocks (never whole into memory)."""
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()
