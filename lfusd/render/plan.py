"""Planning a render: which views are missing, and the work units (the worker's job schema).

No pxr and no bpy here: the parent plans with it and the Blender worker parses its job with it.
"""

from __future__ import annotations

import logging
import os
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

from ..data.integrity import render_problems
from ..layout import frame_dir, view_key
from .request import RenderRequest

log = logging.getLogger(__name__)
View = tuple[int, int]


class Plan:
    """The views still to render, per (rig, frame): a view is done iff its files match its completion
    record (lfusd.data.integrity); a folder that exists but does not match is rendered again."""

    def __init__(self, out: Path, views_of: dict[str, list[View]], frames: list[int]):
        self.todo: dict[tuple[str, int], list[View]] = {}
        self.total = 0
        damaged = []
        for rig, views in views_of.items():
            for f in frames:
                self.total += len(views)
                missing = []
                for v in views:
                    d = frame_dir(out, rig, f) / view_key(v)
                    problems = render_problems(d)
                    if problems:
                        missing.append(v)
                        if d.exists():
                            damaged.append(f"{d} ({problems[0]})")
                if missing:
                    self.todo[(rig, f)] = missing
        if damaged:
            more = f" and {len(damaged) - 1} more" if len(damaged) > 1 else ""
            log.warning("rendering again %d view(s) whose files do not match their record: %s%s", len(damaged), damaged[0], more)

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
    seed: int = 0
    max_bounces: int = 12
    persistent: bool = False
    add_light: bool = False  # the stage has no lights and --light auto: add a neutral sky and sun
    # Instanced gprims (scenegraph instance proxies, point instances), which Blender draws as copies
    # under an anchor object: [anchor prim path, instance id, vertex count, centroid x, y, z in the
    # anchor's space at stage_range[0], part path] (lfusd.author.geometry.render_instances).
    instanced: list = field(default_factory=list)
    render_pixels: int = 0  # at most this many pixels per render call (0: RENDER_PIXELS); see view_chunks
    raw_codec: str = "ZIP"  # Blender's codec for the data passes (lfusd.render.request.raw_codec)

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


def plan_units(req: RenderRequest, plan: Plan, cameras_of: dict[str, dict[View, str]], sizes: dict[str, tuple[int, int]],
               setup: StageSetup, raw_codec: str = "ZIP") -> list[WorkUnit]:
    """Work units covering every missing (rig, frame, view) of ``plan``; Blender writes the data
    passes with ``raw_codec``."""
    units: list[WorkUnit] = []
    for rig_name in sorted({k[0] for k in plan.todo}):
        frames = sorted(f for (r, f) in plan.todo if r == rig_name)
        views = sorted({v for (r, f), vs in plan.todo.items() if r == rig_name for v in vs})
        view_chunks = chunks(views, req.workers)
        # Fewer views than workers: split the frames too. Ray gets units of at most
        # frames_per_unit frames, so retries and load balancing stay fine-grained.
        n_frame_chunks = -(-req.workers // len(view_chunks))
        if req.executor == "ray":
            n_frame_chunks = max(n_frame_chunks, -(-len(frames) // req.frames_per_unit))
        for fchunk in chunks(frames, n_frame_chunks):
            for vchunk in view_chunks:
                todo = [f for f in fchunk if any(v in plan.todo.get((rig_name, f), ()) for v in vchunk)]
                if not todo:
                    continue
                width, height = sizes[rig_name]
                units.append(WorkUnit(
                    unit=len(units), rig=rig_name, stage=str(Path(req.stage).resolve()),
                    cameras={view_key(v): cameras_of[rig_name][v] for v in vchunk}, frames=todo,
                    width=width, height=height, samples=req.samples, device=req.device,
                    # Locally, workers share the cores; on Ray, Blender takes what the node has.
                    threads=max(1, (os.cpu_count() or 1) // req.workers) if req.executor == "local" else 0,
                    motion=req.motion, render_pixels=RENDER_PIXELS, raw_codec=raw_codec, **asdict(setup),
                ))
    return units
