"""Motion derivation overlapped with rendering (`lfusd render-video`).

The Blender workers hand each chunk of views over as soon as it is written and render on; the
parent commits the views (lfusd.render.executors.commit_view) and tells a :class:`MotionScheduler`,
which derives frame t of a view as soon as the raw passes of t-1, t and t+1 are in place (those
of them the dataset has), in derivation processes ("lanes") that run beside the renderer. What
could not be derived early (a neighbour from an earlier run, a unit on Ray) is derived at the end
by lfusd.truth.derive.derive_dataset, as before.

A view always goes to the same lane, which keeps a Dataset per recent view. With exact occlusion
(geometry.npz beside the passes) the motion of t decodes t's raw passes alone: t-1's and t+1's
only lend their cameras (lfusd.data.passes.LazyRawPasses). The image-space route of older
datasets reads the neighbours' images too: the raw passes of t-1 and t then stay decoded for
frame t+1 within a memory budget (:data:`RAW_CACHE_BYTES` per lane); beyond it a view's passes
are decoded again, never held.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import threading
from collections import OrderedDict
from concurrent.futures import Future, ProcessPoolExecutor
from pathlib import Path

from ..processes import derivation_process_init, own_process_group
from . import request

log = logging.getLogger(__name__)

# Decoded raw passes of one view and frame (lfusd.data.passes.read_raw with the motion AOVs): the
# file's 18 channels as float32/int32, depth 4, normal 12, position 12, instance 4, vector 16,
# next/prev position 12 + 12 bytes per pixel.
RAW_BYTES_PER_PIXEL = request.RAW_BYTES_PER_PIXEL[True]
RAW_CACHE_BYTES = 1 << 30  # per lane: at 512x512 about 14 views' windows, at 1024x1024 3
RAW_PER_VIEW = 4  # a Dataset keeps its 4 most recent raw passes (t-1, t, t+1 and the one before)

# A lane's memory at 1024x1024, rounded up: the static memo of its views (lfusd.truth.visibility,
# 30 bytes per pixel a view), RAW_CACHE_BYTES at most, and one view's derivation (about 0.5 GB).
LANE_BYTES = 2 << 30


def derivation_lanes(workers: int, device: str, views: int, cores: int | None = None, memory: int | None = None) -> int:
    """How many derivation processes render-video runs beside ``workers`` Blender workers.

    On the CPU the renderer has the cores: one lane per worker. On a GPU (``device`` cuda or optix,
    or auto where the machine has an NVIDIA device) a lane keeps up with about 1.5 views per second
    at 1024x1024 (0.6 core-s each), slower than the GPU renders, so lanes take the cores the
    workers leave (less one, for the parent's commits), at most one per view of a frame (a view
    stays on one lane) and one per :data:`LANE_BYTES` of half the memory; never fewer than the workers."""
    if device == "cpu" or (device == "auto" and not nvidia_device()):
        return max(1, workers)
    cores = request.usable_cores() if cores is None else cores
    memory = request.memory_available() if memory is None else memory
    fit = (memory // 2) // LANE_BYTES if memory else 1
    return max(1, workers, min(cores - workers - 1, views, fit))


def nvidia_device() -> bool:
    """Whether the NVIDIA driver shows a device here (what Blender's auto device turns to CUDA or OptiX)."""
    return any(os.path.exists(p) for p in ("/dev/nvidiactl", "/proc/driver/nvidia/gpus"))


View = tuple[int, int]
_DATASETS: OrderedDict = OrderedDict()  # in a lane: (root, rig, view) -> Dataset, most recent last


def _warm() -> None:
    """Import the derivation (and load numba's compiled kernels, and Open3D) while the first frame renders."""
    import open3d  # noqa: F401  (a second of CPU: charged to start-up, not to the first view)

    from .. import cpu_account
    from ..truth import derive, motion  # noqa: F401

    motion.load_kernels()
    cpu_account.startup()


def _derive(root: str, rig: str, view: View, frames: list[int], cached_views: int) -> int:
    """In a lane: derive the motion of ``frames`` of one view that is not current; how many were written."""
    from ..data.dataset import open_dataset
    from ..truth.derive import derive_if_stale

    key = (root, rig, view)
    ds = _DATASETS.pop(key, None) or open_dataset(root, rig)
    _DATASETS[key] = ds
    while len(_DATASETS) > cached_views:
        _DATASETS.popitem(last=False)
    from .. import cpu_account

    n = sum(derive_if_stale(ds, f, view) for f in frames)
    cpu_account.flush("lane")
    return n


def cached_views(width: int, height: int, budget: int = RAW_CACHE_BYTES) -> int:
    """How many views' recent raw passes a lane keeps decoded within ``budget`` bytes (at least one)."""
    return max(1, budget // (RAW_PER_VIEW * RAW_BYTES_PER_PIXEL * width * height))


def _view(key: str) -> View:
    row, col = key.split("_")
    return int(row), int(col)


class MotionScheduler:
    """Derive each view's motion as soon as its frame and the neighbours it has are committed.

    ``views_of``: rig -> (its views, (width, height)); ``frames``: the frames this run renders;
    ``dataset_frames``: every frame of the dataset (the manifest's: a frame's neighbour counts only
    if the dataset has it); ``todo``: the (rig, frame, view) this run renders (the others of
    ``frames`` are complete on disk already); ``lanes``: derivation processes."""

    def __init__(self, out: Path, views_of: dict[str, tuple[list[View], tuple[int, int]]], frames: list[int],
                 dataset_frames: list[int], todo: set[tuple[str, int, View]], lanes: int = 1):
        self.out = str(Path(out))
        self.views_of, self.todo = views_of, todo
        self.dataset_frames = set(dataset_frames)
        wanted = set(frames)
        # as derive_dataset: a neighbour's motion changes when a frame next to it arrives
        self.candidates = sorted(wanted | {g for f in wanted for g in (f - 1, f + 1) if g in self.dataset_frames})
        self.committed_views: set[tuple[str, int, View]] = set()
        self.submitted: set[tuple[str, int, View]] = set()
        self.on_disk: dict[tuple[str, int, View], bool] = {}
        self.futures: list[Future] = []
        self.error: BaseException | None = None
        self.lock = threading.Lock()
        self.lane_of = {(rig, v): i for rig, (views, _) in views_of.items() for i, v in enumerate(views)}
        from ..truth.motion import announce_compile

        announce_compile()  # the lanes' first derivation may compile for minutes: say so
        # spawn, not fork: forking after numba's, BLAS's or the executor's threads have run can kill the child
        ctx = multiprocessing.get_context("spawn")
        handler = None
        self.lanes = []
        try:
            # A Ctrl-C while they start must not reach them (lfusd stops them); held, it is raised
            # at the end of the block.
            with own_process_group() as apart:
                if not apart and threading.current_thread() is threading.main_thread():
                    handler = signal.signal(signal.SIGINT, signal.SIG_IGN)
                try:
                    for _ in range(max(1, lanes)):
                        self.lanes.append(ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=derivation_process_init,
                                                              initargs=(os.getpid(),)))
                        self.lanes[-1].submit(_warm)  # starts the process now, beside the workers' start-up
                finally:
                    if handler is not None:
                        signal.signal(signal.SIGINT, handler)
        except BaseException:
            self.stop(now=True)  # lanes still starting must not read what this process is about to remove
            raise

    def _in_place(self, rig: str, frame: int, view: View) -> bool:
        key = (rig, frame, view)
        if key in self.committed_views:
            return True
        if key in self.todo:
            return False  # this run renders it, and has not yet
        if key not in self.on_disk:  # rendered by an earlier run (or missing): a quick check, once
            from ..data.integrity import render_problems
            from ..layout import frame_dir, view_key

            self.on_disk[key] = not render_problems(frame_dir(self.out, rig, frame) / view_key(view), deep=False)
        return self.on_disk[key]

    def _ready(self, rig: str, frame: int, view: View) -> bool:
        return all(self._in_place(rig, g, view) for g in (frame - 1, frame, frame + 1) if g == frame or g in self.dataset_frames)

    def committed(self, rig: str, frame: int, key: str) -> None:
        """A view is in place: submit every derivation it completes. Raises a lane's error, so a
        failing derivation stops the render at once."""
        view = _view(key)
        with self.lock:
            if self.error is not None:
                raise self.error
            self.committed_views.add((rig, frame, view))
            for c in (frame - 1, frame, frame + 1):
                job = (rig, c, view)
                if c in self.candidates and job not in self.submitted and self._ready(*job):
                    self.submitted.add(job)
                    lane = self.lanes[self.lane_of[(rig, view)] % len(self.lanes)]
                    w, h = self.views_of[rig][1]
                    fut = lane.submit(_derive, self.out, rig, view, [c], cached_views(w, h))
                    fut.add_done_callback(self._done)
                    self.futures.append(fut)

    def _done(self, fut: Future) -> None:
        if not fut.cancelled() and fut.exception() is not None and self.error is None:
            self.error = fut.exception()

    def finish(self) -> tuple[int, dict[str, list[int]]]:
        """Wait for the lanes: (views written, rig -> frames some view of which is left to derive)."""
        written = sum(f.result() for f in self.futures)
        left = {}
        for rig, (views, _) in self.views_of.items():
            frames = [f for f in self.candidates if any((rig, f, v) not in self.submitted for v in views)]
            if frames:
                left[rig] = frames
        return written, left

    def stop(self, now: bool = False) -> None:
        """Stop the lanes now (the render failed or ended); what they wrote is complete or absent."""
        for lane in self.lanes:
            lane.shutdown(wait=True, cancel_futures=True)

    def _terminate(self) -> None:
        for lane in self.lanes:
            for p in list((getattr(lane, "_processes", None) or {}).values()):
                p.terminate()
            lane.shutdown(wait=False, cancel_futures=True)


class CommitReport:
    """The progress report the executors call, which also tells the scheduler of each committed view."""

    def __init__(self, report, scheduler: MotionScheduler):
        self.report, self.scheduler = report, scheduler

    def advance(self, n: int) -> None:
        self.report.advance(n)

    def committed(self, rig: str, frame: int, key: str) -> None:
        self.scheduler.committed(rig, frame, key)

    def close(self) -> None:
        self.report.close()
