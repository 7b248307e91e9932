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

This module holds the building blocks (walkers, traffic, drifting boats, performers); each
template's own ``@<template>.dynamic`` function, in its module, decides where they go.

Choreography (issue 16): every rig must see motion. The template names spots where a person
may walk a loop (``ctx.spot``, mostly just clear of a prop: :func:`loop_beside`); :func:`populate`
puts a performer on one spot per set of up to three rigs, and :func:`place_rigs` stands each rig of
a set 1.5-3.5 m from its performer, looking at it, trying candidate placements until one meets the
goal of lfusd.author.choreography (moving objects over 5 % of the centre view in 90 % of the
frames, a person in view in half of them) measured by ray casting the stage at sampled frames;
among passing candidates it prefers one where a moving object passes behind a static one and
(outdoors, ``Scene.near_foreground``) whose nearest surface gives choreography.DISPARITY_GOAL
pixels per baseline step at the reference rig: a rig just behind a prop (:func:`_by_prop`) has
both.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from pxr import Usd, UsdGeom

from .. import movers
from .. import choreography
from ...camera import RigSpec
from ..people import add_person
from ..rigs import add_rig
from ..rules import Checker
from ...errors import LfusdError
from ..human import HumanSpec
from ..labels import object_table
from ..vocabulary import SURFACES
from . import GAP, Placed, Scene, Site, Template
from . import objects as kit

log = logging.getLogger(__name__)

RIGS_PER_SET = 3  # rigs that watch one performer
# Distances from a rig to the centre of its performer's loop, beyond the rig's half size, tried in turn.
RIG_RINGS = ((1.0, 1.6), (1.6, 2.6), (2.6, 3.6))
PLAN_FRAMES = 24  # frames sampled when measuring a candidate rig
PLAN_WIDTH = 32  # pixels across when measuring a candidate rig
PLAN_MARGIN = 0.04  # a candidate must beat the goal by this much at the sampled frames
PROP_REACH = 3.5  # m: props whose box lies this near a performer's loop centre may stand in front of a rig
PROP_SHARE = 0.6  # share of candidates placed just behind a prop
FOCUS_TRIES = 24  # candidates tried behind props / past static objects when the best shows no occlusion
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
                # a point instance (a catalogue asset's /Leaves[3]) has no prim: its object's box
                r = cache.ComputeWorldBound(stage.GetPrimAtPath(m if "[" not in m else o.prim_path)).ComputeAlignedRange()
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
    # spot(rng) -> (centre xy, ground z, heading degrees, loop length, loop width) or None: where a
    # performer may walk a loop (set by the template's dynamic function)
    spot: Callable | None = None
    performers: list[tuple[np.ndarray, float, str]] = field(default_factory=list)  # (centre xyz, heading, prim) per set
    statics: list | None = None  # (label, lo, hi) of static objects (see prop_near)
    characters: list | None = None  # the catalogues' person assets lfusd's gaits can drive (see character)
    # catalogue assets for movers are drawn from this generator, not ``rng``: with or without catalogues
    # a seed's placements, speeds and rigs are drawn alike
    picks: np.random.Generator | None = None

    @property
    def duration(self) -> float:
        return (self.frames - 1) / self.fps

    @property
    def stage(self) -> Usd.Stage:
        return self.scene.stage


def populate(scene: Scene, template: Template, site: Site, seed: int, rigs: int = 10) -> Site:
    """Add people and movers to a freshly built stage of ``template`` (its ``dynamic`` function)
    and one performer per set of up to three of the ``rigs`` (at least one); returns the site,
    with the rig samplers that function replaced. The context is kept as ``scene.ctx``; call
    :func:`finish` once the rigs are placed."""
    stage = scene.stage
    first, last = int(stage.GetStartTimeCode()), int(stage.GetEndTimeCode())
    for o in object_table(stage)[0]:  # the static blocky people make way for animated ones
        if o.label == "person":
            stage.RemovePrim(o.prim_path)
            scene.placed = [p for p in scene.placed if p.path != o.prim_path]
    ctx = Ctx(scene, np.random.default_rng([int(seed), template.seed_key, 1]), Occupancy.of(stage), last - first + 1,
              float(stage.GetTimeCodesPerSecond() or 24.0), picks=np.random.default_rng([int(seed), template.seed_key, 2]))
    replaced = template.animate(ctx, site)
    if ctx.spot is not None:
        for _ in range(max(1, math.ceil(rigs / RIGS_PER_SET))):
            performer(ctx)
    scene.ctx = ctx
    return replaced or site


def finish(scene: Scene) -> None:
    """The rulebook pass over every frame once movers, performers and rigs are in (:func:`settle`)."""
    settle(scene.stage, scene.ctx.movers, scene)


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
def character(ctx: Ctx):
    """A catalogue character for the next walking person, drawn uniformly (``ctx.picks``) from the scene's
    catalogue assets of class ``person`` that lfusd's gaits can drive (UsdSkel bipeds: those
    lfusd.author.people.read_character accepts), or None when there are none (a procedural body)."""
    if ctx.characters is None:
        from ..people import read_character

        ctx.characters = []
        for a in ctx.scene.assets.get("person", ()):
            try:
                read_character(a.path())
            except LfusdError as e:  # a statue or a non-biped stays a static catalogue person
                log.info("catalogue person %s does not walk: %s", a.name, e)
                continue
            ctx.characters.append(a)
    return ctx.characters[int(ctx.picks.integers(len(ctx.characters)))] if ctx.characters else None


def sweep_size(asset) -> tuple[float, float]:
    """(half width, height) of the box a walking person sweeps: PERSON_RADIUS and PERSON_HEIGHT,
    or more for a catalogue character that is wider (half its bind-pose footprint's longer side
    plus 0.1 m: a T-pose's arms) or taller (plus 0.2 m)."""
    if asset is None:
        return PERSON_RADIUS, PERSON_HEIGHT
    from ..catalogue import placed_size

    sx, sy, sz = placed_size(asset)
    return max(PERSON_RADIUS, max(sx, sy) / 2 + 0.1), max(PERSON_HEIGHT, sz + 0.2)


def person_body(rng: np.random.Generator, asset) -> dict:
    """add_person's keyword for the body: the catalogue character ``asset``, else a procedural
    human of random height and build (drawn either way: the seed's later draws stay alike)."""
    spec = HumanSpec(float(rng.uniform(1.6, 1.9)), float(rng.uniform(0.2, 0.8)))
    return {"spec": spec} if asset is None else {"character": str(asset.path())}


def walker(ctx: Ctx, start, direction, z: float, gait: str, speed: float, max_len: float | None = None) -> bool:
    """A person walking/running straight from ``start`` along ``direction`` on a surface at height
    ``z``, if the box it sweeps over the clip is free; True when added. The person is a catalogue
    character when the scene's catalogues have walkable ones (:func:`character`)."""
    start, d = np.asarray(start, float), np.asarray(direction, float) / np.linalg.norm(direction)
    if max_len is not None and max_len < 1.5:
        return False
    travel = speed * ctx.duration
    length = travel + 2.0 if max_len is None else min(travel + 2.0, max_len)
    reach = min(travel, length)
    a, b = start, start + d * reach
    who = character(ctx)
    radius, height = sweep_size(who)
    lo = np.r_[np.minimum(a, b) - radius, z - 0.05]
    hi = np.r_[np.maximum(a, b) + radius, z + height]
    if not ctx.occ.free(lo, hi):
        return False
    points = [start, start + d * max(length, 0.5)]
    try:
        prim = add_person(ctx.stage, points, gait=gait, speed=speed, check=False, **person_body(ctx.rng, who))
    except LfusdError:  # e.g. the path would leave its support: skip this person
        return False
    path = str(prim.GetPath())
    ctx.occ.reserve(ctx.scene, path, lo, hi)
    ctx.movers.append(path)
    return True


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
    if scene.assets.get("car"):
        # catalogue cars in their place, drawn from the catalogue's own generator (Ctx.picks): the seed's
        # other draws (speeds, people, rigs) stay what they were. They drive
        # as they are (their wheels, unknown to lfusd, do not turn); procedural ones roll theirs.
        specs = [(scene.draw("car", kit.car, rng=ctx.picks), [], None) for _ in specs]
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


# -- choreography -----------------------------------------------------------------------------------
def loop_path(centre, heading_deg: float, length: float, width: float, total: float, clockwise: bool) -> np.ndarray:
    """Corners of a rectangular loop (``length`` along ``heading_deg``, ``width`` across) around
    ``centre``, repeated until the path is ``total`` metres long (people turn on fillets)."""
    h = math.radians(heading_deg)
    ax, ay = np.array([math.cos(h), math.sin(h)]), np.array([-math.sin(h), math.cos(h)])
    corners = [(-1, -1), (1, -1), (1, 1), (-1, 1)]
    if clockwise:
        corners = corners[::-1]
    pts = [np.asarray(centre, float) + a * length / 2 * ax + b * width / 2 * ay for a, b in corners]
    lap = 2 * (length + width)
    laps = int(math.ceil(total / lap)) + 1
    return np.array((pts * laps)[: 4 * laps + 1])


def prop_near(ctx: Ctx, rng: np.random.Generator, labels, region):
    """(lo, hi, label): the box of a random static object of ``labels`` whose centre lies inside
    ``region`` ((x0, y0), (x1, y1)), or None."""
    if ctx.statics is None:
        ctx.statics = [(o.label, *next(((p.lo, p.hi) for p in ctx.scene.placed if p.path == o.prim_path), (None, None)))
                       for o in object_table(ctx.stage)[0] if o.prim_path not in ctx.movers]
        ctx.statics = [x for x in ctx.statics if x[1] is not None]
    (x0, y0), (x1, y1) = region
    near = [(lo, hi, label) for label, lo, hi in ctx.statics if label in labels and x0 <= (lo[0] + hi[0]) / 2 <= x1
            and y0 <= (lo[1] + hi[1]) / 2 <= y1]
    return near[int(rng.integers(len(near)))] if near else None


def loop_beside(ctx: Ctx, rng: np.random.Generator, labels, region, length: float, width: float,
                gap=(0.05, 0.5), tries: int = 8, props=None):
    """(centre, heading): a loop (``length`` along ``heading``, 0 or 90 degrees, ``width`` across)
    centred inside ``region`` ((x0, y0), (x1, y1)) whose sweep passes ``gap`` metres from one side of a
    random static object of ``labels`` in that region (or in ``props``, another region), along that
    side; or None. A rig just behind the object then has it as a near foreground that the performer
    passes behind, mostly across the object's short side (nearer the loop)."""
    (x0, y0), (x1, y1) = region
    for _ in range(tries):
        got = prop_near(ctx, rng, labels, props or region)
        if got is None:
            return None
        lo, hi, _ = got
        thin = int(np.argmin(hi[:2] - lo[:2]))
        axis, sign = thin if rng.random() < 0.75 else 1 - thin, 1 if rng.random() < 0.5 else -1
        heading = 90.0 if axis == 0 else 0.0  # the loop runs along the side it is on
        ext = np.array([length, width] if heading == 0.0 else [width, length]) / 2 + PERSON_RADIUS
        c = (lo[:2] + hi[:2]) / 2
        c[1 - axis] += float(rng.uniform(-0.5, 0.5)) * (hi[1 - axis] - lo[1 - axis])  # along the side
        c[axis] = (hi if sign > 0 else lo)[axis] + sign * (ext[axis] + float(rng.uniform(*gap)))
        if x0 <= c[0] <= x1 and y0 <= c[1] <= y1:
            return c, heading
    return None


def performer(ctx: Ctx, tries: int = 100) -> bool:
    """A person (a catalogue character when there are walkable ones: :func:`character`) walking a
    loop on a spot the template offers (``ctx.spot``) for the whole clip, if its sweep is free;
    records it in ``ctx.performers``."""
    rng = ctx.rng
    who = character(ctx)
    radius, height = sweep_size(who)
    for _ in range(tries):
        got = ctx.spot(rng)
        if got is None:
            continue
        centre, z, heading, length, width = got
        centre = np.asarray(centre, float)
        h = math.radians(heading)
        ext = np.abs([length / 2 * math.cos(h)]) + np.abs([width / 2 * math.sin(h)])
        ey = abs(length / 2 * math.sin(h)) + abs(width / 2 * math.cos(h))
        lo = np.r_[centre - [ext[0], ey] - radius, z - 0.05]
        hi = np.r_[centre + [ext[0], ey] + radius, z + height]
        if not ctx.occ.free(lo, hi):
            continue
        speed = float(rng.uniform(0.9, 1.4))
        kw = person_body(rng, who)
        points = loop_path(centre, heading, length, width, speed * ctx.duration + 3.0, bool(rng.random() < 0.5))
        try:
            prim = add_person(ctx.stage, points, gait="walk", speed=speed, check=False, **kw)
        except LfusdError:
            continue
        path = str(prim.GetPath())
        ctx.occ.reserve(ctx.scene, path, lo, hi)
        ctx.movers.append(path)
        ctx.performers.append((np.r_[centre, z], float(heading), path))
        return True
    return False


def _props(scene: Scene, ctx: Ctx) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(path, lo, hi) of the static objects a rig may stand just behind: not surfaces, buildings or
    walls (too big to look past), nor movers."""
    boxes = {p.path: p for p in scene.placed}
    return [(o.prim_path, boxes[o.prim_path].lo, boxes[o.prim_path].hi) for o in object_table(ctx.stage)[0]
            if o.prim_path in boxes and o.prim_path not in ctx.movers and o.label not in SURFACES
            and o.label not in ("building", "wall", "person")]


def _by_prop(rng: np.random.Generator, prop, centre: np.ndarray, body: float, draws: int = 80) -> np.ndarray | None:
    """A rig position 1.5-3.4 m from the performer's loop ``centre`` (nearer, the performer keeps a
    large share of the view) with ``prop`` (path, lo, hi) in front of it: the prop's box 0.02-0.25 m
    beyond the rig's own half size ``body`` (its nearest surface about 0.6-0.9 m away: 150-230 px
    per step at the reference rig), its nearest point within 30 degrees of the direction to the
    loop, so the performer passes behind it at times; a prop wider than 0.6 m and taller than 1.2 m
    stays off the line to the loop's centre (it must not hide it all). Low enough to keep a low prop
    in view. None when no draw fits."""
    _, lo, hi = prop
    reach = body + 0.25
    xy = rng.uniform(lo[:2] - reach, hi[:2] + reach, (draws, 2))
    q = np.clip(xy, lo[:2], hi[:2])  # the prop's nearest points
    gap = np.linalg.norm(q - xy, axis=1)
    to_c = centre[:2] - xy
    d = np.linalg.norm(to_c, axis=1)
    ok = ((body + 0.02 <= gap) & (gap <= reach) & (1.5 <= d) & (d <= 3.4)
          & (np.sum((q - xy) * to_c, axis=1) >= math.cos(math.radians(30)) * gap * d))
    if float(np.max(hi[:2] - lo[:2])) > 0.6 and hi[2] - centre[2] > 1.2:
        ok &= ~_crosses(xy, np.broadcast_to(centre[:2], xy.shape), lo[None, :2], hi[None, :2])[:, 0]
    k = np.flatnonzero(ok)
    if not len(k):
        return None
    top = float(hi[2] - centre[2])
    z = float(rng.uniform(1.2, 1.9)) if top > 1.5 else max(body + 0.05, top + float(rng.uniform(0.15, 0.5)))
    return np.r_[xy[k[0]], centre[2] + z]


def _peek(rng: np.random.Generator, screens, corners, centre: np.ndarray, distance, clear: float,
          draws: int = 30) -> np.ndarray | None:
    """A rig position ``distance`` (a range) from the loop ``centre`` from where the lines to some of
    the loop's ``corners`` (xy) pass one of the static boxes ``screens`` ((lo, hi)) and the lines to
    others do not: the performer passes behind the object for part of each lap; ``clear`` metres
    from every screen. None when no draw fits."""
    a = rng.uniform(0, 2 * math.pi, draws)
    xy = centre[:2] + rng.uniform(*distance, draws)[:, None] * np.stack([np.cos(a), np.sin(a)], axis=1)
    lo, hi = np.array([s[0][:2] for s in screens]), np.array([s[1][:2] for s in screens])
    hidden = np.stack([_crosses(xy, np.broadcast_to(c, xy.shape), lo, hi).any(axis=1) for c in corners], axis=1)
    inside = np.any(np.all((lo[None] - clear < xy[:, None]) & (xy[:, None] < hi[None] + clear), axis=2), axis=1)
    k = np.flatnonzero(hidden.any(axis=1) & ~hidden.all(axis=1) & ~inside)
    if not len(k):
        return None
    return np.r_[xy[k[0]], centre[2] + float(rng.uniform(1.3, 2.1))]


def _crosses(a: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(N, M) bool: whether segment a[i]..b[i] (xy, N of each) meets box lo[j]..hi[j] (xy, M of each)."""
    a, d = a[:, None, :], (b - a)[:, None, :]
    lo, hi = lo[None, :, :], hi[None, :, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - a) / d, (hi - a) / d
    inside = (lo <= a) & (a <= hi)
    t1 = np.where(d == 0, np.where(inside, -np.inf, np.inf), t1)
    t2 = np.where(d == 0, np.where(inside, np.inf, -np.inf), t2)
    near, far = np.max(np.minimum(t1, t2), axis=2), np.min(np.maximum(t1, t2), axis=2)
    return (near <= far) & (far >= 0) & (near <= 1)


def place_rigs(scene: Scene, count: int, spec_kwargs: dict, fallback, tries: int = 8, extra: int = 2) -> list[choreography.Footage] | None:
    """Add ``rig_00``... each watching a performer (round robin over ``scene.ctx.performers``).

    Candidates: 1-1.6 m beyond the rig's own half size from the performer's loop centre (mostly
    across its long axis; then 1.6-2.6 m, 2.6-3.6 m, then the other performers), 1.3-2.1 m above its
    ground, looking at its middle; or just behind a prop near the loop (:func:`_by_prop`, the prop
    0.6-0.85 m from the rig, which then needs only its own extent free); or where the lines of
    sight to part of the loop pass a static object (:func:`_peek`); or past a static object near
    the performer; or near a rig that already watches it with an occlusion. A candidate must be free
    (its box and the first metres of its line of sight) and is measured at sampled frames
    (lfusd.author.choreography.Watch). Candidates rank by (meets the goal with a margin, also at
    the frames halfway between the sampled ones if it shows an occlusion; shows an
    occlusion and a near foreground, an occlusion, a near foreground, coverage); of up to ``tries``
    free candidates the first with the first two wins, else the best; when none meets the goal,
    ``3 * tries`` more are tried, then up to ``extra`` more performers per scene are added and
    tried; when the best shows no occlusion, FOCUS_TRIES more behind props and past static
    objects. ``fallback(i)`` adds rig i the template's way when no candidate is free.
    Returns the planning measurements, or None (nothing added) without performers."""
    ctx = getattr(scene, "ctx", None)
    if ctx is None or not ctx.performers:
        return None
    first, last = int(scene.stage.GetStartTimeCode()), int(scene.stage.GetEndTimeCode())
    watch = choreography.Watch(scene.stage, first, last)
    frames = np.unique(np.linspace(first, last, min(PLAN_FRAMES, last - first + 1)).round().astype(int))
    between = np.setdiff1d((frames[:-1] + frames[1:]) // 2, frames)  # where a candidate with an occlusion is checked again
    half = max(spec_kwargs.get("rows", 9), spec_kwargs.get("cols", 9)) * spec_kwargs.get("baseline", 0.125) / 2 + 0.3
    rings = [(half + a, half + b) for a, b in RIG_RINGS]
    (bx0, by0), (bx1, by1) = scene.bounds
    rng = ctx.rng

    body = (max(spec_kwargs.get("rows", 9), spec_kwargs.get("cols", 9)) - 1) * spec_kwargs.get("baseline", 0.125) / 2 + 0.1
    near = choreography.DISPARITY_GOAL if scene.near_foreground else None
    props = _props(scene, ctx)

    def search(i, plan, tries=tries, focus=False):
        best, best_key, free = None, None, 0
        for (centre, heading, who), distance in plan:
            prop_near(ctx, rng, (), ((0, 0), (0, 0)))  # fills ctx.statics
            behind = [(lo + hi)[:2] / 2 for _, lo, hi in ctx.statics
                      if 0.5 < np.linalg.norm((lo + hi)[:2] / 2 - centre[:2]) < distance[1] - half]
            close = [p for p in props if np.linalg.norm(np.clip(centre[:2], p[1][:2], p[2][:2]) - centre[:2]) < PROP_REACH]
            good = accepted.get(id(centre), [])
            sweep = next((b for b in scene.placed if b.path == who), None)
            corners = [] if sweep is None else [np.array([x, y]) for x in (sweep.lo[0] + PERSON_RADIUS, sweep.hi[0] - PERSON_RADIUS)
                                                for y in (sweep.lo[1] + PERSON_RADIUS, sweep.hi[1] - PERSON_RADIUS)]
            screens = [(lo, hi) for label, lo, hi in ctx.statics if label not in SURFACES
                       and np.linalg.norm(np.clip(centre[:2], lo[:2], hi[:2]) - centre[:2]) < PROP_REACH]
            for _ in range(60):
                prop, clear = None, half
                if good and rng.random() < 0.3:  # near a rig that already watches this performer well
                    at0, target0 = good[int(rng.integers(len(good)))]
                    at = at0 + rng.uniform(-0.4, 0.4, 3) * [1.0, 1.0, 0.5]
                    target = target0 + rng.uniform(-0.2, 0.2, 3)
                    az = None
                elif close and rng.random() < PROP_SHARE:
                    # just behind a prop, on the far side from the performer: a near foreground (large
                    # disparity) that the performer passes behind at times (an occlusion)
                    prop = close[int(rng.integers(len(close)))]
                    at = _by_prop(rng, prop, centre, body)
                    if at is None:
                        continue
                    target = centre + [float(rng.uniform(-0.3, 0.3)), float(rng.uniform(-0.3, 0.3)), float(rng.uniform(0.6, 1.1))]
                    clear, az = body, None
                elif screens and corners and rng.random() < 0.5:
                    # the lines of sight to some corners of the loop pass a static object, to others not
                    at = _peek(rng, screens, corners, centre, distance, half)
                    if at is None:
                        continue
                    target = centre + [float(rng.uniform(-0.3, 0.3)), float(rng.uniform(-0.3, 0.3)), float(rng.uniform(0.7, 1.1))]
                    az = None
                elif focus:  # only candidates made to see an occlusion
                    continue
                elif behind and rng.random() < 0.5:
                    # the rig looks past a static object near the performer (it passes behind it at times)
                    o = behind[int(rng.integers(len(behind)))] - centre[:2]
                    az = math.atan2(o[1], o[0]) + math.radians(float(rng.uniform(-15, 15)))
                else:  # mostly across the loop's long axis, so the performer keeps its distance
                    az = math.radians(heading + (90.0 if rng.random() < 0.5 else -90.0) + float(rng.uniform(-50, 50)))
                if az is not None:
                    d = float(rng.uniform(*distance))
                    at = centre + [d * math.cos(az), d * math.sin(az), float(rng.uniform(1.3, 2.1))]
                    target = centre + [float(rng.uniform(-0.3, 0.3)), float(rng.uniform(-0.3, 0.3)), float(rng.uniform(0.7, 1.1))]
                if not (bx0 + half < at[0] < bx1 - half and by0 + half < at[1] < by1 - half):
                    continue
                dist = float(np.linalg.norm(target - at))
                # the line of sight's first metres are free (the performer's own sweep aside: a rig looking
                # along its loop sees it come near; a prop candidate may look past its prop)
                ignore = (who,) if prop is None else (who, prop[0])
                ahead = [at + (target - at) * (s / dist) for s in np.arange(clear, min(2.0, dist - 1.0), 0.25)]
                if not (scene.free(at - clear, at + clear, margin=0.0)
                        and all(scene.free(p - 0.25, p + 0.25, margin=0.0, ignore=ignore) for p in ahead)):
                    continue
                spec = RigSpec(name=f"rig_{i:02d}", at=tuple(float(v) for v in at), look_at=tuple(float(v) for v in target), **spec_kwargs)
                foot = watch.footage(spec, frames, width=PLAN_WIDTH)
                occluded = bool(foot.occluded.any())
                fore = near is None or near[0] <= foot.reference_disparity()[1] <= near[1]
                key = (foot.meets_goal(PLAN_MARGIN), occluded and fore, occluded, fore,
                       foot.in_view + foot.person_in_view + float(foot.moving.mean()))
                if key[0] and occluded and len(between) and (best_key is None or key > best_key):
                    # a static object that hides the movers at times may hide them between the sampled
                    # frames too: such a candidate, if it would lead, must also pass at the frames halfway
                    if not watch.footage(spec, between, width=PLAN_WIDTH).meets_goal(PLAN_MARGIN):
                        key = (False, *key[1:])
                if best_key is None or key > best_key:
                    best, best_key = (spec, foot, centre), key
                free += 1
                if (key[0] and key[1]) or free >= tries:
                    return best, best_key
            if best_key is not None and best_key[0]:
                break
        return best, best_key

    out = []
    accepted: dict[int, list] = {}  # performer (by its centre array) -> (at, look_at) of rigs that met the goal with an occlusion
    for i in range(count):
        n = len(ctx.performers)
        plan = [(ctx.performers[i % n], ring) for ring in rings]
        plan += [(ctx.performers[(i + k) % n], ring) for k in range(1, n) for ring in rings[:2]]
        best, best_key = search(i, plan)
        if best_key is not None and not best_key[0]:  # none passed: a wider look around the same performers
            got, got_key = search(i, plan, 3 * tries)
            if got_key is not None and got_key > best_key:
                best, best_key = got, got_key
        while (best_key is None or not best_key[0]) and extra > 0:
            extra -= 1
            if not performer(ctx):
                break
            watch.refresh()
            got, got_key = search(i, [(ctx.performers[-1], ring) for ring in rings])
            if got_key is not None and (best_key is None or got_key > best_key):
                best, best_key = got, got_key
        if best_key is not None and best_key[0] and not best_key[2]:
            # it meets the goal but shows no occlusion: a few more candidates behind props and past static
            # objects around its own performer
            got, got_key = search(i, plan[:len(rings)], FOCUS_TRIES, focus=True)
            if got_key is not None and got_key > best_key:
                best, best_key = got, got_key
        if best is None:
            fallback(i)
            continue
        add_rig(scene.stage, best[0])
        out.append(best[1])
        if best_key[0] and best_key[2]:  # rigs near it will likely see the same occlusion
            accepted.setdefault(id(best[2]), []).append((np.asarray(best[0].at), np.asarray(best[0].look_at)))
    return out
