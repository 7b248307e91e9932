"""Writing and removing inside a dataset folder without following symbolic links out of it.

A dataset folder may come from someone else (downloaded, shared, unpacked), and any entry in it
may be a symbolic link planted to make lfusd write or delete elsewhere: ``OUT/.lock`` pointing at
a user's file, a rig folder pointing at their home. lfusd never makes links, so every entry it
writes into is checked to be a real file or folder (:func:`check_tree`), files it creates are
opened with ``O_NOFOLLOW`` (:func:`open_new`), and removals (:func:`remove_own`) touch only names
lfusd's layout spells, at the places it writes them, inside OUT. No pxr, bpy or torch.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import shutil
import stat
from pathlib import Path

from .. import layout
from ..errors import LfusdError
from ..layout import frame_dir, view_key

# What lfusd writes at OUT's top besides the rig folders (none of them may be a link).
TOP_ENTRIES = (layout.MANIFEST, layout.OBJECTS, layout.LOGS, layout.SCRATCH, layout.LOCK)
# A worker's log and a Ray unit's attempt record (lfusd.render.executors), the only files of OUT/logs.
LOG_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*-unit\d{4,}\.(log|ray\.jsonl)")
# Hidden temporaries lfusd's atomic writes and commits make (a killed run leaves them behind):
# ".<name>.<8 random>.tmp" (lfusd.data.folder.atomic_write), ".<stem>.<random>.exr" (store), ".view.<random>.json"
# (integrity), ".<key>.tmp-<pid>-<thread>" (a view being committed or moved aside).
_TMP_STEMS = ("manifest.json", "objects.json", "frame.json", "recipe.toml", "card.json", "CARD.md",
              "gt", "motion", "view", "rgb", "passes")
TMP_NAME = re.compile(r"\.(?:(?:%s)\.[a-z0-9_]{8}\.(?:tmp|exr|json|npz)|\d{2,4}_\d{2,4}\.tmp-[A-Za-z0-9_-]+)"
                      % "|".join(re.escape(s) for s in _TMP_STEMS))


def link_error(path: Path) -> LfusdError:
    """The one-line refusal of a link where lfusd writes or deletes."""
    return LfusdError(f"{path} is a symbolic link, and lfusd never makes links in the folders it writes; "
                      "remove the link (or choose another -o folder), then rerun")


def is_link(path: Path) -> bool:
    """Whether ``path`` itself is a symbolic link (a missing path is not)."""
    try:
        return stat.S_ISLNK(os.lstat(path).st_mode)
    except OSError:
        return False


def check_tree(out: str | Path, rigs=(), frames=None) -> None:
    """Refuse, in one line, a dataset folder in which lfusd would write or delete through a link:
    OUT itself is checked by the caller; here its lfusd entries (manifest, object table, logs,
    scratch, lock), the log files, each rig folder in ``rigs``, their frame folders and the view
    folders in them must be real files and folders (or absent). One ``scandir`` per rig and frame
    folder; the files inside a view folder are only ever replaced by renaming, never written
    through, so a link there is left to the integrity check."""
    out = Path(out)
    for name in TOP_ENTRIES:
        if is_link(out / name):
            raise link_error(out / name)
    logs = out / layout.LOGS
    if logs.is_dir():
        with os.scandir(logs) as it:
            for e in it:
                if e.is_symlink():
                    raise link_error(Path(e.path))
    for rig in rigs:
        rig_dir = out / rig
        if is_link(rig_dir):
            raise link_error(rig_dir)
        if not rig_dir.is_dir():
            continue
        with os.scandir(rig_dir) as it:
            frame_dirs = list(it)
        for fe in frame_dirs:
            if fe.is_symlink():
                raise link_error(Path(fe.path))
            if not fe.is_dir(follow_symlinks=False):
                continue
            with os.scandir(fe.path) as it:
                for ve in it:
                    if ve.is_symlink():  # a view folder or frame.json that is a link
                        raise link_error(Path(ve.path))


def check_entries(folder: str | Path, names=(), folders=()) -> None:
    """Refuse, in one line, a link where lfusd writes in a folder that is not a dataset (a rig
    study's): each entry of ``names`` in ``folder`` and every entry of each folder of ``folders``
    (the folders themselves included) must be a real file or folder (or absent)."""
    folder = Path(folder)
    for name in (*names, *folders):
        if is_link(folder / name):
            raise link_error(folder / name)
    for name in folders:
        if (folder / name).is_dir():
            with os.scandir(folder / name) as it:
                for e in it:
                    if e.is_symlink():
                        raise link_error(Path(e.path))


def open_new(path: str | Path, append: bool = False) -> int:
    """A file descriptor for writing lfusd's own file ``path`` (truncated, or appended to), never
    through a link: a link there is refused in one line (``O_NOFOLLOW``)."""
    flags = os.O_WRONLY | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    flags |= os.O_APPEND if append else os.O_TRUNC
    try:
        return os.open(path, flags, 0o666)
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise link_error(Path(path)) from None
        raise


def _unlink(path: Path) -> None:
    """Remove a file (or a link, never its target); a missing one is fine."""
    with contextlib.suppress(FileNotFoundError):
        if os.path.isdir(path) and not is_link(path):
            return  # a folder where lfusd writes a file: not lfusd's, keep it
        os.unlink(path)


def _rmdir_if_empty(path: Path) -> None:
    with contextlib.suppress(OSError):  # not empty (a user's file), missing, or a link: kept
        if not is_link(path):
            os.rmdir(path)


def remove_temporaries(folder: Path) -> None:
    """Remove the hidden temporaries lfusd's atomic writes leave in ``folder`` when killed
    (:data:`TMP_NAME`), never following links; nothing else."""
    if is_link(folder) or not folder.is_dir():
        return
    with os.scandir(folder) as it:
        for e in it:
            if TMP_NAME.fullmatch(e.name):
                if e.is_dir(follow_symlinks=False):
                    shutil.rmtree(e.path, ignore_errors=True)  # rmtree never follows links inside
                else:
                    _unlink(Path(e.path))


def remove_own(out: str | Path, manifest) -> None:
    """Remove what lfusd wrote for the dataset in ``out`` (a validated manifest), nothing else:
    per rig of the manifest, frame and view, the files lfusd's layout names there and their
    temporaries; frame.json; the object table; the worker logs; the scratch folder; then the
    folders this left empty, and the manifest last (an interrupted removal is finished by the
    next one). A user's file anywhere in these folders, and so its folders, stays."""
    from ..camera import RigSpec

    out = Path(out)
    specs = manifest.settings.rigs  # a lfusd.data.folder.Manifest
    rigs = [r for r in manifest.rigs if r in specs]
    check_tree(out, rigs)
    frames = manifest.frames
    names = set(layout.VIEW_FILES) | set(layout.VIEW_FILES_V1)
    for rig in rigs:
        views = [view_key(v) for v in RigSpec.from_dict(specs[rig]).views]
        for f in frames:
            fd = frame_dir(out, rig, f)
            if not fd.is_dir():
                continue
            for key in views:
                vd = fd / key
                if vd.is_dir():
                    remove_temporaries(vd)
                    for name in names:
                        _unlink(vd / name)
                    _rmdir_if_empty(vd)
            remove_temporaries(fd)
            _unlink(fd / layout.FRAME_META)
            _rmdir_if_empty(fd)
        _rmdir_if_empty(out / rig)
    logs = out / layout.LOGS
    if logs.is_dir():
        with os.scandir(logs) as it:
            for e in it:
                if LOG_NAME.fullmatch(e.name) and e.name.split("-unit")[0] in rigs:
                    _unlink(Path(e.path))
        _rmdir_if_empty(logs)
    scratch = out / layout.SCRATCH
    if scratch.is_dir() and not is_link(scratch):
        shutil.rmtree(scratch)
    remove_temporaries(out)
    _unlink(out / layout.OBJECTS)
    _unlink(out / layout.MANIFEST)


def remove_stale(out: str | Path, rigs) -> None:
    """Remove what a killed run left (it holds no lock any more: the caller holds it): the
    temporaries of atomic writes and view commits in OUT, in each rig's frame folders and view
    folders, and the scratch folder. Links are refused first (:func:`check_tree`)."""
    out = Path(out)
    check_tree(out, rigs)
    remove_temporaries(out)
    for rig in rigs:
        rig_dir = out / rig
        if not rig_dir.is_dir():
            continue
        with os.scandir(rig_dir) as it:
            frame_dirs = [Path(e.path) for e in it if e.is_dir(follow_symlinks=False)]
        for fd in frame_dirs:
            remove_temporaries(fd)
            with os.scandir(fd) as it:
                for e in it:
                    if e.is_dir(follow_symlinks=False) and not e.name.startswith("."):
                        remove_temporaries(Path(e.path))
    scratch = out / layout.SCRATCH
    if scratch.is_dir() and not is_link(scratch):
        shutil.rmtree(scratch, ignore_errors=True)
