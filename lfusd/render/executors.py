"""Running work units (rig x views x frames) in Blender worker processes: locally or on Ray.

A unit is one Blender worker process: it imports the stage once and renders its frames of its
views with multiview. Each view is committed (moved from the worker's scratch folder into the
dataset, atomically) as soon as its frame is written, so any failure loses at most the frame in
flight of each worker.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
import socket
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

from ..data import confined
from ..data.passes import read_rgb_linear
from ..errors import LfusdError
from .. import layout
from ..layout import frame_dir
from ..processes import PARENT_PID_ENV
from .plan import WorkUnit
from .request import RenderRequest

log = logging.getLogger(__name__)

# The Blender worker: a JSON WorkUnit on stdin, "LFUSD {json}" event lines on stdout.
WORKER = [sys.executable, "-X", "faulthandler", "-m", "lfusd.render.worker"]


def _check_rgb(src: Path, key: str, frame: int, unit: WorkUnit):
    """The beauty of one view as linear RGB, refused unless it reads back whole at the unit's size."""
    try:
        rgb = read_rgb_linear(src)
    except LfusdError as e:
        raise _damaged(src, key, frame, e) from None
    _check_shape(src, rgb.shape[:2], key, frame, unit)
    return rgb


def _check_passes(src: Path, key: str, frame: int, unit: WorkUnit) -> None:
    """Refuse a data-pass EXR unless every channel decodes (a cut-off file does not) with the unit's
    size and passes. Decoding only, without read_raw's conversions: a third of the time."""
    from ..data.passes import MOTION_AOVS, read_exr

    try:
        channels = read_exr(src)
        wanted = ["Depth.Z", "Vector.X"] + (list(MOTION_AOVS) if unit.motion else [])
        lacking = [p for p in wanted if not any(n == p or n.endswith("." + p) for n in channels)]
        if lacking:
            raise LfusdError(f"it has no {', '.join(p.split('.')[0] for p in lacking)} pass")
    except LfusdError as e:
        raise _damaged(src, key, frame, e) from None
    shapes = {a.shape[:2] for a in channels.values()}
    _check_shape(src, shapes.pop() if len(shapes) == 1 else (0, 0), key, frame, unit)


def _damaged(src: Path, key: str, frame: int, e: LfusdError) -> LfusdError:
    why = str(e).split(";")[0]
    return LfusdError(f"Blender wrote a damaged {src.name} for view {key} of frame {frame} ({why}); "
                      "free disk space if it is full, then rerun to resume")


def _check_shape(src: Path, shape, key: str, frame: int, unit: WorkUnit) -> None:
    h, w = unit.height, unit.width
    if tuple(shape) != (h, w):
        raise LfusdError(f"Blender wrote {src.name} for view {key} of frame {frame} at {shape[1]}x{shape[0]}, not {w}x{h}; rerun to resume")


def commit_view(out: Path, rig: str, frame: int, key: str, scratch: Path, unit: WorkUnit | None = None) -> None:
    """Move one view's raw files from a worker's scratch into its final folder, atomically.

    The files are checked first (with ``unit``: readable, the right passes and size); the folder
    gets its completion record last, before the rename. A complete view already there is kept; a
    damaged one is replaced. Files are renamed, never copied (the scratch is inside OUT)."""
    from ..data import integrity

    final = frame_dir(out, rig, frame) / key
    if integrity.view_complete(final):
        return
    sources = {name: scratch / f"{name}_{key}.exr" for name in ("rgb", "passes")}  # Blender's multiview suffix
    for src in sources.values():
        if not src.is_file():
            raise LfusdError(f"Blender wrote no {src.name} for view {key} of frame {frame}; rerun to resume")
    if unit is not None:
        _check_rgb(sources["rgb"], key, frame, unit)
        _check_passes(sources["passes"], key, frame, unit)
    tmp = final.parent / f".{key}.tmp-{os.getpid()}-{threading.get_ident()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    for name, final_name in (("rgb", layout.RGB_EXR), ("passes", layout.PASSES_EXR)):
        os.replace(sources[name], tmp / final_name)
    geometry = scratch / layout.GEOMETRY  # one per chunk of views: linked into each (copied where links fail)
    if geometry.is_file():
        try:
            os.link(geometry, tmp / layout.GEOMETRY)
        except OSError:
            shutil.copyfile(geometry, tmp / layout.GEOMETRY)
    integrity.record_render(tmp)  # rgb.png, gt.exr and motion.exr come from lfusd.truth.derive
    if final.exists():  # damaged: move it aside (a stale-tmp name, cleaned by the next run if we die here)
        old = final.parent / f".{key}.tmp-old-{os.getpid()}-{threading.get_ident()}"
        os.rename(final, old)
        os.rename(tmp, final)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.rename(tmp, final)


_LIVE: set[subprocess.Popen] = set()
_LIVE_LOCK = threading.Lock()


def run_unit(unit: WorkUnit, out: Path, report=None, stopping: threading.Event | None = None) -> str:
    """Run one Blender worker over a unit, committing views as the worker hands them over; return
    the device used.

    ``report.advance(1)`` is called per committed view, and ``report.committed(rig, frame, key)``
    too where the report has it (render-video derives motion from it while rendering goes on).
    The worker's warnings are logged here (they reach the terminal); all its output goes to the log."""
    committed = getattr(report, "committed", None)
    scratch = out / layout.SCRATCH / f"{unit.rig}-{unit.unit}-{os.getpid()}-{threading.get_ident()}"
    logs = out / layout.LOGS
    logs.mkdir(parents=True, exist_ok=True)
    log_path = logs / f"{unit.rig}-unit{unit.unit:04d}.log"
    device, error = "cpu", None
    with os.fdopen(confined.open_new(log_path), "w") as log_file:  # never through a link planted there
        proc = subprocess.Popen(
            WORKER,
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=log_file, text=True, bufsize=1,
            env={**os.environ, PARENT_PID_ENV: str(os.getpid())},  # the worker dies with this process
        )
        with _LIVE_LOCK:
            _LIVE.add(proc)
            if stopping is not None and stopping.is_set():  # started while its pool was being stopped
                proc.kill()
        try:
            proc.stdin.write(json.dumps({**unit.to_json(), "scratch": str(scratch)}))
            proc.stdin.close()
            for line in proc.stdout:
                if not line.startswith("LFUSD "):
                    continue  # Blender's own chatter
                event = json.loads(line[6:])
                if event["event"] == "ready":
                    device = event["device"]
                elif event["event"] == "frame":  # one chunk of views of a frame
                    log.debug("rig %s frame %d: %d views in %.2f s %s, scene evaluated at %d times so far", unit.rig, event["frame"],
                              len(event["views"]), event.get("seconds", 0.0), event.get("phases", {}), event.get("evaluations", 0))
                    for key in event["views"]:
                        commit_view(out, unit.rig, event["frame"], key, Path(event["scratch"]), unit)
                        if report is not None:
                            report.advance(1)
                        if committed is not None:
                            committed(unit.rig, event["frame"], key)
                    shutil.rmtree(event["scratch"], ignore_errors=True)
                elif event["event"] == "warning":
                    log.warning("%s (rig %s, log %s)", event["message"], unit.rig, log_path)
                elif event["event"] == "error":
                    error = event["message"]
            code = proc.wait()
        finally:
            with _LIVE_LOCK:
                _LIVE.discard(proc)
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            shutil.rmtree(scratch, ignore_errors=True)
    if error or code != 0:
        what = error or f"exited with code {code} (log: {log_path})"
        frames = unit.frames
        raise LfusdError(
            f"Blender worker for rig {unit.rig} (frames {frames[0]}-{frames[-1]}) failed: {what.splitlines()[0]}; "
            "finished views are kept, rerun the same command to resume"
        )
    return device


def _kill_all(stopping: threading.Event) -> None:
    with _LIVE_LOCK:
        stopping.set()
        for proc in list(_LIVE):
            if proc.poll() is None:
                proc.kill()


def run_local(units: list[WorkUnit], req: RenderRequest, report) -> str:
    """A pool of ``req.workers`` Blender processes on this machine; the first failure stops all."""
    from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait

    pool = ThreadPoolExecutor(max_workers=req.workers)
    stopping = threading.Event()  # set while this pool stops: no new worker of it may live
    try:
        futures = [pool.submit(run_unit, u, req.out, report, stopping) for u in units]
        done, _ = wait(futures, return_when=FIRST_EXCEPTION)
        for f in done:
            if f.exception() is not None:
                raise f.exception()
        devices = [f.result() for f in futures]
    finally:
        _kill_all(stopping)
        pool.shutdown(wait=True, cancel_futures=True)
    return devices[0] if devices else "cpu"


def _ray_unit(unit: WorkUnit, out: str) -> str | None:
    """A Ray task: render the unit's frames that are not complete yet; return the device used (None
    when nothing was left). Ray retries a task whose node died; the dead attempt's committed views
    are kept, so a node loss costs at most its frame in flight."""
    import ray

    from ..data import integrity

    root = Path(out)
    todo = [f for f in unit.frames if not all(integrity.view_complete(frame_dir(root, unit.rig, f) / k) for k in unit.cameras)]
    record_attempt(root, unit, ray.get_runtime_context().get_node_id(), todo)
    if not todo:
        return None
    return run_unit(replace(unit, frames=todo), root)


def record_attempt(out: Path, unit: WorkUnit, node_id: str, frames: list[int]) -> None:
    """Append one line per Ray attempt of a unit to OUT/logs/<rig>-unit<n>.ray.jsonl: the node it
    ran on and the frames it rendered (the unit's others were complete). Where a unit ran, and what a
    retry rendered again, is then on record; one attempt of a unit runs at a time, so no two writers."""
    logs = out / layout.LOGS
    logs.mkdir(parents=True, exist_ok=True)
    line = {"unit": unit.unit, "node_id": node_id, "host": socket.gethostname(), "pid": os.getpid(),
            "frames": frames, "views": sorted(unit.cameras), "time": time.time()}
    with os.fdopen(confined.open_new(logs / f"{unit.rig}-unit{unit.unit:04d}.ray.jsonl", append=True), "a") as f:
        f.write(json.dumps(line) + "\n")


def check_ray_address(address: str) -> None:
    """Fail fast, in one line, when nothing listens at a host:port Ray address."""
    host, _, port = address.rpartition(":")
    if "://" in address or not port.isdigit():
        return  # ray:// client addresses and 'auto' are Ray's to resolve
    try:
        socket.create_connection((host or "127.0.0.1", int(port)), timeout=5).close()
    except OSError as e:
        raise LfusdError(f"cannot reach the Ray cluster at {address} ({e.strerror or e}); check --ray-address, or leave it out to start a local Ray") from None


# Ray's switch that keeps "localhost" loopback (rather than this machine's network address); read
# when Ray is first imported, so it is also set on the imported module.
_RAY_LOOPBACK_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
LOOPBACK = ("127.0.0.1", "::1", "::ffff:127.0.0.1")


@contextlib.contextmanager
def _quiet_auth_advice():
    """Hide Ray's advice to disable its token authentication (lfusd never recommends that), and
    say in one line when it is disabled (RAY_AUTH_MODE=disabled)."""
    if os.environ.get("RAY_AUTH_MODE", "").lower() == "disabled":
        log.warning("Ray's token authentication is disabled (RAY_AUTH_MODE=disabled): anyone who can reach the Ray "
                    "cluster can run code on its machines; unset RAY_AUTH_MODE to turn it back on")
    ray_log = logging.getLogger("ray._private.authentication.authentication_token_setup")
    level = ray_log.level
    ray_log.setLevel(logging.ERROR)
    try:
        yield
    finally:
        ray_log.setLevel(level)


def start_local_ray(workers: int) -> None:
    """Start a Ray instance on this machine for ``workers`` tasks, every server of it bound to
    loopback (Ray binds to its node address, which is this machine's network address unless it
    is told loopback): nobody elsewhere on the network can reach it. Joining a cluster is the
    user's explicit ``--ray-address``. LfusdError if Ray did not stay on loopback."""
    os.environ[_RAY_LOOPBACK_ENV] = "0"  # inherited by the Ray processes this starts
    import ray
    from ray._private import ray_constants

    ray_constants.ENABLE_RAY_CLUSTER = False  # Ray already imported (by a library user) read the variable before
    with _quiet_auth_advice():
        info = ray.init(num_cpus=workers, include_dashboard=False, ignore_reinit_error=True, log_to_driver=False,
                        _node_ip_address="127.0.0.1")
    node = (getattr(info, "address_info", None) or {}).get("node_ip_address")
    if node not in LOOPBACK:
        ray.shutdown()
        raise LfusdError(f"the local Ray instance came up on {node}, not loopback only; "
                         "use --executor local, or start a cluster yourself and pass --ray-address")


def run_ray(units: list[WorkUnit], req: RenderRequest, report) -> str:
    """The same units as Ray tasks (retried on failure); outputs go to ``req.out``, a shared path."""
    import ray

    if req.ray_address:
        check_ray_address(req.ray_address)
    try:
        if req.ray_address:
            with _quiet_auth_advice():
                ray.init(address=req.ray_address, ignore_reinit_error=True, log_to_driver=False)
        else:
            start_local_ray(req.workers)
    except LfusdError:
        raise
    except Exception as e:  # Ray raises ConnectionError, RuntimeError, ValueError, ...
        where = f"the Ray cluster at {req.ray_address}" if req.ray_address else "a local Ray instance"
        raise LfusdError(f"cannot join {where} ({str(e).splitlines()[0]}); check --ray-address or use --executor local") from None
    task = ray.remote(num_cpus=1, max_retries=2, retry_exceptions=True)(_ray_unit)
    refs = {task.remote(u, str(Path(req.out).resolve())): u for u in units}
    device = "cpu"
    try:
        while refs:
            done, _ = ray.wait(list(refs), num_returns=1)
            unit = refs.pop(done[0])
            try:
                device = ray.get(done[0]) or device  # None: a retry found its frames complete
            except ray.exceptions.RayTaskError as e:
                cause = getattr(e, "cause", None)
                msg = str(cause) if isinstance(cause, LfusdError) else f"a Ray task of rig {unit.rig} failed after retries ({str(e).splitlines()[0]}); rerun to resume"
                raise LfusdError(msg) from None
            report.advance(len(unit.cameras) * len(unit.frames))
    finally:
        for r in refs:
            ray.cancel(r, force=True)
        if not req.ray_address:
            ray.shutdown()
    return device


def run_units(units: list[WorkUnit], req: RenderRequest, report) -> str:
    """Run ``units`` with the requested executor; return the device used."""
    return (run_ray if req.executor == "ray" else run_local)(units, req, report)
