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
import logging
import os
import platform
import shutil
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from pxr import Usd, UsdGeom, UsdLux

from .. import __version__
from ..author.labels import ObjectEntry, ObjectPoses, object_table
from ..author.rigs import StageRig, select_rigs
from ..author.stage import check_frames, file_hash, frame_range, is_static, open_stage, world_frame
from ..camera import RigSpec
from ..errors import LfusdError
from .. import layout
from ..layout import FORMAT, FORMAT_VERSION, frame_dir, view_key
from .plan import Plan, StageSetup, plan_units
from .progress import Progress
from .request import DEVICES, EXECUTORS, LIGHTS, RenderRequest  # noqa: F401  (DEVICES, EXECUTORS, LIGHTS: the commands' choices)

log = logging.getLogger(__name__)


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


def _settings(req: RenderRequest, stage_hash: str, rigs: list[StageRig]) -> dict:
    return {
        "stage_sha256": stage_hash,
        "rigs": {r.spec.name: r.spec.to_dict() for r in rigs},
        "samples": req.samples,
        "motion": req.motion,
        "light": req.light,  # auto adds a sky and sun to a stage without lights: other pixels
        **req.extra_settings,
    }


def _prepare_output(req: RenderRequest, settings: dict) -> dict | None:
    """Refuse a folder holding something else; return the existing manifest, if any."""
    out = req.out
    if out.exists() and not out.is_dir():
        raise LfusdError(f"output {out} is a file; give a folder for the dataset")
    manifest_path = out / layout.MANIFEST
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


def _write_manifest(req: RenderRequest, settings: dict, previous: dict | None, rigs: list[StageRig], frames: list[int], device: str | None,
                    world: dict | None = None) -> None:
    from ..data import integrity

    rig_specs = dict(previous["settings"]["rigs"]) if previous else {}
    rig_specs.update(settings["rigs"])
    all_frames = sorted(set(previous.get("frames", [])) | set(frames)) if previous else sorted(frames)
    manifest = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "stage": {"path": str(Path(req.stage).resolve()), "sha256": settings["stage_sha256"]},
        # The stage's up axis and units, and the map of its coordinates into lfusd's world.
        "world": world or (previous or {}).get("world"),
        "rigs": sorted(rig_specs),
        "frames": all_frames,
        "settings": {**settings, "rigs": rig_specs},
        "device": device or (previous or {}).get("device"),
        # Finished units: frames whose every view matches its completion record, per rig (the
        # records are the ground truth; this is the summary a reader can trust).
        "complete": {
            name: [f for f in all_frames if all(integrity.view_complete(frame_dir(req.out, name, f) / view_key(v)) for v in RigSpec.from_dict(spec).views)]
            for name, spec in sorted(rig_specs.items())
        },
        "software": _software(),
        "layout": f"OUT/<rig>/f<frame:06d>/<row:02d>_<col:02d>/{{{','.join(layout.VIEW_FILES)}}}; OUT/<rig>/f<frame:06d>/{layout.FRAME_META}",
    }
    atomic_write_text(req.out / layout.MANIFEST, json.dumps(manifest, indent=1))


def _write_static_metadata(req: RenderRequest, stage: Usd.Stage, rigs: list[StageRig], frames: list[int], objects: list[ObjectEntry], classes: list[str]) -> None:
    table = {
        "classes": classes,
        "objects": [
            {"id": o.instance_id, "prim_path": o.prim_path, "label": o.label, "class_id": o.class_id, "meshes": list(o.mesh_paths)}
            for o in objects
        ],
    }
    atomic_write_text(req.out / layout.OBJECTS, json.dumps(table, indent=1))
    paths = [o.prim_path for o in objects]
    poses = ObjectPoses(stage)
    for rig in rigs:
        for f in frames:
            d = frame_dir(req.out, rig.spec.name, f)
            if (d / layout.FRAME_META).is_file():
                continue
            d.mkdir(parents=True, exist_ok=True)
            meta = {
                "frame": f,
                "time_code": f,
                "cam_to_world": {view_key(v): _matrix(rig.cam_to_world(stage, v, f)) for v in rig.spec.views},
                "object_poses": {p: _matrix(m) for p, m in poses.at(paths, f).items()},
            }
            atomic_write_text(d / layout.FRAME_META, json.dumps(meta))


def _clean_stale(out: Path) -> None:
    for tmp in out.glob("*/f*/.*.tmp-*"):
        shutil.rmtree(tmp, ignore_errors=True)
    shutil.rmtree(out / ".scratch", ignore_errors=True)


def _rigs_and_frames(req: RenderRequest, stage: Usd.Stage) -> tuple[list[StageRig], list[int]]:
    rigs = select_rigs(stage, req.rig, str(req.stage))
    if req.resolution:
        w, h = req.resolution
        rigs = [replace(r, spec=replace(r.spec, width=w, height=h)) for r in rigs]
    frames = req.frames if req.frames else [frame_range(stage)[0]]
    check_frames(stage, frames, req.stage)
    return rigs, frames


def has_lights(stage: Usd.Stage) -> bool:
    """Whether the stage has a UsdLux light (DomeLight and mesh lights included), inside instances too."""
    return any(p.HasAPI(UsdLux.LightAPI) for p in Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies()))


def _add_light(req: RenderRequest, stage: Usd.Stage) -> bool:
    """Whether the workers add a neutral sky and sun; warns when the stage has no lights."""
    if has_lights(stage):
        return False
    if req.light == "none":
        log.warning("stage %s has no lights and --light none: it renders black (--light auto adds a neutral sky and sun)", req.stage)
        return False
    log.warning("stage %s has no lights; lfusd adds a neutral sky and sun (--light none to keep it dark)", req.stage)
    return True


def _stage_range(stage: Usd.Stage, frames: list[int]) -> tuple[int, int]:
    """The frames over which the workers know the stage (t+/-1 outside it is unknown): an
    animated stage's range; a static stage is known everywhere, so one frame past each end."""
    if is_static(stage):
        return min(frames) - 1, max(frames) + 1
    return frame_range(stage)


def render(req: RenderRequest, progress=None) -> dict:
    """Render every missing view of the requested rigs and frames; return the manifest dict."""
    return _render(req, open_stage(req.stage), progress)[0]


def _render(req: RenderRequest, stage: Usd.Stage, progress=None) -> tuple[dict, list[str]]:
    """(manifest, names of the rigs rendered)."""
    req.check()
    if req.executor == "ray" and req.ray_address:
        from .executors import check_ray_address

        check_ray_address(req.ray_address)
    rigs, frames = _rigs_and_frames(req, stage)
    settings = _settings(req, file_hash(req.stage), rigs)
    world = world_frame(stage).to_dict()
    previous = _prepare_output(req, settings)
    req.out.mkdir(parents=True, exist_ok=True)
    _clean_stale(req.out)
    try:
        _write_manifest(req, settings, previous, rigs, frames, None, world)
        objects, classes = object_table(stage)
        _write_static_metadata(req, stage, rigs, frames, objects, classes)
        plan = Plan(req.out, {r.spec.name: r.spec.views for r in rigs}, frames)
        device = None
        if plan.remaining:
            from ..author.geometry import StageGeometry, render_instances
            from .executors import run_units

            plain, instanced = render_instances(StageGeometry(stage), objects, frame_range(stage)[0])
            units = plan_units(
                req, plan, {r.spec.name: r.cameras for r in rigs}, {r.spec.name: (r.spec.width, r.spec.height) for r in rigs},
                StageSetup(plain, instanced, any(p.IsA(UsdLux.DomeLight) for p in stage.Traverse()), list(_stage_range(stage, frames)),
                           _add_light(req, stage), world),
            )
            report = progress or Progress(plan.total, plan.total - plan.remaining, req.quiet)
            try:
                device = run_units(units, req, report)
            except BaseException:
                # Record what did finish; a second failure here (a full disk) must not hide the first.
                with contextlib.suppress(OSError):
                    _write_manifest(req, settings, json.loads((req.out / layout.MANIFEST).read_text()), rigs, frames, None, world)
                raise
            finally:
                report.close()
        _write_manifest(req, settings, json.loads((req.out / layout.MANIFEST).read_text()), rigs, frames, device, world)
    except OSError as e:
        raise LfusdError(f"cannot write to {req.out} ({e.strerror or e}); free space or fix permissions, then rerun to resume") from None
    finally:
        shutil.rmtree(req.out / ".scratch", ignore_errors=True)
    return json.loads((req.out / layout.MANIFEST).read_text()), [r.spec.name for r in rigs]


@dataclass
class VideoResult:
    """What `render_video` did: the manifest, the rigs and frames it rendered, views derived."""

    manifest: dict
    rigs: list[str]
    frames: list[int]
    derived: int


def render_video(req: RenderRequest) -> VideoResult:
    """Render a frame range (default: the stage's) with the motion AOVs, then derive the motion
    keys of exactly the rigs and frames rendered (the folder may hold others)."""
    from ..truth.derive import derive_dataset

    stage = open_stage(req.stage)
    if not req.frames:
        first, last = frame_range(stage)
        req = replace(req, frames=list(range(first, last + 1)))
    req = replace(req, motion=True)
    manifest, names = _render(req, stage)
    derived = derive_dataset(req.out, names, req.frames, workers=req.workers)
    return VideoResult(manifest, names, list(req.frames), derived)
