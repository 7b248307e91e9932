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

import contextlib
import json
import os
import platform
import shutil
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from pxr import Usd, UsdGeom

from .. import __version__
from ..errors import LfusdError
from ..author.labels import ObjectEntry, object_table
from ..author.stage import check_frames, file_hash, frame_range, open_stage
from ..camera import RigSpec
from ..author.rigs import StageRig, select_rigs
from ..layout import FORMAT, FORMAT_VERSION, frame_dir, view_key

DEVICES = ("auto", "cpu", "cuda", "optix")
EXECUTORS = ("local", "ray")


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
    executor: str = "local"
    ray_address: str | None = None
    frames_per_unit: int = 10
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
        # Finished units: frames whose every view folder is complete, per rig (the folders,
        # written atomically, are the ground truth; this is the summary a reader can trust).
        "complete": {
            name: [f for f in all_frames if all((frame_dir(req.out, name, f) / view_key(v)).is_dir() for v in RigSpec.from_dict(spec).views)]
            for name, spec in sorted(rig_specs.items())
        },
        "software": _software(),
        "layout": "OUT/<rig>/f<frame:06d>/<row:02d>_<col:02d>/{rgb.png,rgb.exr,passes.exr}; OUT/<rig>/f<frame:06d>/frame.json",
    }
    atomic_write_text(req.out / "manifest.json", json.dumps(manifest, indent=1))


def _write_static_metadata(req: RenderRequest, stage: Usd.Stage, rigs: list[StageRig], frames: list[int], objects: list[ObjectEntry], classes: list[str]) -> None:
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


def _clean_stale(out: Path) -> None:
    for tmp in out.glob("*/f*/.*.tmp-*"):
        shutil.rmtree(tmp, ignore_errors=True)
    shutil.rmtree(out / ".scratch", ignore_errors=True)


def render(req: RenderRequest, progress=None) -> dict:
    """Render every missing view of the requested rigs and frames; return the manifest dict."""
    if req.samples is None or req.samples < 1:
        raise LfusdError(f"--samples must be a positive integer, got {req.samples}")
    if req.workers is None or req.workers < 1:
        raise LfusdError(f"--workers must be a positive integer, got {req.workers}")
    if req.executor not in EXECUTORS:
        raise LfusdError(f"unknown executor {req.executor!r}; use one of {', '.join(EXECUTORS)}")
    if req.device not in DEVICES:
        raise LfusdError(f"unknown device {req.device!r}; use one of {', '.join(DEVICES)}")
    if req.executor == "ray" and req.ray_address:
        from .executors import check_ray_address

        check_ray_address(req.ray_address)
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
        objects, classes = object_table(stage)
        _write_static_metadata(req, stage, rigs, frames, objects, classes)
        plan = _Plan(req.out, rigs, frames)
        device = None
        if plan.remaining:
            from .executors import run_units

            report = progress or _Progress(plan.total, plan.total - plan.remaining, req.quiet)
            try:
                device = run_units(req, stage, rigs, plan, objects, report)
            except BaseException:
                # Record what did finish; a second failure here (a full disk) must not hide the first.
                with contextlib.suppress(OSError):
                    _write_manifest(req, settings, json.loads((req.out / "manifest.json").read_text()), rigs, frames, None)
                raise
            finally:
                report.close()
        _write_manifest(req, settings, json.loads((req.out / "manifest.json").read_text()), rigs, frames, device)
    except OSError as e:
        raise LfusdError(f"cannot write to {req.out} ({e.strerror or e}); free space or fix permissions, then rerun to resume") from None
    finally:
        shutil.rmtree(req.out / ".scratch", ignore_errors=True)
    return json.loads((req.out / "manifest.json").read_text())


class _Progress:
    """Views done, views per second and time left, as a rich progress bar or plain log lines."""

    LOG_EVERY_S = 5.0  # log lines (--quiet, or no terminal): at most one per interval, and the last

    def __init__(self, total: int, done: int, quiet: bool):
        self.quiet = quiet or not sys.stderr.isatty()
        self.total, self.done, self.start, self.started_with = total, done, time.monotonic(), done
        self.bar = None
        self.last_log = -float("inf")
        self.lock = threading.Lock()  # workers report from several threads
        if not self.quiet:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

            self.bar = Progress(
                TextColumn("rendering"), BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[rate]}"), TimeRemainingColumn()
            )
            self.task = self.bar.add_task("views", total=total, completed=done, rate="")
            self.bar.start()

    def advance(self, n: int) -> None:
        with self.lock:
            self._advance(n)

    def _advance(self, n: int) -> None:
        self.done += n
        rate = (self.done - self.started_with) / max(time.monotonic() - self.start, 1e-9)
        if self.bar:
            self.bar.update(self.task, advance=n, rate=f"{rate:.2f} views/s")
        elif self.done == self.total or time.monotonic() - self.last_log >= self.LOG_EVERY_S:
            self.last_log = time.monotonic()
            left = (self.total - self.done) / rate if rate > 0 else float("inf")
            print(f"lfusd: {self.done}/{self.total} views, {rate:.2f} views/s, {left:.0f} s left", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.bar:
            self.bar.stop()
