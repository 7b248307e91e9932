"""Derive the motion ground truth of a rendered dataset (raw passes -> motion.npz per view).

Frame t's forward keys need frame t+1 rendered too (and backward keys t-1); at the ends of the
rendered range they are masked invalid, as CONVENTIONS.md states.
"""

from __future__ import annotations

import multiprocessing
import os
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from ..data.dataset import Dataset
from ..camera import View
from ..layout import MOTION_FILE

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


def write_motion(ds: Dataset, frame: int, view: View) -> Path:
    """Derive and store ``motion.npz`` for one view, atomically."""
    keys = derive_view(ds, frame, view)
    d = ds.view_dir(frame, view)
    fd, tmp = tempfile.mkstemp(dir=d, prefix=".motion.", suffix=".npz")
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **keys)
        os.replace(tmp, d / MOTION_FILE)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return d / MOTION_FILE


def _derive_run(args: tuple[str, str, tuple[int, int], list[int]]) -> int:
    root, rig, view, frames = args
    ds = Dataset(root, rig=rig)
    for f in frames:
        write_motion(ds, f, view)
    return len(frames)


def derive_dataset(
    root: str | Path,
    rigs: list[str] | None = None,
    frames: list[int] | None = None,
    workers: int = 1,
    overwrite: bool = False,
    progress=None,
    views: list[View] | None = None,
) -> int:
    """Write motion.npz for every (rig, frame, view) that lacks one (all of them with ``overwrite``).

    ``rigs``, ``frames`` and ``views`` default to every rig, completely rendered frame and view of
    the dataset. Returns how many views were written.
    """
    from ..data.export import open_datasets

    todo = []
    for ds in open_datasets(root) if rigs is None else [Dataset(root, rig=rig) for rig in rigs]:
        rig_frames = ds.frames if frames is None else frames
        # Runs of frames of one view: consecutive frames share t+/-1 in the dataset's raw-pass cache.
        for v in ds.views if views is None else views:
            # view_dir raises naming a view or frame the dataset lacks
            missing = [f for f in rig_frames if overwrite or not (ds.view_dir(f, v) / MOTION_FILE).is_file()]
            todo += [(str(root), ds.rig_name, tuple(v), missing[i : i + RUN]) for i in range(0, len(missing), RUN)]
    if workers <= 1 or len(todo) <= 1:
        for item in todo:
            n = _derive_run(item)
            progress and progress(n)
    else:
        # spawn, not fork: forking after numba's or BLAS's threads have run can kill the child
        with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn")) as pool:
            for n in pool.map(_derive_run, todo):
                progress and progress(n)
    return sum(len(item[3]) for item in todo)
