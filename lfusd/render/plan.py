"""Planning a render: which views are missing, and the work units (the worker's job schema).

No pxr and no bpy here: the parent plans with it and the Blender worker parses its job with it.
"""

from __future__ import annotations

import logging
import os
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

from .. import layout
from ..data.integrity import FULL, RAW, motion_inputs, motion_problem, passes_on_disk, read_record, render_problems, repair_need
from ..layout import frame_dir, view_key
from .request import RenderRequest

log = logging.getLogger(__name__)
View = tuple[int, int]


class Plan:
    """The views still to render, per (rig, frame): a view is done iff its files match its completion
    record (lfusd.data.integrity). A damaged view is repaired, not replaced: what its record proves
    intact stays, and only what is needed to rebuild the rest is rendered (lfusd.render.executors.commit_view).
    Views whose image is intact but whose ground truth must be derived again (gt.exr, or with
    ``motion`` the motion of a view or its neighbours', whose raw passes a render without --keep-raw
    removed) get their raw passes alone rendered again: :attr:`raw_only`.

    ``dataset_frames``: every frame the dataset lists (a frame's neighbour counts only if it has it)."""

    def __init__(self, out: Path, views_of: dict[str, list[View]], frames: list[int], motion: bool = False,
                 dataset_frames: list[int] | None = None):
        self.todo: dict[tuple[str, int], list[View]] = {}
        self.raw_only: set[tuple[str, int, View]] = set()
        self.total = 0
        damaged, raw = [], []
        for rig, views in views_of.items():
            need: dict[tuple[int, View], str] = {}
            for f in frames:
                self.total += len(views)
                for v in views:
                    d = frame_dir(out, rig, f) / view_key(v)
                    problems = render_problems(d)
                    if problems:
                        need[(f, v)] = repair_need(d) or FULL
                        if d.exists():
                            damaged.append(f"{d} ({problems[0]})")
            if motion:
                self._motion_needs(out, rig, views, frames, set(dataset_frames or frames), need)
            for (f, v), what in sorted(need.items()):
                self.todo.setdefault((rig, f), []).append(v)
                self.total += f not in frames  # a neighbour outside the range, rendered for the derivation
                if what == RAW:
                    self.raw_only.add((rig, f, v))
                    if f not in frames or not render_problems(frame_dir(out, rig, f) / view_key(v)):
                        raw.append(f"frame {f} view {view_key(v)}")
        if damaged:
            more = f" and {len(damaged) - 1} more" if len(damaged) > 1 else ""
            log.warning("rendering again %d view(s) whose files do not match their record: %s%s", len(damaged), damaged[0], more)
        if raw:
            more = f" and {len(raw) - 1} more" if len(raw) > 1 else ""
            log.warning("rendering the raw passes of %d intact view(s) again, to derive the motion keys next to them: %s%s", len(raw), raw[0], more)

    @staticmethod
    def _motion_needs(out: Path, rig: str, views: list[View], frames: list[int], known: set[int], need: dict) -> None:
        """Add to ``need`` the raw passes (RAW) that deriving a view's motion again needs, for every
        view of ``frames`` or a rendered neighbour of them whose motion is missing, damaged or stale:
        its own and its neighbours', where they are not on disk."""
        known_rendered: dict[int, bool] = {}

        def rendered(g: int) -> bool:  # a neighbour counts when this run renders it or an earlier one did
            if g not in known_rendered:  # once per frame: each view's record is read once
                known_rendered[g] = g in frames or all(read_record(frame_dir(out, rig, g) / view_key(v)) is not None for v in views)
            return known_rendered[g]

        wanted = set(frames)
        candidates = sorted(wanted | {g for f in wanted for g in (f - 1, f + 1) if g in known and rendered(g)})
        for v in views:
            for c in candidates:
                d = frame_dir(out, rig, c) / view_key(v)
                window = [g for g in (c - 1, c, c + 1) if g == c or (g in known and rendered(g))]
                passes = {k: frame_dir(out, rig, g) / view_key(v) / layout.PASSES_EXR if g in window else None
                          for k, g in (("prev", c - 1), ("cur", c), ("next", c + 1))}
                if not motion_problem(d, motion_inputs(passes)):
                    continue  # current, judged by the digests on record (a re-render gives the same pixels)
                for g in window:
                    if (g, v) not in need and not passes_on_disk(frame_dir(out, rig, g) / view_key(v)):
                        need[(g, v)] = RAW

    @property
    def remaining(self) -> int:
        return sum(len(v) for v in self.todo.values())


@dataclass
class WorkUnit:
    """One Blender worker's job: it imports ``stage`` once and renders ``frames`` of ``cameras``.

    Sent to the worker as JSON on stdin (``to_json``) and parsed there (``from_json``), so
    both sides share this schema."""

    unit: int
    rig: str
    stage: str
    cameras: dict[str, str]  # view key -> camera prim path
    frames: list[int]
    width: int
    height: int
    samples: int
    device: str
    instances: dict[str, int]  # mesh prim path -> instance id
    threads: int  # Cycles threads; 0: Blender's default (all cores)
    motion: bool  # render the t+/-1 position AOVs
    has_dome: bool  # the stage has a DomeLight: the worker creates a world before import
    stage_range: list[int]  # the stage's [first, last] frame
    # The stage's WorldFrame.to_dict() (up_axis, meters_per_unit, stage_to_world): the worker
    # checks that Blender's import lands in lfusd's world (Z-up, metres) by this map.
    world: dict = field(default_factory=dict)
    scratch: str = ""  # where the worker writes; set by the executor
    add_light: bool = False  # the stage has no lights and --light auto: add a neutral sky and sun
    # Instanced gprims (scenegraph instance proxies, point instances), which Blender draws as copies
    # under an anchor object: [anchor prim path, instance id, vertex count, centroid x, y, z in the
    # anchor's space at stage_range[0], part path] (lfusd.author.geometry.render_instances).
    instanced: list = field(default_factory=list)
    render_pixels: int = 0  # at most this many pixels per render call (0: RENDER_PIXELS); see view_chunks
    raw_codec: str = "ZIP"  # Blender's codec for the data passes (lfusd.render.request.raw_codec)
    beauty: bool = True  # False: the data passes alone (a repair that needs no image: Plan.raw_only)
    physical_sky: bool = False  # a DomeLight asks for Blender's physical sky (lfusd:sky = "physical")
    fstop: float = 0.0  # --fstop / --focus: the beauty's thin lens (0: a pinhole); the data passes stay pinhole
    focus: float = 0.0
    shutter: float = 0.0  # --shutter: the beauty's motion blur (fraction of a frame, centred); the data passes stay sharp
    materials: bool = False  # --materials: the material-flags AOV and per-triangle flags (lfusd.render.worker.mark_materials)
    # --lens: view key -> {"K": 3x3, "dist": lfusd.camera.Distortion.to_dict()}; each such view renders
    # through the OSL camera of lfusd.render.lens (the beauty and the data passes alike); {}: pinholes
    lenses: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return asdict(self)

    @classmethod
    def from_json(cls, job: dict) -> "WorkUnit":
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in job.items() if k in known})


def chunks(items: list, n: int) -> list[list]:
    """Split into at most n contiguous, nearly equal runs (contiguous frames share t+/-1)."""
    n = max(1, min(n, len(items)))
    size, extra = divmod(len(items), n)
    out, i = [], 0
    for k in range(n):
        j = i + size + (1 if k < extra else 0)
        out.append(items[i:j])
        i = j
    return out


# Pixels per render call. A multiview render result holds every enabled view's passes at once:
# about 100 bytes per pixel with the data passes and the motion AOVs (measured: 8.6 GB in one
# process for 81 views at 1024x1024). The worker renders its views in chunks of at most this many
# pixels, so its memory does not grow with the grid: 16 views per call at 1024x1024, 64 at 512x512.
# Measured with `lfusd render-video`, 2 frames at 1 sample, 1024x1024: peak RSS of the worker 1.39 GiB
# for 3x3 views and 1.88 GiB for 9x9 (8.6 GB in one call before). A call costs about 60 ms beyond
# its pixels, nothing at this size.
RENDER_PIXELS = 16 * 1024 * 1024


def view_chunks(views: list, width: int, height: int, budget: int = 0) -> list[list]:
    """``views`` in as few render calls of at most ``budget`` pixels (default RENDER_PIXELS) as
    possible, of nearly equal size; at least one view per call."""
    per_call = max(1, (budget or RENDER_PIXELS) // max(1, width * height))
    return chunks(list(views), -(-len(views) // per_call))


@dataclass
class StageSetup:
    """What every worker of a render needs to know about the stage, found once by the parent with
    pxr (the worker must not use usd-core): the WorkUnit fields shared by all units."""

    instances: dict[str, int]  # mesh prim path -> instance id
    instanced: list  # see WorkUnit.instanced
    has_dome: bool
    stage_range: list[int]  # frames over which the worker knows the stage (t+/-1 outside is unknown)
    add_light: bool
    world: dict  # the stage's WorldFrame.to_dict()
    physical_sky: bool = False  # see WorkUnit.physical_sky


def plan_units(req: RenderRequest, plan: Plan, cameras_of: dict[str, dict[View, str]], sizes: dict[str, tuple[int, int]],
               setup: StageSetup, raw_codec: str = "ZIP", lenses: dict | None = None) -> list[WorkUnit]:
    """Work units covering every missing (rig, frame, view) of ``plan``; Blender writes the data
    passes with ``raw_codec``. ``lenses``: {rig: {view key: lens}} of a render with --lens (WorkUnit.lenses)."""
    units: list[WorkUnit] = []
    for beauty in (True, False):
        todo = {k: [v for v in vs if ((k[0], k[1], v) in plan.raw_only) != beauty] for k, vs in plan.todo.items()}
        todo = {k: vs for k, vs in todo.items() if vs}
        groups = []  # (rig, frames, views): full renders as a cross-product (a complete view is not committed again)
        for rig_name in sorted({k[0] for k in todo}):
            if beauty:
                groups.append((rig_name, sorted(f for (r, f) in todo if r == rig_name),
                               sorted({v for (r, f), vs in todo.items() if r == rig_name for v in vs})))
                continue
            # raw passes alone: exactly the views and frames asked for (an extra one would replace the
            # digest its neighbours' motion records name), views with the same frames together
            frames_of: dict[View, list[int]] = {}
            for (r, f), vs in sorted(todo.items()):
                for v in vs if r == rig_name else ():
                    frames_of.setdefault(v, []).append(f)
            for fs in sorted({tuple(fs) for fs in frames_of.values()}):
                groups.append((rig_name, list(fs), sorted(v for v, g in frames_of.items() if tuple(g) == fs)))
        for rig_name, frames, views in groups:
            view_chunks = chunks(views, req.workers)
            # Fewer views than workers: split the frames too. Ray gets units of at most
            # frames_per_unit frames, so retries and load balancing stay fine-grained.
            n_frame_chunks = -(-req.workers // len(view_chunks))
            if req.executor == "ray":
                n_frame_chunks = max(n_frame_chunks, -(-len(frames) // req.frames_per_unit))
            for fchunk in chunks(frames, n_frame_chunks):
                for vchunk in view_chunks:
                    unit_frames = [f for f in fchunk if any(v in todo.get((rig_name, f), ()) for v in vchunk)]
                    if not unit_frames:
                        continue
                    width, height = sizes[rig_name]
                    units.append(WorkUnit(
                        unit=len(units), rig=rig_name, stage=str(Path(req.stage).resolve()),
                        cameras={view_key(v): cameras_of[rig_name][v] for v in vchunk}, frames=unit_frames,
                        lenses={view_key(v): (lenses or {})[rig_name][view_key(v)] for v in vchunk} if (lenses or {}).get(rig_name) else {},
                        width=width, height=height, samples=req.samples, device=req.device,
                        # Locally, workers share the cores; on Ray, Blender takes what the node has.
                        threads=max(1, (os.cpu_count() or 1) // req.workers) if req.executor == "local" else 0,
                        motion=req.motion, render_pixels=RENDER_PIXELS, raw_codec=raw_codec, beauty=beauty, materials=req.materials, shutter=req.shutter, fstop=req.fstop, focus=req.focus,
                        **asdict(setup),
                    ))
    return units
