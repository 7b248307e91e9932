"""Planning a render: which views are missing, and the work units (the worker's job schema).

No pxr and no bpy here: the parent plans with it and the Blender worker parses its job with it.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

from ..layout import frame_dir, view_key
from .request import RenderRequest

View = tuple[int, int]


class Plan:
    """The views still to render, per (rig, frame); a view folder that exists is done."""

    def __init__(self, out: Path, views_of: dict[str, list[View]], frames: list[int]):
        self.todo: dict[tuple[str, int], list[View]] = {}
        self.total = 0
        for rig, views in views_of.items():
            for f in frames:
                self.total += len(views)
                missing = [v for v in views if not (frame_dir(out, rig, f) / view_key(v)).is_dir()]
                if missing:
                    self.todo[(rig, f)] = missing

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
    scratch: str = ""  # where the worker writes; set by the executor
    seed: int = 0
    max_bounces: int = 12
    persistent: bool = False
    # Instanced gprims (scenegraph instance proxies, point instances), which Blender draws as copies
    # under an anchor object: [anchor prim path, instance id, vertex count, centroid x, y, z in the
    # anchor's space at stage_range[0], part path] (lfusd.author.geometry.render_instances).
    instanced: list = field(default_factory=list)

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


def plan_units(req: RenderRequest, plan: Plan, cameras_of: dict[str, dict[View, str]], sizes: dict[str, tuple[int, int]],
               instances: dict[str, int], has_dome: bool, stage_range: tuple[int, int],
               instanced: list | None = None) -> list[WorkUnit]:
    """Work units covering every missing (rig, frame, view) of ``plan``."""
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
                    width=width, height=height, samples=req.samples, device=req.device, instances=instances,
                    # Locally, workers share the cores; on Ray, Blender takes what the node has.
                    threads=max(1, (os.cpu_count() or 1) // req.workers) if req.executor == "local" else 0,
                    motion=req.motion, has_dome=has_dome, stage_range=list(stage_range), instanced=instanced or [],
                ))
    return units
