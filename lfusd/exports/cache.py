"""The training cache as an export format (``lfusd export cache OUT DEST``): every key decoded once
into memory-mapped ``.npy`` arrays (:mod:`lfusd.data.cache`), which ``lfusd.torch`` reads fast.
Unlike the other formats it resumes its target: a rerun completes and repairs it."""

from __future__ import annotations

from ..data.cache import write_cache
from .registry import TEXT, Option, register


@register("cache", "a training cache: every key decoded once into memory-mapped .npy arrays (resumable)", unit="frame", resumable=True,
          options=(Option("--keys", "keys", TEXT, "the keys to cache, comma-separated (default: every key the dataset gives)"),))
def export_cache(ds, dest, frame: int | None = None, keys: str | None = None):
    """:func:`lfusd.data.cache.write_cache` with ``keys`` as the command line gives them (comma-separated)."""
    wanted = None if keys is None else [k.strip() for k in keys.split(",") if k.strip()]
    return write_cache(ds, dest, frame=frame, keys=wanted)
