"""Render a stage's light-field rig(s) into a dataset folder, with Blender in worker processes.

Dataset layout (see README.md):

    OUT/manifest.json                 stage path and hash, rigs, frames, settings, versions
    OUT/logs/                         Blender's output of each worker
    OUT/objects.json                  class table and instance table (id -> prim path, label)
    OUT/<rig>/f000001/frame.json      per-view cam_to_world and per-object world poses
    OUT/<rig>/f000001/00_00/          one folder per view (row 00, col 00):
        rgb.png, rgb.exr, passes.exr

A view folder appears only when complete: it is assembled under a hidden temporary name and
renamed, so an interrupted run leaves nothing half-written and a rerun renders only what is
missing.
"""

from __future__ import annotations

import json
import os
import platform
import queue
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from PIL import Image
from pxr import Usd, UsdGeom

from .. import __version__
from ..errors import LfusdError
from ..labels import object_table
from ..passes import linear_to_srgb8, read_rgb_linear
from ..stageio import check_frames, file_hash, frame_range, open_stage
from ..usdrig import StageRig, select_rigs

FORMAT = "lfusd-dataset"
FORMAT_VERSION = 1
DEVICES = ("auto", "cpu", "cuda", "optix")


def view_key(view: tuple[int, int]) -> str:
    return f"{view[0]:02d}_{view[1]:02d}"


def frame_dir(root: Path, rig: str, frame: int) -> Path:
    return root / rig / f"f{frame:06d}"


@dataclass
class RenderRequest:
    """What `lfusd render` / `render-video` asks for."""

    stage: Path
    out: Path
    rig: str | None = None
    frames: list[int] | None = None
    samples: int = 16
    device: str = "auto"
    workers: int = 1
    resolution: tuple[int, int] | None = None
    overwrite: bool = False
    quiet: bool = False
    motion: bool = False  # also render the t+/-1 position AOVs (render-video)
    extra_settings: dict = field(default_factory=dict)


def atomic_write_text(path: Path, text: str) -> None:
    """Write a file under a temporary name in the same folder, then rename it into place."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _software() -> dict:
    import importlib.metadata as md

    versions = {"lfusd": __version__, "python": platform.python_version()}
    for pkg in ("bpy", "usd-core", "OpenEXR", "numpy", "open3d"):
        try:
            versions[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            pass
    return versions


def _matrix(m) -> list[list[float]]:
    return np.asarray(m, dtype=np.float64).tolist()


def object_poses(stage: Usd.Stage, prim_paths: list[str], frame: int) -> dict[str, list]:
    """World pose (4x4, column vectors, metres) of each object prim at ``frame``."""
    cache = UsdGeom.XformCache(Usd.TimeCode(frame))
    mpu = UsdGeom.GetStageMetersPerUnit(stage)
    out = {}
    for path in prim_paths:
        m = np.array(cache.GetLocalToWorldTransform(stage.GetPrimAtPath(path)), dtype=np.float64).T
        m[:3, 3] *= mpu
        out[path] = _matrix(m)
    return out


class _Plan:
    """The views still to render, per rig and frame."""

    def __init__(self, out: Path, rigs: list[StageRig], frames: list[int]):
        self.todo: dict[tuple[str, int], list[tuple[int, int]]] = {}
        self.total = 0
        for rig in rigs:
            for f in frames:
                self.total += len(rig.spec.views)
                missing = [v for v in rig.spec.views if not (frame_dir(out, rig.spec.name, f) / view_key(v)).is_dir()]
                if missing:
                    self.todo[(rig.spec.name, f)] = missing

    @property
    def remaining(self) -> int:
        return sum(len(v) for v in self.todo.values())


def _settings(req: RenderRequest, stage_hash: str, rigs: list[StageRig]) -> dict:
    return {
        "stage_sha256": stage_hash,
        "rigs": {r.spec.name: r.spec.to_dict() for r in rigs},
        "samples": req.samples,
        "motion": req.motion,
        **req.extra_settings,
    }


def _prepare_output(req: RenderRequest, settings: dict) -> dict | None:
    """Refuse a folder holding something else; return the existing manifest, if any."""
    out = req.out
    if out.exists() and not out.is_dir():
        raise LfusdError(f"output {out} is a file; give a folder for the dataset")
    manifest_path = out / "manifest.json"
    if out.is_dir() and any(out.iterdir()):
        if not manifest_path.is_file():
            raise LfusdError(f"output folder {out} is not empty and holds no lfusd dataset; choose an empty or new folder")
        try:
            manifest = json.loads(manifest_path.read_text())
        except (OSError, json.JSONDecodeError):
            raise LfusdError(f"{manifest_path} is unreadable; move the folder aside or use --overwrite") from None
        old = manifest.get("settings", {})
        # Rigs not asked for this time may already be in the folder; the ones asked for must match.
        same = old.get("stage_sha256") == settings["stage_sha256"] and all(
            old.get(k) == v for k, v in settings.items() if k not in ("stage_sha256", "rigs")
        ) and all(old.get("rigs", {}).get(n, s) == s for n, s in settings["rigs"].items())
        if not same:
            if not req.overwrite:
                diff = [k for k in settings if k != "rigs" and old.get(k) != settings[k]]
                diff += [f"rig {n}" for n, s in settings["rigs"].items() if old.get("rigs", {}).get(n, s) != s]
                raise LfusdError(
                    f"output folder {out} holds a different dataset (differs in {', '.join(diff) or 'settings'}); "
                    "choose another -o folder or pass --overwrite"
                )
            shutil.rmtree(out)
            return None
        return manifest
    return None


def _write_manifest(req: RenderRequest, settings: dict, previous: dict | None, rigs: list[StageRig], frames: list[int], device: str | None) -> None:
    rig_specs = dict(previous["settings"]["rigs"]) if previous else {}
    rig_specs.update(settings["rigs"])
    all_frames = sorted(set(previous.get("frames", [])) | set(frames)) if previous else sorted(frames)
    manifest = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "stage": {"path": str(Path(req.stage).resolve()), "sha256": settings["stage_sha256"]},
        "rigs": sorted(rig_specs),
        "frames": all_frames,
        "settings": {**settings, "rigs": rig_specs},
        "device": device or (previous or {}).get("device"),
        "software": _software(),
        "layout": "OUT/<rig>/f<frame:06d>/<row:02d>_<col:02d>/{rgb.png,rgb.exr,passes.exr}; OUT/<rig>/f<frame:06d>/frame.json",
    }
    atomic_write_text(req.out / "manifest.json", json.dumps(manifest, indent=1))


def _write_static_metadata(req: RenderRequest, stage: Usd.Stage, rigs: list[StageRig], frames: list[int]) -> None:
    objects, classes = object_table(stage)
    table = {
        "classes": classes,
        "objects": [
            {"id": o.instance_id, "prim_path": o.prim_path, "label": o.label, "class_id": o.class_id, "meshes": list(o.mesh_paths)}
            for o in objects
        ],
    }
    atomic_write_text(req.out / "objects.json", json.dumps(table, indent=1))
    paths = [o.prim_path for o in objects]
    for rig in rigs:
        for f in frames:
            d = frame_dir(req.out, rig.spec.name, f)
            if (d / "frame.json").is_file():
                continue
            d.mkdir(parents=True, exist_ok=True)
            meta = {
                "frame": f,
                "time_code": f,
                "cam_to_world": {view_key(v): _matrix(rig.cam_to_world(stage, v, f)) for v in rig.spec.views},
                "object_poses": object_poses(stage, paths, f),
            }
            atomic_write_text(d / "frame.json", json.dumps(meta))


def _commit_view(out: Path, rig: str, frame: int, key: str, scratch: Path) -> None:
    """Move one view's raw files from the worker's scratch into its final folder, atomically."""
    final = frame_dir(out, rig, frame) / key
    if final.is_dir():
        return
    tmp = final.parent / f".{key}.tmp-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    for name in ("rgb", "passes"):
        src = scratch / f"{name}_{key}.exr"
        if not src.is_file():
            raise LfusdError(f"Blender wrote no {src.name} for view {key} of frame {frame}; rerun to resume")
        shutil.move(str(src), tmp / f"{name}.exr")
    Image.fromarray(linear_to_srgb8(read_rgb_linear(tmp / "rgb.exr"))).save(tmp / "rgb.png", optimize=False, compress_level=3)
    os.rename(tmp, final)


def _clean_stale(out: Path) -> None:
    for tmp in out.glob("*/f*/.*.tmp-*"):
        shutil.rmtree(tmp, ignore_errors=True)
    shutil.rmtree(out / ".scratch", ignore_errors=True)


def _chunks(items: list, n: int) -> list[list]:
    n = max(1, min(n, len(items)))
    return [items[i::n] for i in range(n)]


class _Worker:
    """One Blender worker process; a thread forwards its protocol lines to a shared queue."""

    def __init__(self, job: dict, log: Path, events: "queue.Queue"):
        self.job = job
        self.log = open(log, "w")
        self.proc = subprocess.Popen(
            [sys.executable, "-X", "faulthandler", "-m", "lfusd.render.worker"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self.log,
            text=True,
            bufsize=1,
        )
        self.proc.stdin.write(json.dumps(job))
        self.proc.stdin.close()
        threading.Thread(target=self._pump, args=(events,), daemon=True).start()

    def _pump(self, events: "queue.Queue") -> None:
        for line in self.proc.stdout:
            if line.startswith("LFUSD "):
                events.put((self, json.loads(line[6:])))
        events.put((self, {"event": "exit", "code": self.proc.wait()}))


def render(req: RenderRequest, progress=None) -> dict:
    """Render every missing view of the requested rigs and frames; return the manifest dict."""
    if req.samples is None or req.samples < 1:
        raise LfusdError(f"--samples must be a positive integer, got {req.samples}")
    if req.workers is None or req.workers < 1:
        raise LfusdError(f"--workers must be a positive integer, got {req.workers}")
    if req.device not in DEVICES:
        raise LfusdError(f"unknown device {req.device!r}; use one of {', '.join(DEVICES)}")
    stage = open_stage(req.stage)
    rigs = select_rigs(stage, req.rig, str(req.stage))
    if req.resolution:
        w, h = req.resolution
        rigs = [replace(r, spec=replace(r.spec, width=w, height=h)) for r in rigs]
    frames = req.frames if req.frames else [frame_range(stage)[0]]
    check_frames(stage, frames, req.stage)
    settings = _settings(req, file_hash(req.stage), rigs)
    previous = _prepare_output(req, settings)
    req.out.mkdir(parents=True, exist_ok=True)
    _clean_stale(req.out)
    try:
        _write_manifest(req, settings, previous, rigs, frames, None)
        _write_static_metadata(req, stage, rigs, frames)
        plan = _Plan(req.out, rigs, frames)
        device = _run_workers(req, stage, rigs, plan, progress) if plan.remaining else None
        _write_manifest(req, settings, json.loads((req.out / "manifest.json").read_text()), rigs, frames, device)
    except OSError as e:
        raise LfusdError(f"cannot write to {req.out} ({e.strerror or e}); free space or fix permissions, then rerun to resume") from None
    finally:
        shutil.rmtree(req.out / ".scratch", ignore_errors=True)
    return json.loads((req.out / "manifest.json").read_text())


def _run_workers(req: RenderRequest, stage: Usd.Stage, rigs: list[StageRig], plan: _Plan, progress) -> str:
    objects, _ = object_table(stage)
    instances = {mesh: o.instance_id for o in objects for mesh in o.mesh_paths}
    by_name = {r.spec.name: r for r in rigs}
    scratch_root = req.out / ".scratch"
    jobs = []
    # One job per (rig, set of views), covering all its frames: a worker imports the stage once.
    for rig_name in sorted({k[0] for k in plan.todo}):
        rig = by_name[rig_name]
        frames = sorted(f for (r, f) in plan.todo if r == rig_name)
        views = sorted({v for (r, f), vs in plan.todo.items() if r == rig_name for v in vs})
        for i, chunk in enumerate(_chunks(views, req.workers)):
            jobs.append(
                {
                    "rig": rig_name,
                    "stage": str(Path(req.stage).resolve()),
                    "cameras": {view_key(v): rig.cameras[v] for v in chunk},
                    "frames": frames,
                    "width": rig.spec.width,
                    "height": rig.spec.height,
                    "samples": req.samples,
                    "device": req.device,
                    "instances": instances,
                    "threads": max(1, (os.cpu_count() or 1) // min(req.workers, len(views))),
                    "scratch": str(scratch_root / f"{rig_name}-{i}"),
                    "motion": req.motion,
                    "stage_range": list(frame_range(stage)),
                }
            )
    report = progress or _Progress(plan.total, plan.total - plan.remaining, req.quiet)
    device = "cpu"
    pending = list(jobs)
    running: list[_Worker] = []
    events: queue.Queue = queue.Queue()
    logs = req.out / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    try:
        while pending or running:
            while pending and len(running) < req.workers:
                job = pending.pop(0)
                running.append(_Worker(job, logs / f"worker-{job['rig']}-{len(jobs) - len(pending)}.log", events))
            w, event = events.get()
            if event["event"] == "ready":
                device = event["device"]
            elif event["event"] == "frame":
                for key in event["views"]:
                    _commit_view(req.out, w.job["rig"], event["frame"], key, Path(event["scratch"]))
                    report.advance(1)
                shutil.rmtree(event["scratch"], ignore_errors=True)
            elif event["event"] == "error":
                raise LfusdError(_failure(w, event["message"]))
            elif event["event"] == "exit":
                running.remove(w)
                w.log.close()
                if event["code"] != 0:
                    raise LfusdError(_failure(w, f"exited with code {event['code']} (log: {w.log.name})"))
    finally:
        for w in running:
            if w.proc.poll() is None:
                w.proc.kill()
                w.proc.wait()
        report.close()
    return device


def _failure(worker: _Worker, what: str) -> str:
    frames = worker.job["frames"]
    return (
        f"Blender worker for rig {worker.job['rig']} (frames {frames[0]}-{frames[-1]}) failed: {what.splitlines()[0]}; "
        "finished views are kept, rerun the same command to resume"
    )


class _Progress:
    """Views done, views per second and time left, as a rich progress bar or plain log lines."""

    def __init__(self, total: int, done: int, quiet: bool):
        self.quiet = quiet or not sys.stderr.isatty()
        self.total, self.done, self.start, self.started_with = total, done, time.monotonic(), done
        self.bar = None
        if not self.quiet:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

            self.bar = Progress(
                TextColumn("rendering"), BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[rate]}"), TimeRemainingColumn()
            )
            self.task = self.bar.add_task("views", total=total, completed=done, rate="")
            self.bar.start()

    def advance(self, n: int) -> None:
        self.done += n
        rate = (self.done - self.started_with) / max(time.monotonic() - self.start, 1e-9)
        if self.bar:
            self.bar.update(self.task, advance=n, rate=f"{rate:.2f} views/s")
        else:
            left = (self.total - self.done) / rate if rate > 0 else float("inf")
            print(f"lfusd: {self.done}/{self.total} views, {rate:.2f} views/s, {left:.0f} s left", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.bar:
            self.bar.stop()
