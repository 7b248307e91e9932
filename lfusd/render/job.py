"""Render a stage's light-field rig(s) into a dataset folder, with Blender in worker processes.

Dataset layout, format version 2 (the file names are spelled in :mod:`lfusd.layout`, whose
docstring lists them; docs/layout.md has the whole of it):

    OUT/manifest.json                 format, stage files and hashes, rigs, frames, settings, versions
    OUT/logs/                         Blender's output of each worker
    OUT/objects.json                  class table and instance table (id -> prim path, label)
    OUT/<rig>/f000001/frame.json      per-view cam_to_world and per-object world poses
    OUT/<rig>/f000001/00_00/          one folder per view (row 00, col 00):
        rgb.exr, gt.exr, motion.exr (render-video), view.json; passes.exr only with --keep-raw

A view folder appears only when complete: it is assembled under a hidden temporary name and
renamed, so an interrupted run leaves nothing half-written and a rerun renders only what is
missing.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import platform
import shutil
import uuid
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from pxr import Usd, UsdLux

from .. import __version__, cpu_account
from ..author.labels import ObjectEntry, ObjectPoses, object_table
from ..author.rigs import StageRig, select_rigs
from ..author.stage import changed_file, check_frames, files_digest, frame_range, is_static, open_stage, stage_files, world_frame
from ..author.vocabulary import PHYSICAL_SKY, SKY
from ..camera import RigSpec, rig_distortions
from ..data import confined
from ..data.folder import FrameMeta, Manifest, ObjectRow, ObjectTable, atomic_write, existing_dataset, output_lock
from ..errors import LfusdError
from .. import layout
from ..layout import FORMAT, FORMAT_VERSION, frame_dir, view_key
from .plan import Plan, StageSetup, plan_units
from .progress import Progress
from .request import RenderRequest, check_size, raw_codec

log = logging.getLogger(__name__)


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


def _versions() -> dict:
    """The software whose version changes pixels: lfusd and Blender (of :func:`_software`)."""
    software = _software()
    return {"lfusd": software["lfusd"], "bpy": software.get("bpy")}


def _settings(req: RenderRequest, files: dict, rigs: list[StageRig]) -> dict:
    return {
        # Everything that affects pixels: the stage's files (layer stack, textures, ...), the
        # renderer's version and the render settings. A resume must match all of it.
        "stage_id": files_digest(files),
        "versions": _versions(),
        "rigs": {r.spec.name: r.spec.to_dict() for r in rigs},
        "samples": req.samples,
        "motion": req.motion,
        "light": req.light,  # auto adds a sky and sun to a stage without lights: other pixels
        # Format version 2 (lfusd.layout): the keys stored and whether the raw passes stay.
        "format_version": FORMAT_VERSION,
        "keys": list(req.stored_keys()),
        "keep_raw": req.keep_raw,
        # camera effects, recorded only when on (a dataset rendered without them resumes as before)
        **({"sensor": req.sensor.to_dict()} if req.sensor is not None else {}),
        **({"materials": True} if req.materials else {}),
        **({"shutter": req.shutter} if req.shutter else {}),
        **({"defocus": {"fstop": req.fstop, "focus": req.focus}} if req.fstop else {}),
        **({"lens": _lens_record(req, rigs)} if req.distorted else {}),
    }


def _lens_record(req: RenderRequest, rigs: list[StageRig]) -> dict:
    """settings.lens: --lens, --lens-seed, --lens-spread and each view's model (lfusd.camera.rig_distortions,
    which refuses one that folds), which readers take as the view's camera (lfusd.data.dataset.Dataset.camera)."""
    views = {r.spec.name: {view_key(v): d.to_dict() for v, d in rig_distortions(r.spec, req.lens, req.lens_seed, req.lens_spread).items()}
             for r in rigs}
    return {"model": req.lens.to_dict(), "seed": req.lens_seed, "spread": req.lens_spread, "views": views}


def _lenses_of(settings: dict) -> dict[str, dict[str, dict]]:
    """{rig: {view key: {"K", "dist"}}} of a render with --lens (the workers' lfusd.render.plan.WorkUnit.lenses); {} without."""
    doc = settings.get("lens")
    if not doc:
        return {}
    return {name: {key: {"K": _matrix(RigSpec.from_dict(settings["rigs"][name]).intrinsics()), "dist": d} for key, d in views.items()}
            for name, views in doc["views"].items()}


def _io_error(path: Path, e: OSError) -> LfusdError:
    """One line for a failed read or write under ``path``, with the fix its errno calls for."""
    if e.errno in (errno.ENOSPC, errno.EDQUOT):
        fix = "free disk space, then rerun to resume"
    elif e.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        fix = "make it writable or choose another -o folder"
    else:
        fix = "fix the folder, then rerun to resume"
    return LfusdError(f"cannot write to {path} ({e.strerror or e}); {fix}")


def _overwrite_refusal(req: RenderRequest, manifest: Manifest) -> str | None:
    """Why ``--overwrite`` may not remove the dataset in ``req.out``, or None when it may."""
    out = req.out
    if out.is_symlink():
        return f"{out} is a symbolic link; give the folder it points to"
    real = out.resolve()
    if real == Path.cwd().resolve():
        return f"{out} is the current folder"
    if real in Path(req.stage).resolve().parents:
        return f"{out} holds the stage {req.stage}"
    for name in _own_names(manifest):
        if (out / name).is_symlink():
            return f"{out / name} is a symbolic link lfusd did not make"
    return None


def _own_names(manifest: Manifest) -> list[str]:
    """The top-level entries of OUT that lfusd wrote: its files and one folder per rig (a
    validated manifest's rig names)."""
    return [*layout.OWN_ENTRIES, *manifest.rigs]


def _remove_dataset(out: Path, manifest: Manifest) -> None:
    """Remove the files lfusd wrote for the dataset in ``out`` (lfusd.data.confined.remove_own):
    never the folder itself, nor a file a user added anywhere in it; the manifest last, so an
    interrupted removal leaves a dataset that --overwrite removes."""
    try:
        confined.remove_own(out, manifest)
    except OSError as e:
        raise _io_error(out, e) from None


def _prepare_output(req: RenderRequest, settings: dict, files: dict, remove: bool = True) -> Manifest | None:
    """Refuse a folder holding something else or another dataset; return the existing
    manifest, if any (``--overwrite``: remove the other dataset when ``remove``, and return None)."""
    out = req.out
    manifest = existing_dataset(out)
    if manifest is None:
        return None
    old = manifest.settings
    # Rigs not asked for this time may already be in the folder; the ones asked for must match.
    diff = [k for k in settings if k != "rigs" and old.get(k) != settings[k]]
    diff += [f"rig {n}" for n, s in settings["rigs"].items() if old.get("rigs", {}).get(n, s) != s]
    if not diff:
        return manifest
    if "stage_id" in diff:
        changed = changed_file(manifest.stage.get("files") or {}, files)
        diff[diff.index("stage_id")] = f"stage file {changed} (changed since it was rendered)" if changed else "stage files"
    refusal = _overwrite_refusal(req, manifest)
    if not req.overwrite or refusal:
        why = f"; --overwrite is refused here: {refusal}" if refusal else " or pass --overwrite"
        raise LfusdError(f"output folder {out} holds a different dataset (differs in {', '.join(diff)}); "
                         f"choose another -o folder{why}")
    if remove:
        _remove_dataset(out, manifest)
    return None


def _write_manifest(req: RenderRequest, settings: dict, previous: Manifest | None, rigs: list[StageRig], frames: list[int], device: str | None,
                    files: dict, world: dict | None = None) -> Manifest:
    """Write OUT/manifest.json for this run over ``previous`` (the dataset's manifest before it); returns it."""
    from ..data import integrity
    from ..data.folder import RenderSettings

    rig_specs = dict(previous.settings.rigs) if previous else {}
    rig_specs.update(settings["rigs"])
    all_frames = sorted(set(previous.frames) | set(frames)) if previous else sorted(frames)
    manifest = Manifest.new(
        format=FORMAT,
        version=FORMAT_VERSION,
        id=(previous.id if previous else None) or uuid.uuid4().hex,  # proof that lfusd wrote the folder
        stage={"path": str(Path(req.stage).resolve()), "sha256": files.get(Path(req.stage).name, {}).get("sha256"), "files": files},
        # The stage's up axis and units, and the map of its coordinates into lfusd's world.
        world=world or (previous.world if previous else None),
        rigs=tuple(sorted(rig_specs)),
        frames=tuple(all_frames),
        settings=RenderSettings.from_dict({**settings, "rigs": rig_specs}),
        device=device or (previous.device if previous else None),
        # Finished units: frames whose every view matches its completion record, per rig (the
        # records are the ground truth; this is the summary a reader can trust).
        complete={
            # sizes only: Plan has checked the checksums of this run's views, and rehashing a
            # whole dataset at every manifest write would cost minutes at the reference scale
            name: integrity.complete_frames(req.out, name, all_frames, RigSpec.from_dict(spec).views)
            for name, spec in sorted(rig_specs.items())
        },
        software=_software(),
        layout=f"OUT/<rig>/f<frame:06d>/<row:02d>_<col:02d>/{{{','.join(layout.VIEW_FILES)}}}; OUT/<rig>/f<frame:06d>/{layout.FRAME_META}",
    )
    atomic_write(req.out / layout.MANIFEST, manifest.to_json())
    return manifest


def _write_static_metadata(req: RenderRequest, stage: Usd.Stage, rigs: list[StageRig], frames: list[int], objects: list[ObjectEntry],
                           classes: list[str], created: list[Path] | None = None) -> None:
    """objects.json, and each frame's frame.json that is not there yet; ``created`` collects the
    frame folders made here."""
    table = ObjectTable.new(classes=tuple(classes), objects=tuple(
        ObjectRow.new(id=o.instance_id, prim_path=o.prim_path, label=o.label, class_id=o.class_id, meshes=tuple(o.mesh_paths))
        for o in objects))
    atomic_write(req.out / layout.OBJECTS, table.to_json())
    paths = [o.prim_path for o in objects]
    poses = ObjectPoses(stage)
    for rig in rigs:
        for f in frames:
            d = frame_dir(req.out, rig.spec.name, f)
            if (d / layout.FRAME_META).is_file():
                continue
            if created is not None and not d.exists():
                created.append(d)
            d.mkdir(parents=True, exist_ok=True)
            meta = FrameMeta.new(
                frame=f,
                time_code=f,
                cam_to_world={view_key(v): _matrix(rig.cam_to_world(stage, v, f)) for v in rig.spec.views},
                object_poses={p: _matrix(m) for p, m in poses.at(paths, f).items()},
            )
            atomic_write(d / layout.FRAME_META, meta.to_json())


def _clean_stale(out: Path, rigs: list[str]) -> None:
    """Remove what a killed run left (it holds no lock any more: this run holds it), in lfusd's
    own folders only, after refusing any link among them (lfusd.data.confined)."""
    confined.remove_stale(out, rigs)


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


def physical_sky(stage: Usd.Stage) -> bool:
    """Whether a DomeLight of the stage asks for Blender's physical sky (``lfusd:sky = "physical"``)."""
    for prim in stage.Traverse():
        attr = prim.GetAttribute(SKY) if prim.IsA(UsdLux.DomeLight) else None
        if attr and attr.Get() == PHYSICAL_SKY:
            return True
    return False


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
    """Render every missing view of the requested rigs and frames, store their ground truth
    (lfusd.truth.derive); return the manifest dict."""
    from ..truth.derive import derive_dataset

    req = req.capped()
    setup = _plan_job(req, open_stage(req.stage, render=True))
    with _open_folder(setup) as job:
        manifest = job.run(progress)
        derive_dataset(req.out, job.names, workers=req.workers, lock=False)  # the job holds the lock
    return manifest


@dataclass
class _Setup:
    """What the stage and the options fix before the folder is touched (:func:`_plan_job`)."""

    req: RenderRequest
    stage: Usd.Stage
    rigs: list[StageRig]
    frames: list[int]
    files: dict
    settings: dict
    world: dict
    sizes: list[tuple[str, int, int, int]]
    objects: list[ObjectEntry]
    classes: list[str]
    plain: object
    instanced: object


def _plan_job(req: RenderRequest, stage: Usd.Stage) -> _Setup:
    """Everything that can refuse from the stage and the options (sizes, ranges, geometry, the
    folder), before the folder is touched."""
    from ..author.geometry import StageGeometry, check_geometry, render_instances

    req.check()
    if req.executor == "ray" and req.ray_address:
        from .executors import check_ray_address

        check_ray_address(req.ray_address)
    rigs, frames = _rigs_and_frames(req, stage)
    existing = existing_dataset(req.out)
    files = stage_files(req.stage, known=existing.stage.get("files") if existing else None)
    settings = _settings(req, files, rigs)
    # Frames that may still be rendered next to these keep their raw passes (lfusd.truth.derive):
    # an animated stage's range; None for a static stage, which renders over any range.
    settings["stage_frames"] = None if is_static(stage) else list(frame_range(stage))
    world = world_frame(stage).to_dict()
    sizes = [(r.spec.name, len(r.spec.views), r.spec.width, r.spec.height) for r in rigs]
    check_size(req, sizes, frames)
    # The stage's objects and drawn geometry: a Sphere or a broken mesh is refused here, not midway.
    objects, classes = object_table(stage)
    geometry = StageGeometry(stage)
    check_geometry(geometry)
    plain, instanced = render_instances(geometry, objects, frame_range(stage)[0])
    if existing is not None:
        _prepare_output(req, settings, files, remove=False)  # refuse before taking the lock (which writes OUT/.lock)
    return _Setup(req, stage, rigs, frames, files, settings, world, sizes, objects, classes, plain, instanced)


class _Job:
    """A render job in its open folder (:func:`_open_folder`): the manifest written, the plan made.
    ``scheduler``, when set (lfusd.render.overlap.MotionScheduler), is told of every view as it is
    committed, and stopped when the folder closes."""

    def __init__(self, setup: _Setup, undo: "_Undo", written: Manifest, plan: Plan):
        self.setup, self.undo, self.written, self.plan = setup, undo, written, plan
        self.names = [r.spec.name for r in setup.rigs]
        self.scheduler = None

    def run(self, progress=None) -> dict:
        """Render the views the plan has left; write the manifest; return it as a dict. From here on
        what is written is kept: a rerun resumes it."""
        from .executors import run_units

        s, req = self.setup, self.setup.req
        self.undo.done()
        device = None
        if self.plan.remaining:
            stage = s.stage
            units = plan_units(
                req, self.plan, {r.spec.name: r.cameras for r in s.rigs}, {r.spec.name: (r.spec.width, r.spec.height) for r in s.rigs},
                StageSetup(s.plain, s.instanced, any(p.IsA(UsdLux.DomeLight) for p in stage.Traverse()), list(_stage_range(stage, s.frames)),
                           _add_light(req, stage), s.world, physical_sky(stage)),
                raw_codec(req, s.sizes), _lenses_of(s.settings),
            )
            report = progress or Progress(self.plan.total, self.plan.total - self.plan.remaining, req.quiet)
            if self.scheduler is not None:
                from .overlap import CommitReport

                report = CommitReport(report, self.scheduler)
            cpu_account.startup()  # imports, stage checks and planning: once per run
            try:
                device = run_units(units, req, report)
            except BaseException:
                # Record what did finish; a second failure here (a full disk) must not hide the first.
                with contextlib.suppress(OSError):
                    self._write_manifest(None)
                raise
            finally:
                report.close()
        return self._write_manifest(device).to_dict()

    def _write_manifest(self, device: str | None) -> Manifest:
        s = self.setup
        return _write_manifest(s.req, s.settings, self.written, s.rigs, s.frames, device, s.files, s.world)


@contextlib.contextmanager
def _open_folder(setup: _Setup):
    """Take OUT's lock, accept the folder (again: it may have changed before the lock), clean what a
    killed run left, write the manifest and the frames' metadata, and plan: yields the :class:`_Job`.
    A refusal before :meth:`_Job.run` puts the folder back as it was (:class:`_Undo`); an OSError
    becomes one line (:func:`_io_error`); the scratch folder goes on the way out."""
    req = setup.req
    undo = _Undo(req.out)
    try:
        req.out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise _io_error(req.out, e) from None
    with undo, output_lock(req.out):
        previous = _prepare_output(req, setup.settings, setup.files)
        undo.previous(previous)
        job = None
        try:
            names = [r.spec.name for r in setup.rigs]
            _clean_stale(req.out, sorted(set(names) | set(previous.rigs if previous else ())))
            written = _write_manifest(req, setup.settings, previous, setup.rigs, setup.frames, None, setup.files, setup.world)
            _write_static_metadata(req, setup.stage, setup.rigs, setup.frames, setup.objects, setup.classes, undo.frame_dirs)
            from ..keys import KEYS, MOTION

            motion = req.motion and any(KEYS[k].stage == MOTION for k in req.stored_keys())
            plan = Plan(req.out, {r.spec.name: r.spec.views for r in setup.rigs}, setup.frames, motion=motion,
                        dataset_frames=list(written.frames))
            # imported before any child starts: a Ctrl-C then interrupts no import
            from .executors import run_units  # noqa: F401

            job = _Job(setup, undo, written, plan)
            yield job
            cpu_account.flush("parent")
        except OSError as e:
            raise _io_error(req.out, e) from None
        finally:
            if job is not None and job.scheduler is not None:
                job.scheduler.stop()
            shutil.rmtree(req.out / layout.SCRATCH, ignore_errors=True)


class _Undo:
    """Puts OUT back as it was when a run is refused after it started writing, before it rendered
    anything: a folder this run created is removed; in a folder that was empty, the entries this run
    made go; in a dataset, the manifest is restored and the frame folders this run created are removed.
    Only a refusal (LfusdError, or an OSError turned into one) undoes; an interrupt keeps what is
    written, for a rerun to resume. Used as ``with undo, output_lock(out)``: the lock is released first."""

    def __init__(self, out: Path):
        self.out = Path(out)
        self.created = not self.out.exists()
        self.before = set() if self.created else {p.name for p in self.out.iterdir()} if self.out.is_dir() else set()
        self.manifest: str | None = None
        self.frame_dirs: list[Path] = []  # frame folders this run created (lfusd's frame.json alone in them)
        self.active = False  # from the moment this run holds the lock and has accepted the folder

    def previous(self, manifest: dict | None) -> None:
        """The folder is accepted (holding ``manifest``'s dataset, or nothing): undo from here on."""
        if manifest is not None:
            self.manifest = (self.out / layout.MANIFEST).read_text()
        now = {p.name for p in self.out.iterdir()} - {layout.LOCK}
        if self.created and (now or manifest is not None):  # another run filled it meanwhile: not ours to remove
            self.created, self.before = False, now
        self.active = True

    def done(self) -> None:
        self.active = False

    def __enter__(self) -> "_Undo":
        return self

    def __exit__(self, kind, error, tb) -> None:
        if not self.active or kind is None or not issubclass(kind, (LfusdError, OSError)):
            return
        try:
            if self.created:
                shutil.rmtree(self.out)
            elif self.manifest is None:  # an empty folder: the entries this run made
                for p in self.out.iterdir():
                    if p.name in self.before:
                        continue
                    if p.is_dir() and not p.is_symlink():
                        shutil.rmtree(p)
                    else:
                        p.unlink()
            else:
                for d in reversed(self.frame_dirs):
                    (d / layout.FRAME_META).unlink(missing_ok=True)
                    with contextlib.suppress(OSError):
                        d.rmdir()  # only when empty
                        d.parent.rmdir()  # a rig folder this run created, when empty
                atomic_write(self.out / layout.MANIFEST, self.manifest)
        except OSError as e:
            log.warning("could not put %s back as it was (%s); remove what this run wrote by hand", self.out, e.strerror or e)


@dataclass
class VideoResult:
    """What `render_video` did: the manifest, the rigs and frames it rendered, views derived, and
    verify's reports ({rig: lfusd.truth.verify.VerifyReport}) when it certified the result."""

    manifest: dict
    rigs: list[str]
    frames: list[int]
    derived: int
    reports: dict | None = None


def render_video(req: RenderRequest, verify: bool = False, verify_progress=None) -> VideoResult:
    """Render a frame range (default: the stage's) with the motion AOVs and derive the motion keys
    of exactly the rigs and frames rendered (the folder may hold others): each view's frame as soon
    as it and its neighbours are committed, in ``req.workers`` derivation processes beside the
    renderer (lfusd.render.overlap.derivation_lanes of them); what is left (neighbours from earlier
    runs, Ray units) at the end. With ``verify``, certify the result: lfusd.truth.verify on the
    rigs and frames rendered, its figures recorded in the manifest (``verify_progress(frame, view)``
    is called before each view). One pass down: plan, open the folder, run, derive, certify."""
    stage = open_stage(req.stage, render=True)
    if not req.frames:
        first, last = frame_range(stage)
        if last - first + 1 > layout.MAX_FRAMES:  # before a list of them is made
            raise LfusdError(f"stage {req.stage}'s range {first}-{last} is {last - first + 1} frames, more than a dataset holds "
                             f"({layout.MAX_FRAMES}); give --frames A-B, or fix the stage's endTimeCode")
        req = replace(req, frames=list(range(first, last + 1)))
    req = replace(req, motion=True).capped()
    setup = _plan_job(req, stage)
    with _open_folder(setup) as job:
        lanes = _motion_scheduler(job)
        manifest = job.run()
        derived = _derive_video(job, lanes)
    reports = _certify(req.out, job.names, list(req.frames), verify_progress) if verify else None
    return VideoResult(manifest, job.names, list(req.frames), derived, reports)


def _motion_scheduler(job: _Job) -> int:
    """Start the job's lfusd.render.overlap.MotionScheduler (it derives each view's frame as soon as
    it and its neighbours are committed); returns its derivation lanes."""
    from .overlap import MotionScheduler, derivation_lanes

    req, plan = job.setup.req, job.plan
    todo = {(rig, f, tuple(v)) for (rig, f), views in plan.todo.items() for v in views}
    views_of = {r.spec.name: (list(r.spec.views), (r.spec.width, r.spec.height)) for r in job.setup.rigs}
    lanes = derivation_lanes(req.workers, req.device, max((len(v) for v, _ in views_of.values()), default=1))
    job.scheduler = MotionScheduler(req.out, views_of, list(req.frames), list(job.written.frames), todo, lanes=lanes)
    return lanes


def _derive_video(job: _Job, lanes: int) -> int:
    """Finish the job's scheduler, derive what it left (neighbours from earlier runs, Ray units) and
    drop the raw passes no longer needed; the number of views derived."""
    from ..truth.derive import derive_dataset, drop_raw_near

    req = job.setup.req
    written, left = job.scheduler.finish()
    for rig, frames in sorted(left.items()):
        written += derive_dataset(req.out, [rig], frames, workers=lanes, lock=False)  # the job holds the lock
    drop_raw_near(req.out, job.names, req.frames)  # the views derived early kept their raw passes
    return written


def _certify(out: Path, rigs: list[str], frames: list[int], progress=None) -> dict:
    """lfusd.truth.verify on the rigs and frames rendered, its figures recorded in the manifest
    (``certificate``); returns the reports."""
    from ..truth.verify import record_certificate, verify

    reports = verify(out, rig=rigs[0] if len(rigs) == 1 else "all", frames=frames, progress=progress)
    record_certificate(out, reports)  # the dataset carries verify's figures (manifest.json "certificate")
    return reports
