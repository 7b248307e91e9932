"""Derive the motion ground truth of a rendered dataset (raw passes -> motion.npz per view).

Frame t's forward keys need frame t+1 rendered too (and backward keys t-1); at the ends of the
rendered range they are masked invalid, as CONVENTIONS.md states. Each motion.npz is recorded in
its view's completion record with the digests of the raw passes it came from (t-1, t, t+1), so a
frame derived at the end of one range is derived again when its neighbour arrives with the next:
ranges rendered in pieces join without a seam.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import tempfile
import threading
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from ..data import integrity
from ..processes import die_with_parent
from ..data.formats import file_mode
from ..data.dataset import Dataset
from ..camera import View
from ..layout import MOTION_FILE, PASSES_EXR, frame_dir, view_key

RUN = 8  # frames of one view per task: the task's Dataset reads each raw pass once, bar the two at its ends


def derive_view(ds: Dataset, frame: int, view: View) -> dict[str, np.ndarray]:
    """All motion keys of one view at one frame, from its raw passes and its neighbours'."""
    from ..errors import LfusdError
    from .motion import derive_motion

    frames = set(ds.manifest["frames"])
    try:
        nxt = ds.raw_passes(frame + 1, view) if frame + 1 in frames else None
        prv = ds.raw_passes(frame - 1, view) if frame - 1 in frames else None
        return derive_motion(ds.raw_passes(frame, view), nxt, prv, baseline=ds.baseline)
    except LfusdError as e:
        raise LfusdError(f"{ds.root} frame {frame} view {view[0]},{view[1]}: {e}") from None


def _passes_of(ds: Dataset, frame: int, view: View) -> dict[str, Path | None]:
    """The raw-pass files a derivation of (frame, view) reads: {"prev", "cur", "next"}; None where the
    dataset has no such frame (as :func:`derive_view` decides)."""
    frames = set(ds.manifest["frames"])
    return {k: frame_dir(ds.root, ds.rig_name, g) / view_key(view) / PASSES_EXR if k == "cur" or g in frames else None
            for k, g in (("prev", frame - 1), ("cur", frame), ("next", frame + 1))}


def write_motion(ds: Dataset, frame: int, view: View) -> Path:
    """Derive and store ``motion.npz`` for one view, atomically, and record it with its inputs."""
    inputs = integrity.motion_inputs(_passes_of(ds, frame, view))
    keys = derive_view(ds, frame, view)
    d = ds.view_dir(frame, view)
    fd, tmp = tempfile.mkstemp(dir=d, prefix=".motion.", suffix=".npz")
    try:
        os.fchmod(fd, file_mode())  # mkstemp makes 0600; a dataset is shared like its other files
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **keys)
        os.replace(tmp, d / MOTION_FILE)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    integrity.record_motion(d, inputs)
    return d / MOTION_FILE


def derive_if_stale(ds: Dataset, frame: int, view: View) -> bool:
    """Write one view's motion unless it is current (as :func:`derive_dataset` decides); whether it wrote."""
    d = ds.view_dir(frame, view)
    if not integrity.motion_problem(d) and not integrity.motion_problem(d, integrity.motion_inputs(_passes_of(ds, frame, view))):
        return False  # (the first check needs no hashing: a freshly rendered view has no motion yet)
    write_motion(ds, frame, view)
    return True


def _derive_run(args: tuple[str, str, tuple[int, int], list[int]]) -> int:
    root, rig, view, frames = args
    ds = Dataset(root, rig=rig)
    for f in frames:
        write_motion(ds, f, view)
    return len(frames)


def _pool_init(parent: int) -> None:
    """Derivation pool processes: the parent alone answers Ctrl-C, and they die with it."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent(parent)


def derive_dataset(
    root: str | Path,
    rigs: list[str] | None = None,
    frames: list[int] | None = None,
    workers: int = 1,
    overwrite: bool = False,
    progress=None,
    views: list[View] | None = None,
) -> int:
    """Write motion.npz for every (rig, frame, view) whose motion is not current (all of them with ``overwrite``).

    Current: present, matching the view's record, and derived from the raw passes now at t-1, t
    and t+1. The neighbours of the selected frames are checked too (a frame rendered next to them
    changes their motion). ``rigs``, ``frames`` and ``views`` default to every rig, completely
    rendered frame and view of the dataset. Returns how many views were written.
    """
    from ..data.export import open_datasets

    todo = []
    for ds in open_datasets(root) if rigs is None else [Dataset(root, rig=rig) for rig in rigs]:
        wanted = set(ds.frames if frames is None else frames)
        # A neighbour's motion changes when a frame next to it arrives (its t+-1 keys were masked):
        # it is a candidate too, derived again only if its record says it came from other passes.
        candidates = sorted(wanted | {g for f in wanted for g in (f - 1, f + 1) if g in ds.frames})
        # Runs of frames of one view: consecutive frames share t+/-1 in the dataset's raw-pass cache.
        for v in ds.views if views is None else views:
            # view_dir raises naming a view or frame the dataset lacks
            stale = [f for f in candidates if (overwrite and f in wanted)
                     or integrity.motion_problem(ds.view_dir(f, v), integrity.motion_inputs(_passes_of(ds, f, v)))]
            todo += [(str(root), ds.rig_name, tuple(v), stale[i : i + RUN]) for i in range(0, len(stale), RUN)]
    if workers <= 1 or len(todo) <= 1:
        for item in todo:
            n = _derive_run(item)
            progress and progress(n)
    else:
        # spawn, not fork: forking after numba's or BLAS's threads have run can kill the child.
        # The pool's processes are started (in submit) while this process ignores Ctrl-C, a
        # disposition they inherit through exec (a blocked mask is not: measured) and Python keeps:
        # a Ctrl-C to the process group while they start up must not kill them with a traceback.
        main = threading.current_thread() is threading.main_thread()  # only it may set handlers
        handler = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
        try:
            pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                                       initializer=_pool_init, initargs=(os.getpid(),))
            futures = [pool.submit(_derive_run, item) for item in todo]
        finally:
            if main:
                signal.signal(signal.SIGINT, signal.SIG_DFL if handler is None else handler)
        try:
            for f in futures:
                n = f.result()
                progress and progress(n)
        except BaseException:
            # Interrupted or failed: stop the pool now rather than let it finish its queue.
            for p in list((getattr(pool, "_processes", None) or {}).values()):
                p.terminate()
            pool.shutdown(wait=False, cancel_futures=True)
            raise
        pool.shutdown(wait=True)
    return sum(len(item[3]) for item in todo)
