"""Dynamic variants of the templates (`lfusd stage new ... --dynamic`): walking and running
people (lfusd.author.people, UsdSkel), drifting boats, driving cars and swinging doors / sliding chairs
(lfusd.author.movers) over the stage's frame range.

Placement is constraint-aware like the static templates: every mover gets a path over its
support surface and reserves the box it sweeps over the clip, and later movers, people and rig
placements keep out of reserved boxes, so nothing meets. People are added with check=False; one
rulebook pass (lfusd.author.rules.Checker) at the end checks every object at every frame, and a
mover that still breaks a rule (which the reservations should prevent) is removed, so the
written stage always passes ``lfusd check``. The static template's blocky people are replaced
by animated ones. All randomness comes from a generator seeded with (seed, the template's seed
key, 1): the static part of the stage is the same as without --dynamic and the seed -> stage
mapping is stable.

This module holds the building blocks (walkers, traffic, drifting boats); each template's own
``@<template>.dynamic`` function, in its module, decides where they go.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pxr import Usd, UsdGeom

from .. import movers
from ..people import add_person
from ..rules import Checker
from ...errors import LfusdError
from ..human import HumanSpec
from ..labels import object_table
from ..vocabulary import SURFACES
from . import GAP, Placed, Scene, Site, Template
from . import objects as kit

PERSON_RADIUS = 0.6  # half width of the box a walking person sweeps (arm swing, turning)
PERSON_HEIGHT = 2.1


@dataclass
class Occupancy:
    """World boxes of every static part (per mesh, so a street light's arm does not block the
    road under it) and of every mover's sweep over the clip."""

    boxes: list[tuple[str, np.ndarray, np.ndarray]] = field(default_factory=list)

    @classmethod
    def of(cls, stage: Usd.Stage) -> "Occupancy":
        cache = UsdGeom.BBoxCache(Usd.TimeCode.Default(), [UsdGeom.Tokens.default_, UsdGeom.Tokens.render])
        occ = cls()
        for o in object_table(stage)[0]:
            if o.label in SURFACES:
                continue
            for m in o.mesh_paths:
                r = cache.ComputeWorldBound(stage.GetPrimAtPath(m)).ComputeAlignedRange()
                occ.boxes.append((o.prim_path, np.array(r.GetMin()), np.array(r.GetMax())))
        return occ

    def free(self, lo, hi, ignore: tuple[str, ...] = ()) -> bool:
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        return not any(p not in ignore and np.all(lo < b) and np.all(hi > a) for p, a, b in self.boxes)

    def reserve(self, scene: Scene, path: str, lo, hi) -> None:
        """Reserve a sweep (also for rig placement, which reads ``scene.placed``)."""
        self.boxes = [b for b in self.boxes if b[0] != path]
        self.boxes.append((path, np.asarray(lo, float), np.asarray(hi, float)))
        scene.placed = [p for p in scene.placed if p.path != path] + [Placed(path, np.asarray(lo, float), np.asarray(hi, float))]

    def drop(self, scene: Scene, path: str) -> None:
        self.boxes = [b for b in self.boxes if b[0] != path]
        scene.placed = [p for p in scene.placed if p.path != path]


@dataclass
class Ctx:
    scene: Scene
    rng: np.random.Generator
    occ: Occupancy
    frames: int
    fps: float
    movers: list[str] = field(default_factory=list)

    @property
    def duration(self) -> float:
        return (self.frames - 1) / self.fps

    @property
    def stage(self) -> Usd.Stage:
        return self.scene.stage


def populate(scene: Scene, template: Template, site: Site, seed: int) -> Site:
    """Add people and movers to a freshly built stage of ``template`` (its ``dynamic`` function);
    returns the site, with the rig samplers that function replaced."""
    stage = scene.stage
    first, last = int(stage.GetStartTimeCode()), int(stage.GetEndTimeCode())
    for o in object_table(stage)[0]:  # the static blocky people make way for animated ones
        if o.label == "person":
            stage.RemovePrim(o.prim_path)
            scene.placed = [p for p in scene.placed if p.path != o.prim_path]
    ctx = Ctx(scene, np.random.default_rng([int(seed), template.seed_key, 1]), Occupancy.of(stage), last - first + 1,
              float(stage.GetTimeCodesPerSecond() or 24.0))
    replaced = template.animate(ctx, site)
    settle(stage, ctx.movers, scene)
    return replaced or site


def settle(stage: Usd.Stage, dynamic: list[str], scene: Scene | None = None, rounds: int = 4) -> None:
    """One rulebook pass over every frame; movers that break a rule are removed (and the stage
    checked again). Raises if a static object breaks one."""
    for _ in range(rounds):
        bad = Checker(stage).check()
        if not bad:
            return
        culprits = set()
        for v in bad:
            hit = [p for p in dynamic if v.prim_path == p or p in v.detail.split()]
            if not hit:
                raise LfusdError(f"generated stage breaks a rule on a static object ({v.line()}); report this seed")
            culprits.update(hit)
        for p in sorted(culprits):
            stage.RemovePrim(p)
            dynamic.remove(p)
            if scene is not None:
                scene.placed = [x for x in scene.placed if x.path != p]
    raise LfusdError("generated movers keep breaking the rulebook; report this seed")


# -- building blocks -------------------------------------------------------------------------------
def walker(ctx: Ctx, start, direction, z: float, gait: str, speed: float, max_len: float | None = None) -> bool:
    """A person walking/running straight from ``start`` along ``direction`` on a surface at height
    ``z``, if the box it sweeps over the clip is free; True when added."""
    start, d = np.asarray(start, float), np.asarray(direction, float) / np.linalg.norm(direction)
    if max_len is not None and max_len < 1.5:
        return False
    travel = speed * ctx.duration
    length = travel + 2.0 if max_len is None else min(travel + 2.0, max_len)
    reach = min(travel, length)
    a, b = start, start + d * reach
    lo = np.r_[np.minimum(a, b) - PERSON_RADIUS, z - 0.05]
    hi = np.r_[np.maximum(a, b) + PERSON_RADIUS, z + PERSON_HEIGHT]
    if not ctx.occ.free(lo, hi):
        return False
    spec = HumanSpec(float(ctx.rng.uniform(1.6, 1.9)), float(ctx.rng.uniform(0.2, 0.8)))
    points = [start, start + d * max(length, 0.5)]
    try:
        prim = add_person(ctx.stage, points, gait=gait, speed=speed, spec=spec, check=False)
    except LfusdError:  # e.g. the path would leave its support: skip this person
        return False
    path = str(prim.GetPath())
    ctx.occ.reserve(ctx.scene, path, lo, hi)
    ctx.movers.append(path)
    return True


def walkers(ctx: Ctx, count: int, sample, tries: int = 40) -> None:
    """``count`` people from ``sample(rng) -> (start, direction, z, max_len or None)``."""
    for _ in range(count):
        for _ in range(tries):
            start, direction, z, max_len = sample(ctx.rng)
            run = ctx.rng.random() < 0.25
            speed = float(ctx.rng.uniform(2.5, 3.5) if run else ctx.rng.uniform(1.0, 1.6))
            if walker(ctx, start, direction, z, "run" if run else "walk", speed, max_len):
                break


def traffic(ctx: Ctx, lane_y: float, heading: int, x0: float, x1: float, cars: int) -> None:
    """``cars`` cars in convoy along the lane y = ``lane_y`` heading +x (1) or -x (-1), kept
    inside x0..x1 over the clip; parked cars in the lane make way."""
    scene, rng = ctx.scene, ctx.rng
    lane_lo, lane_hi = np.array([x0, lane_y - 1.1, 0.0]), np.array([x1, lane_y + 1.1, 1.8])
    for o in object_table(ctx.stage)[0]:
        if o.label == "car" and o.prim_path not in ctx.movers:
            box = [p for p in scene.placed if p.path == o.prim_path]
            if box and np.all(box[0].lo < lane_hi) and np.all(box[0].hi > lane_lo):
                ctx.stage.RemovePrim(o.prim_path)
                ctx.occ.drop(scene, o.prim_path)
    if not ctx.occ.free(lane_lo, lane_hi):
        return
    specs = [kit.moving_car(rng) for _ in range(cars)]
    lengths = [float(np.ptp(p[0][1].points[:, 0])) for p, _, _ in specs]
    gaps = [float(rng.uniform(4.0, 9.0)) for _ in specs]
    convoy = sum(lengths) + sum(gaps[1:])
    speed = float(rng.uniform(4.0, 9.0))
    if ctx.duration > 0:
        speed = min(speed, (x1 - x0 - 1.0 - convoy) / ctx.duration)
    if speed < 1.0:
        return
    back = 0.5  # rear of the last car, measured along the heading from the lane's start
    for k in reversed(range(cars)):
        (parts, wheels, radius), length = specs[k], lengths[k]
        s = back + length / 2
        cx = x0 + s if heading > 0 else x1 - s
        path = scene.name("Car")
        scene.add(path, "car", parts, (cx, lane_y, GAP), 0.0 if heading > 0 else 180.0, track=False)
        for name, hub, mesh in wheels:
            movers.make_wheel(scene.builder.mesh(f"{path}/{name}", mesh, kit.WHEEL_TEXTURE).GetPrim(), hub, radius)
        movers.drive_car(ctx.stage, path, speed)
        width = float(np.ptp(parts[0][1].points[:, 1]))
        end = cx + heading * speed * ctx.duration
        lo = np.array([min(cx, end) - length / 2 - 0.2, lane_y - width / 2 - 0.2, 0.0])
        hi = np.array([max(cx, end) + length / 2 + 0.2, lane_y + width / 2 + 0.2, 1.8])
        ctx.occ.reserve(scene, path, lo, hi)
        ctx.movers.append(path)
        back += length + gaps[k]


def boats(ctx: Ctx, level: float, x0: float, x1: float, y0: float, y1: float, speeds=(0.3, 0.9)) -> None:
    """Make every boat drift along x (either way, slower if blocked, else bob in place) inside x0..x1."""
    scene, rng = ctx.scene, ctx.rng
    for o in object_table(ctx.stage)[0]:
        if o.label != "boat":
            continue
        box = next(p for p in scene.placed if p.path == o.prim_path)
        waves = movers.wave_params(rng)
        choices = [float(rng.uniform(*speeds)) * (1 if rng.random() < 0.5 else -1)]
        choices += [-choices[0], choices[0] / 3, -choices[0] / 3, 0.0]
        for v in choices:
            shift = v * ctx.duration
            lo = box.lo + [min(shift, 0.0) - 0.3, -0.3, -0.3]
            hi = box.hi + [max(shift, 0.0) + 0.3, 0.3, 0.3]
            if lo[0] >= x0 and hi[0] <= x1 and lo[1] >= y0 and hi[1] <= y1 and ctx.occ.free(lo, hi, ignore=(o.prim_path,)):
                movers.drift_boat(ctx.stage, o.prim_path, (v, 0.0), level=level, waves=waves)
                ctx.occ.reserve(scene, o.prim_path, lo, hi)
                ctx.movers.append(o.prim_path)
                break


AXES = [np.array(v, float) for v in ((1, 0), (0, 1), (-1, 0), (0, -1))]


def run_inside(start, d, lo, hi) -> float:
    """How far one can go from ``start`` along the axis direction ``d`` inside the box lo..hi."""
    k = int(np.argmax(np.abs(d)))
    return float((hi[k] - start[k]) if d[k] > 0 else (start[k] - lo[k]))
