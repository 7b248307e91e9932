"""The registry of export formats: each format module registers its writer with :func:`register`.

``lfusd export`` builds its choices and options from :data:`FORMATS`, :func:`lfusd.exports.export`
dispatches through it, and ``lfusd eval`` asks the formats that have a :class:`Reader` whether a
folder is one of their exports (:func:`find_export`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ..errors import LfusdError

# Kinds of option values; the command line turns each into its argparse setting (lfusd.commands.export).
FLAG, VIEW, TEXT = "flag", "view", "text"


@dataclass(frozen=True)
class Option:
    """A keyword argument of a format's writer, offered on the command line as ``flag``.

    ``kind``: :data:`FLAG` (a switch, default False), :data:`VIEW` (``ROW,COL``) or :data:`TEXT`;
    ``help`` says what it does for this format (formats sharing a flag each say their own)."""

    flag: str
    param: str
    kind: str
    help: str


@dataclass(frozen=True)
class Reader:
    """How ``lfusd eval`` scores predictions against an export of this format rather than a dataset.

    ``find(path)``: the folder holding the export's ground truth, or None when ``path`` is not such
    an export; ``names(root, task)``: the images with ground truth; ``truth(root, name, task)``:
    their ground truth for :func:`lfusd.evaluation.protocols.score`; ``protocol``: the only
    protocol it is scored under; ``predictions``: the prediction folder of each task (the
    benchmark's submission layout)."""

    find: Callable[[Path], Path | None]
    names: Callable[[Path, str], list[str]]
    truth: Callable[[Path, str, str], dict]
    protocol: str
    predictions: dict[str, str]


@dataclass(frozen=True)
class Format:
    """One export format: its name, a line of help, the writer ``writer(ds, dest, frame=None,
    **options)``, its options, what the writer's result counts (``unit``), its reader, if any, and
    whether it resumes its own target (``resumable``)."""

    name: str
    help: str
    writer: Callable
    options: tuple[Option, ...] = ()
    unit: str = "item"
    reader: Reader | None = None
    resumable: bool = False  # the writer makes or completes ``dest`` itself (the training cache), not a new folder
    pinhole: bool = False  # the format's geometry is a pinhole's (rectified disparity, no lens model): a distorted dataset is refused


FORMATS: dict[str, Format] = {}


def register(name: str, help: str, options: tuple[Option, ...] = (), unit: str = "item", reader: Reader | None = None,
             resumable: bool = False, pinhole: bool = False):
    """Decorator registering ``writer`` as export format ``name`` (``resumable``: it makes or
    completes its target itself rather than writing a new folder whole; ``pinhole``: the format cannot
    express a lens distortion, so a dataset rendered with ``--lens`` is refused)."""

    def wrap(writer: Callable) -> Callable:
        if name in FORMATS:
            raise ValueError(f"export format {name!r} is registered twice")
        FORMATS[name] = Format(name, help, writer, tuple(options), unit, reader, resumable, pinhole)
        return writer

    return wrap


def get(name: str) -> Format:
    """The format ``name``, or LfusdError listing the formats."""
    if name not in FORMATS:
        raise LfusdError(f"unknown export format {name!r}; use one of {', '.join(FORMATS)}")
    return FORMATS[name]


def find_export(path) -> tuple[Format, Path] | None:
    """(format, ground-truth folder) when ``path`` is an export some format can read back, else None."""
    for fmt in FORMATS.values():
        if fmt.reader is not None:
            root = fmt.reader.find(Path(path))
            if root is not None:
                return fmt, root
    return None
