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
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

from .. import cpu_account
from ..data import confined
from ..data.formats import link_or_copy
from ..data.passes import read_rgb
from ..errors import LfusdError
from .. import layout
from ..layout import frame_dir
from ..processes import PARENT_PID_ENV, hold_stops, native_stderr_silenced
from .plan import WorkUnit
from .request import RenderRequest

log = logging.getLogger(__name__)

# The Blender worker: a JSON WorkUnit on stdin, "LFUSD {json}" event lines on stdout.
WORKER = [sys.executable, "-X", "faulthandler", "-m", "lfusd.render.worker"]


def _check_rgb(src: Path, key: str, frame: int, unit: WorkUnit):
    """The beauty of one view as stored (half float), refused unless it reads back whole at the unit's size."""
    try:
        rgb = read_rgb(src)  # decoded, not converted: the check needs its channels and size
    except LfusdError as e:
        raise _damaged(src, key, frame, e) from None
    _check_shape(src, rgb.shape[:2], key, frame, unit)
    return rgb


def _check_passes(src: Path, key: str, frame: int, unit: WorkUnit) -> None:
    """Refuse a data-pass EXR unless every channel decodes (a cut-off file does not) with the unit's
    size and passes. Decoding only, without read_raw's conversions: a third of the time."""
    from ..data.passes import read_exr, uncompressed_channels
    from ..keys import MOTION_AOVS, RAW_PASS

    try:
        # uncompressed (transient raw passes): complete when its size is what its header needs, no
        # decoding (the derivation decodes it once); compressed: every channel must decode
        layout_ = uncompressed_channels(src)
        if layout_ is not None:
            names, shape = layout_
        else:
            channels = read_exr(src)
            names = list(channels)
            shapes = {a.shape[:2] for a in channels.values()}
            shape = shapes.pop() if len(shapes) == 1 else (0, 0)
        # a pass every data render writes, the vector pass, and render-video's AOVs (lfusd.keys.RAW_PASSES)
        wanted = [RAW_PASS["depth"].channel_names[0], RAW_PASS["vector"].channel_names[0]] + ([p.layer for p in MOTION_AOVS] if unit.motion else [])
        # OpenEXR's Python API groups an AOV's R, G, B, A into one array named after the AOV
        lacking = [p for p in wanted if not any(n == p or n.endswith("." + p) or n.startswith(p + ".") or f".{p}." in n for n in names)]
        if lacking:
            raise LfusdError(f"it has no {', '.join(p.split('.')[0] for p in lacking)} pass")
    except LfusdError as e:
        raise _damaged(src, key, frame, e) from None
    _check_shape(src, shape, key, frame, unit)


def _damaged(src: Path, key: str, frame: int, e: LfusdError) -> LfusdError:
    why = str(e).split(";")[0]
    return LfusdError(f"Blender wrote a damaged {src.name} for view {key} of frame {frame} ({why}); "
                      "free disk space if it is full, then rerun to resume")


def _check_shape(src: Path, shape, key: str, frame: int, unit: WorkUnit) -> None:
    h, w = unit.height, unit.width
    if tuple(shape) != (h, w):
        raise LfusdError(f"Blender wrote {src.name} for view {key} of frame {frame} at {shape[1]}x{shape[0]}, not {w}x{h}; rerun to resume")


def commit_view(out: Path, rig: str, frame: int, key: str, scratch: Path, unit: WorkUnit | None = None) -> None:
    """Move one view's rendered files from a worker's scratch into its final folder.

    The files are checked first (with ``unit``: readable, the right passes and size). A new view is
    assembled under a temporary name with its completion record last, then renamed into place. An
    existing view with a readable record is repaired in place (:func:`_repair_view`): what its record
    proves intact is kept, never replaced. A view without a readable record is replaced. Files are
    renamed, never copied (the scratch is inside OUT)."""
    from ..data import integrity

    final = frame_dir(out, rig, frame) / key
    beauty = unit is None or unit.beauty
    need = integrity.repair_need(final)
    if need is None and (beauty or integrity.passes_on_disk(final)):
        return
    if unit is not None and beauty and need == integrity.RAW:
        return  # a view whose image is intact: a unit of raw passes alone repairs it (lfusd.render.plan.plan_units)
    sources = {name: scratch / f"{name}_{key}.exr" for name in (("rgb", "passes") if beauty else ("passes",))}  # Blender's multiview suffix
    for src in sources.values():
        if not src.is_file():
            raise LfusdError(f"Blender wrote no {src.name} for view {key} of frame {frame}; rerun to resume")
    if unit is not None:
        with cpu_account.phase("raw check"):
            if beauty:
                _check_rgb(sources["rgb"], key, frame, unit)
            _check_passes(sources["passes"], key, frame, unit)
    geometry = scratch / layout.GEOMETRY  # one per chunk of views (render-video): each view gets its own link
    if geometry.is_file():
        sources["geometry"] = scratch / f"geometry_{key}.npz"
        link_or_copy(geometry, sources["geometry"])
    if integrity.read_record(final) is not None:
        _repair_view(final, {layout.RGB_EXR: sources.get("rgb"), layout.PASSES_EXR: sources["passes"],
                             layout.GEOMETRY: sources.get("geometry")})
        return
    if not beauty:
        raise LfusdError(f"view {key} of frame {frame} has no readable record, so its raw passes alone cannot repair it; rerun to resume")
    tmp = final.parent / f".{key}.tmp-{os.getpid()}-{threading.get_ident()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    for name, final_name in (("rgb", layout.RGB_EXR), ("passes", layout.PASSES_EXR), ("geometry", layout.GEOMETRY)):
        if name in sources:
            os.replace(sources[name], tmp / final_name)
    integrity.record_render(tmp)  # rgb.png, gt.exr and motion.exr come from lfusd.truth.derive
    if final.exists():  # no readable record: nothing in it is provably intact; move it aside (a stale-tmp name, cleaned by the next run if we die here)
        old = final.parent / f".{key}.tmp-old-{os.getpid()}-{threading.get_ident()}"
        # what lfusd did not write (a user's note, an extra label image) moves into the new view
        for entry in final.iterdir():
            if entry.name not in layout.VIEW_FILES and not entry.name.startswith("."):
                os.replace(entry, tmp / entry.name)
        os.rename(final, old)
        os.rename(tmp, final)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.rename(tmp, final)


def _repair_view(final: Path, new: dict[str, Path | None]) -> None:
    """Repair a view folder in place from freshly rendered files ``new`` (file name -> scratch path;
    None: not rendered). A file its record proves intact stays and the new one is dropped; a new file
    goes in where the recorded one is missing, damaged or removed; every other recorded file that
    does not match its record (a damaged gt.exr, motion.exr or rgb.png) is removed with its entry,
    for the derivation to write again. The record is rewritten last: a run killed before that leaves
    files that do not match it, which the next run repairs again."""
    from ..data import integrity

    rec = integrity.read_record(final)
    files = rec["files"]
    damaged = set(integrity.damaged_files(final))
    add = {}
    for name, src in new.items():
        if src is None:
            continue
        entry = files.get(name)
        if name == layout.RGB_EXR and entry is not None and entry.get("removed") and layout.RGB_PNG not in damaged:
            continue  # not asked for (rgb.png, intact or not asked for either, holds the image)
        if entry is not None and not entry.get("removed") and name not in damaged:
            continue  # intact: keep it
        os.replace(src, final / name)
        entry = integrity.file_entry(final / name)
        if entry is None:
            raise LfusdError(f"cannot read back {final / name}; free disk space if it is full, then rerun")
        add[name] = entry
    for name in damaged - set(add):
        if name not in new:
            (final / name).unlink(missing_ok=True)
            files.pop(name, None)
    files.update(add)
    integrity.write_record(final, rec)


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
                        with cpu_account.phase("commit"):
                            commit_view(out, unit.rig, event["frame"], key, Path(event["scratch"]), unit)
                        if report is not None:
                            report.advance(1)
                        if committed is not None:
                            committed(unit.rig, event["frame"], key)
                    shutil.rmtree(event["scratch"], ignore_errors=True)
                    cpu_account.flush("parent")
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
    def done(d: Path) -> bool:  # as commit_view decides: it commits nothing into such a view
        return integrity.passes_on_disk(d) if not unit.beauty else integrity.repair_need(d) != integrity.FULL

    todo = [f for f in unit.frames if not all(done(frame_dir(root, unit.rig, f) / k) for k in unit.cameras)]
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
    previous = os.environ.get(_RAY_LOOPBACK_ENV)
    os.environ[_RAY_LOOPBACK_ENV] = "0"  # inherited by the Ray processes this starts
    import ray
    from ray._private import ray_constants

    cluster = ray_constants.ENABLE_RAY_CLUSTER
    ray_constants.ENABLE_RAY_CLUSTER = False  # Ray already imported (by a library user) read the variable before
    try:
        with _quiet_auth_advice():
            # address "local": a new instance even where RAY_ADDRESS or a `ray start` of the user names a cluster
            info = ray.init(address="local", num_cpus=workers, include_dashboard=False, ignore_reinit_error=True, log_to_driver=False,
                            _node_ip_address="127.0.0.1", logging_level=logging.ERROR)
    finally:
        # only this instance: a later --ray-address, or a cluster node the caller starts, joins as usual
        ray_constants.ENABLE_RAY_CLUSTER = cluster
        if previous is None:
            os.environ.pop(_RAY_LOOPBACK_ENV, None)
        else:
            os.environ[_RAY_LOOPBACK_ENV] = previous
    node = (getattr(info, "address_info", None) or {}).get("node_ip_address")
    if node not in LOOPBACK:
        ray.shutdown()
        raise LfusdError(f"the local Ray instance came up on {node}, not loopback only; "
                         "use --executor local, or start a cluster yourself and pass --ray-address")


def run_ray(units: list[WorkUnit], req: RenderRequest, report) -> str:
    """The same units as Ray tasks (retried on failure); outputs go to ``req.out``, a shared path.

    Whatever ends the run (success, failure, Ctrl-C or SIGTERM at any moment, during ``ray.init``
    too, where they are held until the local instance has started), the tasks are cancelled and a
    local Ray instance this run started is shut down, with further signals held until that is done:
    nothing of Ray's or Blender's outlives lfusd."""
    # Ray's C++ failure signal handler (absl) takes SIGTERM too, and ray.shutdown uninstalls it to the
    # default: a SIGTERM during shutdown killed lfusd outright (exit -15, measured). Read when Ray loads.
    os.environ.setdefault("RAY_DISABLE_FAILURE_SIGNAL_HANDLER", "1")
    import ray

    if req.ray_address:
        check_ray_address(req.ray_address)
    main = threading.current_thread() is threading.main_thread()  # only it may set handlers
    sigterm = signal.getsignal(signal.SIGTERM) if main else None
    refs: dict = {}
    others = _children()  # derivation processes already running: not Ray's
    try:
        try:
            # logging_level: Ray's own INFO and WARNING lines (its start-up banner) would break lfusd's one-line output
            with _own_sigterm(ray):
                if req.ray_address:
                    with _quiet_auth_advice():
                        ray.init(address=req.ray_address, ignore_reinit_error=True, log_to_driver=False, logging_level=logging.ERROR)
                else:
                    # A Ctrl-C or SIGTERM while the local instance starts is held until ray.init
                    # returns (seconds), then the whole instance is shut down: raised inside ray.init,
                    # it cut the start short (processes its clean-up does not know of), or landed in
                    # Python's at-fork hooks of Ray's process starts, which print it as a traceback
                    # ("Exception ignored in: <function _releaseLock ...>", measured) and go on.
                    with hold_stops(main):
                        start_local_ray(req.workers)
        except LfusdError:
            raise
        except Exception as e:  # Ray raises ConnectionError, RuntimeError, ValueError, ...
            where = f"the Ray cluster at {req.ray_address}" if req.ray_address else "a local Ray instance"
            raise LfusdError(f"cannot join {where} ({str(e).splitlines()[0]}); check --ray-address or use --executor local") from None
        finally:
            if main and sigterm is not None:
                # ray.init makes SIGTERM sys.exit(15) (or kill its node and exit 1): lfusd's handler cleans up and exits 143
                signal.signal(signal.SIGTERM, sigterm)
        task = ray.remote(num_cpus=1, max_retries=2, retry_exceptions=True)(_ray_unit)
        for u in units:
            refs[task.remote(u, str(Path(req.out).resolve()))] = u
        device = "cpu"
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
        _stop_ray(ray, refs, shutdown=not req.ray_address, main=main, ray_processes=_children(others) if not req.ray_address else set())
    return device


@contextlib.contextmanager
def _own_sigterm(ray):
    """Keep lfusd's SIGTERM handler while ``ray.init`` runs: Ray installs its own (``sys.exit(15)``, or
    kill its node and exit 1) in the main thread, so a SIGTERM during its start ended lfusd with exit
    15 and no line (measured). Ray's private hook is replaced for that time, where it exists."""
    utils = getattr(getattr(ray, "_private", None), "utils", None)
    original = getattr(utils, "set_sigterm_handler", None)
    if original is None:
        yield
        return
    utils.set_sigterm_handler = lambda handler: None
    try:
        yield
    finally:
        utils.set_sigterm_handler = original


def _stop_ray(ray, refs: dict, shutdown: bool, main: bool, ray_processes: set[int] = frozenset()) -> None:
    """Cancel ``refs`` on a cluster lfusd joined or, when this run started the Ray instance, shut it
    down (its tasks with it) and kill what is left of ``ray_processes`` (the children ray.init
    started) and their descendants. A Ctrl-C or SIGTERM meanwhile is held and raised once that is done (:func:`lfusd.processes.hold_stops`), and so is
    the Ctrl-C that lfusd.cli latched and raises again at every import: raised inside ray.shutdown
    (which imports), it cut the shutdown short and left Ray's agents running, orphaned (measured);
    ignored, a Ctrl-C during the seconds of ray.shutdown after a finished render was lost (the run
    went on to exit 0)."""
    with hold_stops(main):
        # Tasks on a cluster lfusd joined are cancelled; those of a local instance it started end with
        # it. Cancelling those too raced with their replies inside Ray's driver (Ray 2.60: "Check failed:
        # it != submissible_tasks_.end() Tried to complete task that was not pending", a crash with exit 1
        # that cut this clean-up short and left the agents running: 4 of 34 stops under load, measured).
        for r in refs if not shutdown else ():
            with contextlib.suppress(Exception):
                ray.cancel(r, force=True)
        if shutdown:
            tree = _tree(ray_processes)  # before shutdown: its processes are still below their parents
            with contextlib.suppress(Exception), native_stderr_silenced():
                ray.shutdown()
            _kill_tree(ray_processes, tree)


def _processes() -> dict[int, tuple[int, int]]:
    """pid -> (parent pid, start time in clock ticks) of this user's processes, from /proc."""
    out, uid = {}, os.getuid()
    for entry in os.scandir("/proc") if os.path.isdir("/proc") else ():
        if not entry.name.isdigit():
            continue
        try:
            if entry.stat().st_uid != uid:
                continue
            with open(f"/proc/{entry.name}/stat", "rb") as f:
                fields = f.read().rsplit(b")", 1)[1].split()  # after the command name, which may hold spaces
            out[int(entry.name)] = (int(fields[1]), int(fields[19]))
        except (OSError, ValueError, IndexError):
            continue
    return out


def _children(exclude: set[int] = frozenset()) -> set[int]:
    """The pids of this process's direct children, bar ``exclude``."""
    me = os.getpid()
    return {pid for pid, (ppid, _) in _processes().items() if ppid == me and pid not in exclude}


def _tree(roots: set[int]) -> set[tuple[int, int]]:
    """(pid, start time) of ``roots`` and all their descendants alive now."""
    procs = _processes()
    kids: dict[int, list[int]] = {}
    for pid, (ppid, _) in procs.items():
        kids.setdefault(ppid, []).append(pid)
    found, todo = set(), [r for r in roots if r in procs]
    while todo:
        pid = todo.pop()
        found.add((pid, procs[pid][1]))
        todo += kids.get(pid, [])
    return found


def _kill_tree(roots: set[int], before: set[tuple[int, int]]) -> None:
    """SIGKILL what is still alive of ``before`` and of the trees of ``roots`` now (the same processes:
    pid and start time), so nothing a local Ray started outlives it: an interrupt during ``ray.init``
    leaves processes ``ray.shutdown`` does not know of (measured: its dashboard and runtime-env
    agents, orphaned when their raylet dies, running on indefinitely)."""
    targets = before | _tree(roots)
    sessions = {d for pid, _ in targets for d in _session_dirs(pid)}
    alive = _processes()
    for pid, start in targets:
        if alive.get(pid, (0, None))[1] == start:
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
    # Agents a raylet started in its last moments are orphaned before they show in any tree: they
    # are this Ray instance's when their open files are in its session folder. One that was still
    # starting opens them a moment later, hence a few passes.
    for attempt in range(4) if sessions else ():
        if attempt:
            time.sleep(0.25)
        for pid in _processes():
            if pid != os.getpid() and _session_dirs(pid) & sessions:
                with contextlib.suppress(OSError):
                    os.kill(pid, signal.SIGKILL)


def _session_dirs(pid: int) -> set[str]:
    """Ray session folders (``.../session_<date>_<pid>``) among the files process ``pid`` has open
    and its command line (agents rename their command line, so their log files tell)."""
    found = set()
    paths = []
    with contextlib.suppress(OSError):
        paths.append(open(f"/proc/{pid}/cmdline", "rb").read().decode("utf-8", "replace"))
    with contextlib.suppress(OSError):
        for fd in os.listdir(f"/proc/{pid}/fd"):
            with contextlib.suppress(OSError):
                paths.append(os.readlink(f"/proc/{pid}/fd/{fd}"))
    for text in paths:
        found.update(re.findall(r"/[^\s\x00=]*?/session_\d{4}-\d\d-\d\d_[\d_-]+", text))
    return found


def run_units(units: list[WorkUnit], req: RenderRequest, report) -> str:
    """Run ``units`` with the requested executor; return the device used."""
    return (run_ray if req.executor == "ray" else run_local)(units, req, report)
