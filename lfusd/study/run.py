"""Run a rig study: the folder, the layers, the renders, the scores (resumable) and ``--apply``.

    STUDY/study.json          the settings (a rerun must match them; --task and --min-psnr only rank)
    STUDY/render.usda         a layer over the stage: the stage's own rigs deactivated, one union rig
                              (the distinct cameras of every candidate) per position
    STUDY/candidates.usda     a layer over the stage holding every candidate as an lfusd rig
                              ('lfusd render STUDY/candidates.usda --rig NAME' renders one in full)
    STUDY/renders/            the lfusd dataset of the union rigs (resumable like any render)
    STUDY/scores/NAME.json    a candidate's scores per frame; a rerun scores only what is missing
    STUDY/report.md, STUDY/score_vs_baseline.png, STUDY/heatmaps/*.png

The user's stage is never written, except by ``--apply NAME`` (into the stage itself, or into
a new layer over it with ``--apply-layer NEW.usda``), with lfusd's rig authoring.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .. import layout
from ..camera import AXES, LAYOUTS, SPACINGS, RigSpec
from ..errors import LfusdError
from .candidates import Candidate, arrangements, author_union, build, union_rig_name
from .score import Bands, Views, estimate_inverse_depth, scene_flow_error, score

log = logging.getLogger(__name__)

TASKS = ("disparity", "views", "sceneflow")
STUDY_FORMAT = "lfusd-rig-study"


@dataclass
class StudyRequest:
    """What `lfusd rig-study` asks for."""

    stage: Path
    out: Path
    grid: tuple[int, int] = (9, 9)
    baselines: tuple[float, ...] = (0.02, 0.05, 0.125, 0.3)
    spacings: tuple[str, ...] = SPACINGS
    layouts: tuple[str, ...] = LAYOUTS
    axes: tuple[str, ...] = AXES
    frames: list[int] | None = None
    task: str = "disparity"
    rig: str | None = None  # a rig of the stage, or 'all': the position(s) studied
    resolution: tuple[int, int] = (64, 64)
    samples: int = 4
    bands: tuple[float, ...] = (1.0, 3.0, 10.0, 30.0)
    min_psnr: float = 30.0  # --task views: a view reconstructed below this is not recovered
    n_planes: int | None = None  # planes per sweep (default: ~1 px of parallax per plane, 16-96)
    device: str = "auto"
    workers: int = 1
    executor: str = "local"
    ray_address: str | None = None
    quiet: bool = False
    force: bool = False
    apply: str | None = None
    apply_layer: Path | None = None
    extra: dict = field(default_factory=dict)

    def check(self) -> None:
        """Raise LfusdError naming the first impossible setting, before any work."""
        if self.task not in TASKS:
            raise LfusdError(f"unknown --task {self.task!r}; use one of {', '.join(TASKS)}")
        for what, values, allowed in (("--spacing", self.spacings, SPACINGS), ("--layout", self.layouts, LAYOUTS), ("--axes", self.axes, AXES)):
            if not values:
                raise LfusdError(f"{what} is empty; give one or more of {', '.join(allowed)}")
            bad = [v for v in values if v not in allowed]
            if bad:
                raise LfusdError(f"unknown {what} value {bad[0]!r}; use one or more of {', '.join(allowed)}, comma-separated")
        if not self.baselines or any(not (np.isfinite(b) and b > 0) for b in self.baselines):
            raise LfusdError(f"--baselines must be positive numbers of metres, got {list(self.baselines)}")
        if self.grid[0] * self.grid[1] < 2:
            raise LfusdError("--grid must have at least two views (e.g. 3x3)")
        if min(self.resolution) < 11:
            raise LfusdError(f"--resolution {self.resolution[0]}x{self.resolution[1]} is below SSIM's 11x11 window; use at least 16x16")
        if list(self.bands) != sorted(set(self.bands)) or any(b <= 0 for b in self.bands):
            raise LfusdError(f"--bands must be increasing positive depths in metres, got {list(self.bands)}")
        if self.n_planes is not None and self.n_planes < 3:
            raise LfusdError(f"--planes must be at least 3, got {self.n_planes}")

    def settings(self) -> dict:
        """What the renders and scores depend on (ranking options --task, --min-psnr excluded, except that scene flow renders motion)."""
        return {"grid": list(self.grid), "baselines": [float(b) for b in self.baselines], "spacings": list(self.spacings),
                "layouts": list(self.layouts), "axes": list(self.axes), "rig": self.rig, "resolution": list(self.resolution),
                "samples": self.samples, "bands": list(self.bands), "n_planes": self.n_planes, "motion": self.task == "sceneflow",
                "frames": self.frames}


@dataclass
class StudyResult:
    ranked: list[dict]  # arrangement rows, best first (lfusd.study.report.rank)
    out: Path
    candidates: int
    skipped: list[tuple[str, str]]
    cameras: int  # distinct cameras rendered (all positions)
    views: int  # views of all candidates (what rendering each candidate would cost)
    applied: list[str]
    seconds: float


def _digest(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True).encode()).hexdigest()[:16]


# What lfusd writes in a study folder (none of them, nor anything in the folders, may be a link:
# lfusd would write through it); renders/ is a dataset, checked by the render like any other.
STUDY_FILES = (layout.STUDY_RECORD, layout.STUDY_RENDER_LAYER, layout.STUDY_CANDIDATES_LAYER, layout.STUDY_REPORT,
               layout.STUDY_PLOT, f".{layout.STUDY_RENDER_LAYER}.tmp.usda", f".{layout.STUDY_CANDIDATES_LAYER}.tmp.usda",
               layout.STUDY_RENDERS, layout.LOCK)
STUDY_FOLDERS = (layout.STUDY_SCORES, layout.STUDY_HEATMAPS)


def check_links(out: Path) -> None:
    """Refuse, in one line, a study folder in which lfusd would write through a link (lfusd.data.confined)."""
    from ..data.confined import check_entries

    check_entries(out, STUDY_FILES, STUDY_FOLDERS)


def _prepare_folder(out: Path, record: dict) -> None:
    """Refuse a folder that is not this study's: a file, other files, another study's record
    (lfusd.data.folder.resumable_folder), a link where lfusd writes (:func:`check_links`); then
    write the record of a new study."""
    from ..data.folder import atomic_write, resumable_folder

    def same_study(path: Path) -> dict:
        try:
            old = json.loads(path.read_text())
        except (OSError, ValueError) as e:
            raise LfusdError(f"{path} is unreadable ({e}); move the folder aside or choose another -o folder") from None
        if not isinstance(old, dict) or old.get("format") != STUDY_FORMAT:
            raise LfusdError(f"{path} is not a rig study's record; choose another -o folder")
        diff = [k for k in record["settings"] if (old.get("settings") or {}).get(k) != record["settings"][k]]
        if old.get("stage_id") != record["stage_id"]:
            diff.insert(0, "the stage's files")
        if diff:
            raise LfusdError(f"study folder {out} holds a study with other settings (differs in {', '.join(diff)}); "
                             "choose another -o folder, or rerun with its settings to resume it")
        return old

    resumable_folder(out, layout.STUDY_RECORD, "study", "rig study", same_study)
    check_links(out)
    out.mkdir(parents=True, exist_ok=True)
    if not (out / layout.STUDY_RECORD).is_file():
        atomic_write(out / layout.STUDY_RECORD, json.dumps(record, indent=1))


def _check_apply(req: StudyRequest, stage_rigs: dict, positions: list[str]) -> list[str]:
    """The names --apply will write (checked before the study runs, not after an hour of it)."""
    from ..author.stage import open_for_edit

    if req.apply_layer is not None and not req.apply:
        raise LfusdError("--apply-layer needs --apply NAME (the name of the rig to write)")
    if not req.apply:
        return []
    names = [req.apply] if len(positions) == 1 else [f"{req.apply}_{p}" for p in positions]
    for n in names:
        RigSpec(name=n)  # a valid prim name, or one line naming it
        if n in stage_rigs and req.apply_layer is None:
            raise LfusdError(f"the stage already has a rig named {n!r}; choose another --apply NAME")
    if req.apply_layer is not None:
        p = Path(req.apply_layer)
        if p.exists():
            raise LfusdError(f"--apply-layer {p} already exists; give a new file (the stage itself is written by --apply alone)")
        if p.suffix.lower() not in (".usda", ".usdc", ".usd"):
            raise LfusdError(f"--apply-layer {p} is not a .usda/.usdc/.usd file; give a new layer such as scene.usda")
    else:
        open_for_edit(req.stage)  # refuses a package or a read-only file now
    return names


def _write_layers(req: StudyRequest, stage, bases: dict, candidates: list[Candidate], unions: dict, frames: list[int]) -> Path:
    from ..author.rigs import add_rig, rigs
    from ..author.stage import layer_over

    render_layer = req.out / layout.STUDY_RENDER_LAYER
    if not render_layer.is_file():
        tmp = req.out / f".{layout.STUDY_RENDER_LAYER}.tmp.usda"
        tmp.unlink(missing_ok=True)
        st = layer_over(req.stage, tmp)
        for r in rigs(st).values():  # the stage's own rigs are not rendered (their cameras not even imported)
            st.GetPrimAtPath(r.prim_path).SetActive(False)
        for name, base in bases.items():
            first = next(c for c in candidates if c.position == name)
            author_union(st, base.prim_path, first.spec, unions[name], frames)
        st.GetRootLayer().Export(str(render_layer))  # written whole under its final name only when complete
        tmp.unlink(missing_ok=True)
    cand_layer = req.out / layout.STUDY_CANDIDATES_LAYER
    if not cand_layer.is_file():
        tmp = req.out / f".{layout.STUDY_CANDIDATES_LAYER}.tmp.usda"
        tmp.unlink(missing_ok=True)
        st = layer_over(req.stage, tmp)
        for c in candidates:
            add_rig(st, replace(c.spec, name=c.name))
        st.GetRootLayer().Export(str(cand_layer))
        tmp.unlink(missing_ok=True)
    return render_layer


def _render(req: StudyRequest, render_layer: Path, frames: list[int]) -> None:
    from ..render.job import render, render_video
    from ..render.request import RenderRequest

    rr = RenderRequest(stage=render_layer, out=req.out / layout.STUDY_RENDERS, rig="all", frames=frames, samples=req.samples,
                       device=req.device, workers=req.workers, executor=req.executor, ray_address=req.ray_address,
                       quiet=req.quiet, force=req.force)
    if req.task == "sceneflow":
        render_video(rr)
    else:
        render(rr)


def load_views(root: Path, rig: str, frame: int, index: dict[str, int]) -> Views:
    """Every camera of a union rig at one frame, from the study's renders."""
    from ..data.dataset import open_dataset
    from ..data.folder import require_pinhole

    ds = open_dataset(root, rig)
    require_pinhole(ds, "the rig study (its sweeps and scores project with K)", "remove it and run the study again")
    n = len(index)
    rgb = np.stack([ds.read(frame, (0, k), "rgb") for k in range(n)])
    depth = np.stack([ds.read(frame, (0, k), "depth") for k in range(n)])
    poses = np.stack([ds.cam_to_world(frame, (0, k)) for k in range(n)])
    return Views(rgb, depth, ds.intrinsics((0, 0)), poses, index)


def _jsonable(d: dict) -> dict:
    return {k: v for k, v in d.items() if not isinstance(v, np.ndarray)}


def run_study(req: StudyRequest, say=None) -> StudyResult:
    """Build, render and score every candidate, then rank and report (see the module docstring)."""
    from ..author.rigs import rigs, select_rigs
    from ..author.stage import check_frames, files_digest, frame_range, is_static, open_stage, stage_files

    say = say or (lambda msg: print(msg, file=sys.stderr, flush=True))
    start = time.monotonic()
    req.check()
    stage = open_stage(req.stage)
    bases = {r.spec.name: r for r in select_rigs(stage, req.rig, str(req.stage))}
    frames = list(req.frames) if req.frames else [frame_range(stage)[0]]
    render_frames = frames
    if req.task == "sceneflow":
        if is_static(stage):
            raise LfusdError(f"stage {req.stage} is static: nothing moves, so scene flow is zero; use --task disparity or views, or a dynamic stage")
        render_frames = list(range(min(frames), max(frames) + 2))  # t+1 of every scored frame
    check_frames(stage, render_frames, req.stage)
    applied_names = _check_apply(req, rigs(stage), list(bases))
    arrs = arrangements(req.baselines, req.spacings, req.layouts, req.axes)
    candidates, skipped, unions = build({n: r.spec for n, r in bases.items()}, arrs, req.grid, req.resolution)
    record = {"format": STUDY_FORMAT, "version": 1, "stage": str(req.stage), "stage_id": files_digest(stage_files(req.stage)),
              "settings": req.settings()}
    _prepare_folder(req.out, record)
    from ..data.folder import output_lock

    with output_lock(req.out):  # one writer of the study's files (its renders take their own lock)
        return _run(req, say, start, stage, bases, frames, render_frames, applied_names, candidates, skipped, unions, record)


def _run(req: StudyRequest, say, start, stage, bases, frames, render_frames, applied_names, candidates, skipped, unions, record) -> StudyResult:
    """Render, score, rank, report and apply, in a prepared and locked study folder."""
    from . import report

    cameras = sum(len(u.ids) for u in unions.values())
    views_total = sum(len(c.cameras) for c in candidates)
    say(f"lfusd: {len(candidates)} candidates at {len(bases)} position(s): {views_total} views, {cameras} distinct cameras to render")
    render_layer = _write_layers(req, stage, bases, candidates, unions, render_frames)
    _render(req, render_layer, render_frames)

    bands = Bands(tuple(req.bands))
    scores_dir = req.out / layout.STUDY_SCORES
    scores_dir.mkdir(exist_ok=True)
    settings_id = _digest(record)
    results: dict[str, dict] = {}
    todo = []
    for c in candidates:
        path = scores_dir / f"{c.name}.json"
        try:
            old = json.loads(path.read_text()) if path.is_file() else {}
        except (OSError, ValueError):
            old = {}
        have = old.get("frames", {}) if old.get("settings_id") == settings_id else {}
        results[c.name] = have
        todo += [(c, t) for t in frames if str(t) not in have]
    todo.sort(key=lambda ct: (ct[0].position, ct[1]))  # one position and frame at a time: their views are loaded once
    if todo:
        say(f"lfusd: scoring {len({c.name for c, _ in todo})} candidates ({len(candidates) - len({c.name for c, _ in todo})} already scored)")
    device = "cuda" if _cuda() else "cpu"
    with _one_thread():
        _score_all(req, todo, results, unions, bands, scores_dir, settings_id, device, say)
    ranked = report.rank(candidates, results, frames, req.task, req.min_psnr, bands)
    check_links(req.out)  # again: the report and figures are written now, an hour after the first check
    report.write(req, ranked, candidates, skipped, bands, cameras, views_total)
    applied = _apply(req, bases, candidates, ranked[0], applied_names) if req.apply else []
    return StudyResult(ranked, req.out, len(candidates), skipped, cameras, views_total, applied, time.monotonic() - start)


@contextlib.contextmanager
def _one_thread():
    """Score with one torch thread: on 64x64 images the threads' synchronisation costs more than
    they compute (a sweep's warp took 23x longer with 2 threads than with 1 on a loaded 2-core machine)."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def _score_all(req, todo, results, unions, bands, scores_dir, settings_id, device, say) -> None:
    from ..data.folder import atomic_write

    cache: dict[tuple[str, int], Views] = {}
    t0 = time.monotonic()
    for n, (c, t) in enumerate(todo):
        def views_at(f):
            key = (c.position, f)
            if key not in cache:
                for k in [k for k in cache if k[0] != c.position or abs(k[1] - f) > 1]:
                    del cache[k]
                cache[key] = load_views(req.out / layout.STUDY_RENDERS, union_rig_name(c.position), f, unions[c.position].index())
            return cache[key]

        v = views_at(t)
        s = score(c.spec, c.cameras, v, bands, True, req.n_planes, device=device)
        if req.task == "sceneflow":
            s |= _scene_flow(req, c, v, views_at(t + 1), s["q_centre"], t, device)
        results[c.name][str(t)] = _jsonable(s)
        # a candidate is done only when its file is whole (a new temporary, never one found there)
        atomic_write(scores_dir / f"{c.name}.json", json.dumps({"settings_id": settings_id, "candidate": c.name, "frames": results[c.name]}))
        el = time.monotonic() - t0
        if not req.quiet or n + 1 == len(todo):
            say(f"lfusd: scored {n + 1}/{len(todo)} ({c.name}, frame {t}): disparity error {s['disp_err']:.1f} %, "
                f"held-out PSNR {s['psnr']:.1f} dB ({el / (n + 1):.1f} s each)")


def _scene_flow(req, c: Candidate, v0: Views, v1: Views, q0, t: int, device) -> dict:
    from ..data.dataset import open_dataset

    centre = v0.index[c.cameras[c.spec.views.index(c.spec.centre_view)]]
    q1 = estimate_inverse_depth(v1, centre, sorted({v1.index[i] for i in c.cameras}), req.n_planes, device=device)
    ds = open_dataset(req.out / layout.STUDY_RENDERS, union_rig_name(c.position))
    gt, valid = ds.read(t, (0, centre), "scene_flow"), ds.read(t, (0, centre), "valid_fwd")
    return scene_flow_error(q0, q1, v0.rgb[centre], v1.rgb[centre], v0.K, v0.poses[centre], v1.poses[centre], gt, valid)


def _cuda() -> bool:
    try:
        import torch

        return torch.cuda.is_available()
    except ImportError:  # pragma: no cover - torch is a dependency
        return False


def _apply(req: StudyRequest, bases: dict, candidates: list[Candidate], best: dict, names: list[str]) -> list[str]:
    """Write the winning arrangement at every studied position, at the base rig's own resolution."""
    from ..author.rigs import add_rig
    from ..author.stage import open_for_edit

    stage = open_for_edit(req.stage, req.apply_layer)
    for name, position in zip(names, bases):
        c = next(c for c in candidates if c.position == position and c.arrangement.name == best["arrangement"])
        base = bases[position].spec
        add_rig(stage, replace(c.spec, name=name, width=base.width, height=base.height))
    try:
        stage.GetRootLayer().Save()
    except Exception as e:
        target = req.apply_layer or req.stage
        raise LfusdError(f"cannot save {target} ({(str(e).strip().splitlines() or [type(e).__name__])[-1]}); check the file is writable") from None
    return names
