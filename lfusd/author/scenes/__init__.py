"""The scene library: deterministic, constraint-aware stage templates (street, river, room, mixed, things).

``generate(template, path, seed)`` writes a stage whose every labelled object satisfies the
stage's rules by construction: objects are sampled only where their support surface lies
(the surface's height is known analytically) and where their footprint is free, never moved
after a failed check. Randomness comes from one ``numpy.random.Generator`` seeded with
(seed, the template's seed key), and every double is written rounded to 1e-9
(``stage.round_layer``), so the mapping seed -> stage file is byte-identical on every run and CPU.

A template is one module of this package with a ``@template(name, seed_key=...)`` build function
(``build(scene) -> Site``) and, for ``--dynamic``, a ``@<template>.dynamic`` function adding the
movers; every module here is imported when the package is, so a new template touches only its
own module. Its seed key is its own for good: the seed of a stage never depends on which other
templates exist or in which order they were registered.
"""

from __future__ import annotations

import importlib
import logging
import os
import math
import pkgutil
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom

from ...errors import LfusdError
from ...files import atomic_write
from ...camera import RigSpec
from ..stage import new_stage, round_layer
from ..rigs import add_rig
from ..rules import set_class_rule
from ..vocabulary import ASSET, BOUNDS, DYNAMIC, LIGHTING, SEED, TEMPLATE
from .build import Builder, MeshData, box

log = logging.getLogger(__name__)

# Rules for the object kit's classes (lfusd.author.scenes.objects), which every generated stage
# adds to the default rulebook (stored as lfusd:rule:* attributes); a template adds its own.
TEMPLATE_RULES: dict[str, dict[str, list[str]]] = {
    "building": {"on": ["grass", "ground", "sidewalk", "pavement", "dirt"]},
    "tree": {"on": ["grass", "ground", "dirt"]},
    "street_light": {"on": ["sidewalk", "pavement"]},
    "bench": {"on": ["grass", "ground", "sidewalk", "pavement", "dirt"]},
    "table": {"on": ["floor"]},
    "chair": {"on": ["floor"]},
    "cabinet": {"on": ["floor"]},
    "lamp": {"on": ["floor", "table"]},
    "bowl": {"on": ["table"]},
    "wall": {"on": ["floor"]},
    "bin": {"on": ["sidewalk", "pavement", "grass", "ground"]},
    "railing": {"on": ["sidewalk", "pavement", "grass", "ground", "bridge"]},
    "shelf": {"on": ["floor"]},
    # Static things must not interpenetrate either (the default rulebook only covers dynamic ones).
    "any": {"no_interpenetration": ["any"]},
}

GAP = 0.001  # objects rest 1 mm above their support: no coplanar contact faces


@dataclass
class Placed:
    """An authored object's world axis-aligned box, for free-space tests."""

    path: str
    lo: np.ndarray
    hi: np.ndarray


@dataclass
class Scene:
    """The state of one template run: builder, random generator, occupancy, camera targets."""

    builder: Builder
    rng: np.random.Generator
    placed: list[Placed] = field(default_factory=list)
    counters: dict[str, int] = field(default_factory=dict)
    bounds: tuple[tuple[float, float], tuple[float, float]] = ((-30.0, -30.0), (30.0, 30.0))
    baseline: float = 0.125  # the rigs' baseline: the template sets it to the scene's scale
    # dynamic rig placement prefers a near foreground (per-step disparity in choreography.DISPARITY_GOAL
    # at the reference rig); indoor templates with a small baseline turn it off
    near_foreground: bool = True
    lighting: dict = field(default_factory=dict)  # the drawn lighting setup (customData lfusd:lighting)
    ctx: object = None  # the dynamic variant's state (lfusd.author.scenes.dynamic.Ctx)
    assets: dict = field(default_factory=dict)  # class -> catalogue assets drawn instead of its generator (catalogue.draw_assets)
    assets_drawn: set = field(default_factory=set)  # classes of which a catalogue asset was drawn (Scene.draw)
    assets_placed: set = field(default_factory=set)  # ... and placed (Scene.add)
    grid: tuple[int, int] = (9, 9)  # the rigs' views (rows, cols) and image size: a template may size its
    resolution: tuple[int, int] = (1024, 1024)  # baseline to a disparity range in pixels (things)

    @property
    def stage(self) -> Usd.Stage:
        return self.builder.stage

    def name(self, base: str) -> str:
        """``/World/<Base>_NN`` numbered in creation order (deterministic)."""
        n = self.counters.get(base, 0)
        self.counters[base] = n + 1
        return f"/World/{base}_{n:02d}"

    def draw(self, cls: str, make: Callable, *args, rng: np.random.Generator | None = None):
        """An object of class ``cls``: a catalogue asset of that class when the scene has any
        (drawn uniformly, one draw of the generator ``rng``, by default the scene's), else
        ``make(rng, *args)``, the procedural generator's result. An asset comes as parts ``[("asset", its box, AssetPart)]``, which
        :meth:`place` and :meth:`add` take like any kit's parts (:func:`is_asset`)."""
        rng = self.rng if rng is None else rng
        pool = self.assets.get(cls)
        if not pool:
            return make(rng, *args)
        from ..catalogue import placed_size

        asset = pool[int(rng.integers(len(pool)))]
        self.assets_drawn.add(cls)
        sx, sy, sz = placed_size(asset)
        return [("asset", box((sx, sy, sz), (0.0, 0.0, sz / 2)), AssetPart(asset))]

    def add(self, path: str, label: str | None, parts: list[tuple[str, MeshData, str]], pos=(0.0, 0.0, 0.0),
            yaw_deg: float = 0.0, roughness: dict | None = None, track: bool = True) -> str:
        """Author an object from named mesh parts (local coordinates) at ``pos`` turned ``yaw_deg``
        (a catalogue asset: a reference to it, see :func:`reference_asset`)."""
        self.builder.obj(path, label, pos, yaw_deg)
        if is_asset(parts):
            reference_asset(self.stage, self.builder.stage_path, path, parts[0][2].asset)
            self.assets_placed.add(parts[0][2].asset.cls)
        else:
            for part, data, texture in parts:
                r = (roughness or {}).get(part)  # None: the texture's finish (build.FINISHES)
                self.builder.mesh(f"{path}/{part}", data, texture, roughness=r,
                                  metallic=0.6 if part == "body" and label == "car" else None)
        if track:
            lo, hi = world_box([d for _, d, _ in parts], pos, yaw_deg)
            self.placed.append(Placed(path, lo, hi))
        return path

    def free(self, lo, hi, margin: float = 0.05, ignore: tuple[str, ...] = ()) -> bool:
        """True when the box [lo, hi] (grown by ``margin``) meets no placed object's box."""
        lo, hi = np.asarray(lo, float) - margin, np.asarray(hi, float) + margin
        if not self.placed:
            return True
        key = tuple(id(p) for p in self.placed)
        if getattr(self, "_boxes", (None,))[0] != key:  # one array of every box (rebuilt when placed changes)
            self._boxes = (key, np.array([p.lo for p in self.placed], float), np.array([p.hi for p in self.placed], float))
        _, los, his = self._boxes
        meet = np.all(lo < his, axis=1) & np.all(hi > los, axis=1)
        return not any(self.placed[k].path not in ignore for k in np.flatnonzero(meet))

    def place(self, parts: list[tuple[str, MeshData, str]], region, z: float, yaw_choices=None, tries: int = 60,
              margin: float = 0.1, ignore: tuple[str, ...] = ()) -> tuple[tuple[float, float, float], float] | None:
        """Sample a pose whose footprint lies inside ``region`` ((x0, y0), (x1, y1)) at base height ``z``
        and meets no placed object; None when none of ``tries`` samples is free."""
        datas = [d for _, d, _ in parts]
        (x0, y0), (x1, y1) = region
        for _ in range(tries):
            yaw = float(self.rng.choice(yaw_choices)) if yaw_choices is not None else float(self.rng.uniform(0, 360))
            lo, hi = world_box(datas, (0.0, 0.0, z), yaw)
            if hi[0] - lo[0] > x1 - x0 or hi[1] - lo[1] > y1 - y0:
                continue
            # sample the object's origin so that its whole footprint stays inside the region
            x = float(self.rng.uniform(x0 - lo[0], x1 - hi[0]))
            y = float(self.rng.uniform(y0 - lo[1], y1 - hi[1]))
            if self.free(lo + [x, y, 0], hi + [x, y, 0], margin, ignore):
                return (x, y, z), yaw
        return None


@dataclass(frozen=True)
class AssetPart:
    """Stands in a part's texture slot for a catalogue asset (:meth:`Scene.draw`)."""

    asset: object  # lfusd.author.catalogue.Asset


def is_asset(parts) -> bool:
    """Whether ``parts`` (a kit's parts) are a catalogue asset drawn by :meth:`Scene.draw`."""
    return isinstance(parts, list) and len(parts) == 1 and isinstance(parts[0][2], AssetPart)


def reference_asset(stage: Usd.Stage, stage_path: Path, path: str, asset) -> None:
    """Author ``<path>/Asset/Model``, a reference to the catalogue asset's default prim, under one
    transform that takes it into the object's frame (Z up, metres, grounded on its lowest point,
    centred: lfusd.author.catalogue.placement_matrix), and mark the object prim with the asset's
    content hash (``lfusd:asset``: everything below it is one object, lfusd.author.labels)."""
    from ..catalogue import placement_matrix

    file = asset.path().resolve()
    try:
        ref = os.path.relpath(file, Path(stage_path).resolve().parent)
    except ValueError:  # another drive
        ref = str(file)
    ref = ref if os.path.isabs(ref) or ref.startswith("..") else f"./{ref}"
    x = UsdGeom.Xform.Define(stage, f"{path}/Asset")
    m = placement_matrix(asset)
    x.AddTransformOp().Set(Gf.Matrix4d(*[float(v) for v in m.ravel()]))
    # the reference one level down: the asset's root keeps its own transform (a converter's turn or scale)
    stage.DefinePrim(f"{path}/Asset/Model").GetReferences().AddReference(Path(ref).as_posix(), asset.prim)
    for light in asset.lights:  # the template lights the scene
        stage.OverridePrim(f"{path}/Asset/Model/{light}").SetActive(False)
    stage.GetPrimAtPath(path).CreateAttribute(ASSET, Sdf.ValueTypeNames.String, custom=True).Set(asset.sha256)


def world_box(datas: list[MeshData], pos, yaw_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """World axis-aligned bounds of mesh parts under translate(pos) * rotateZ(yaw)."""
    pts = np.concatenate([np.asarray(d.points, float) for d in datas])
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    w = pts @ rot.T + np.asarray(pos, float)
    return w.min(0), w.max(0)


def author_rules(stage: Usd.Stage, rules: dict[str, dict[str, list[str]]]) -> None:
    """Store class rules on the default prim (``lfusd:rule:<class>:<kind>``, sorted by class and kind)."""
    for cls in sorted(rules):
        for kind in sorted(rules[cls]):
            set_class_rule(stage, cls, kind, rules[cls][kind])


@dataclass(frozen=True)
class Site:
    """What a template's build returns: where rigs stand and what they look at, each drawn from
    a generator; a template's subclass adds what its dynamic variant needs to know."""

    rig_position: Callable[[np.random.Generator], tuple]
    look_at: Callable[[np.random.Generator], tuple]


@dataclass
class Template:
    """A registered template: its build function, its seed key, the classes every stage of it
    contains (``labels``) and moves when dynamic (``movers``), and class rules of its own."""

    name: str
    seed_key: int
    build: Callable[[Scene], Site]
    labels: frozenset[str] = frozenset()
    movers: frozenset[str] = frozenset()
    rules: dict[str, dict[str, list[str]]] = field(default_factory=dict)
    animate: Callable | None = None

    def dynamic(self, fn: Callable) -> Callable:
        """Decorator: ``fn(ctx, site) -> Site | None`` adds the movers of ``--dynamic`` stages
        (lfusd.author.scenes.dynamic); a Site it returns replaces the rig samplers."""
        self.animate = fn
        return fn


TEMPLATES: dict[str, Template] = {}  # name -> template, by seed key (the registry)


def template(name: str, *, seed_key: int, labels=(), movers=(), rules: dict | None = None):
    """Decorator: register ``build(scene) -> Site`` as template ``name``; returns the Template.

    ``seed_key`` (a non-negative integer no other template has) seeds the template's generator
    with (seed, seed_key): keep it once stages exist, as their bytes depend on it."""

    def register(build: Callable[[Scene], Site]) -> Template:
        if name in TEMPLATES:
            raise LfusdError(f"template {name!r} is registered twice; give the new template another name")
        if not (isinstance(seed_key, int) and seed_key >= 0):
            raise LfusdError(f"template {name!r} has seed key {seed_key!r}; give a non-negative integer")
        taken = {t.seed_key: t.name for t in TEMPLATES.values()}
        if seed_key in taken:
            raise LfusdError(f"template {name!r} has seed key {seed_key}, which template {taken[seed_key]!r} has; "
                             "give it an unused one")
        t = Template(name, seed_key, build, frozenset(labels), frozenset(movers), dict(rules or {}))
        TEMPLATES[name] = t
        return t

    return register


def stage_rules(t: Template) -> dict[str, dict[str, list[str]]]:
    """The class rules a stage of ``t`` stores: TEMPLATE_RULES, with the template's own on top."""
    return {cls: {**TEMPLATE_RULES.get(cls, {}), **t.rules.get(cls, {})} for cls in {**TEMPLATE_RULES, **t.rules}}


def add_rigs(scene: Scene, count: int, sample_position, look_at, spec_kwargs: dict, tries: int = 200, first: int = 0) -> None:
    """Add ``rig_NN`` (NN from ``first``) placements: each at a sampled free position looking at ``look_at(rng)``."""
    half = max(spec_kwargs.get("rows", 9), spec_kwargs.get("cols", 9)) * spec_kwargs.get("baseline", 0.125) / 2 + 0.3
    for i in range(first, first + count):
        for _ in range(tries):
            at = np.asarray(sample_position(scene.rng), float)
            target = np.asarray(look_at(scene.rng), float)
            dist = float(np.linalg.norm(target - at))
            if dist < 2.0:
                continue
            # the rig's own box is free, and so is the first 2.5 m of its line of sight
            ahead = [at + (target - at) * (s / dist) for s in np.arange(half, min(2.5, dist - 1.2), 0.25)]
            if scene.free(at - half, at + half, margin=0.0) and all(scene.free(p - 0.3, p + 0.3, margin=0.0) for p in ahead):
                break
        else:
            raise LfusdError(f"found no free spot for rig_{i:02d}; use fewer --rigs")
        add_rig(scene.stage, RigSpec(name=f"rig_{i:02d}", at=tuple(float(v) for v in at),
                                     look_at=tuple(float(v) for v in target), **spec_kwargs))


def generate(template: str, path: str | Path, seed: int, frames: int = 150, rigs: int = 10,
             grid: tuple[int, int] = (9, 9), resolution: tuple[int, int] = (1024, 1024), dynamic: bool = False,
             catalogues=()) -> Usd.Stage:
    """Write the stage of ``template`` with ``seed`` to ``path`` (textures into ``path``'s textures/).

    ``dynamic``: add walking people and movers over the frame range (lfusd.author.scenes.dynamic).
    ``catalogues``: asset catalogue files (lfusd.author.catalogue) whose assets the template
    draws instead of its procedural objects of the same class."""
    t = TEMPLATES.get(template)
    if t is None:
        raise LfusdError(f"unknown template {template!r}; choose one of: {', '.join(TEMPLATES)}")
    if dynamic and t.animate is None:
        raise LfusdError(f"template {template!r} has no dynamic variant; leave out --dynamic")
    if frames < 1:
        raise LfusdError(f"--frames must be at least 1, got {frames}")
    if not 0 <= rigs <= 10:
        raise LfusdError(f"--rigs must be between 0 and 10 (rig_00..rig_09), got {rigs}")
    if seed < 0:
        raise LfusdError(f"--seed must be a non-negative integer, got {seed}")
    from ..catalogue import draw_assets

    assets = draw_assets(catalogues)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # Authored under a temporary name beside ``path`` (textures are found relative to the folder)
    # and renamed into place once saved: a killed generation leaves no half-written stage that a
    # rerun (`lfusd dataset make`) would take for the scene.
    _remove_stale_temporaries(path)
    atomic_write(path, lambda tmp: _build(t, Path(tmp), seed, frames, rigs, grid, resolution, dynamic, template, assets),
                 prefix=f".{path.stem}.{os.getpid()}-", suffix=f".tmp{path.suffix}")
    layer = Sdf.Layer.Find(str(path))
    if layer is not None:  # a stage regenerated in this process: the cached layer holds the old one
        layer.Reload(force=True)
    return Usd.Stage.Open(str(path))


def _remove_stale_temporaries(path: Path) -> None:
    """Remove the temporaries a killed generation of ``path`` left beside it, of a process no longer
    running: ``.<stem>.<pid>-<8 random>.tmp<suffix>``, and the file USD saves that one through
    (``.<stem>.<pid>-<8 random>.tmp.<6 random>``, renamed over it when whole); nothing else."""
    pattern = re.compile(rf"\.{re.escape(path.stem)}\.(\d+)-[a-z0-9_]{{8}}\.tmp(?:{re.escape(path.suffix)}|\.[A-Za-z0-9]{{6}})")
    for p in path.parent.iterdir():
        m = pattern.fullmatch(p.name)
        if m and not p.is_symlink() and p.is_file():
            try:
                os.kill(int(m[1]), 0)
            except ProcessLookupError:
                p.unlink(missing_ok=True)
            except (PermissionError, OverflowError):
                pass  # alive under another user, or no pid: not ours to remove


def _build(t, path: Path, seed: int, frames: int, rigs: int, grid, resolution, dynamic: bool, template: str,
           assets: dict | None = None) -> None:
    """Author and save the stage of template ``t`` at ``path`` (see :func:`generate`)."""
    stage = new_stage(path, 1, frames)
    UsdGeom.Scope.Define(stage, "/World/Looks")
    UsdGeom.Xform.Define(stage, "/World/Lights")
    scene = Scene(Builder(stage, path), np.random.default_rng([int(seed), t.seed_key]), assets=dict(assets or {}),
                  grid=tuple(grid), resolution=tuple(resolution))
    site = t.build(scene)
    if dynamic:
        from .dynamic import populate

        site = populate(scene, t, site, seed, rigs)
    author_rules(stage, stage_rules(t))
    (bx0, by0), (bx1, by1) = scene.bounds
    world = stage.GetDefaultPrim()
    world.CreateAttribute(BOUNDS, Sdf.ValueTypeNames.Double3Array, custom=True).Set(
        [Gf.Vec3d(bx0, by0, -100.0), Gf.Vec3d(bx1, by1, 100.0)])
    world.SetCustomDataByKey(TEMPLATE, template)
    world.SetCustomDataByKey(SEED, int(seed))
    if scene.lighting:
        world.SetCustomDataByKey(LIGHTING, scene.lighting)
    if dynamic:
        world.SetCustomDataByKey(DYNAMIC, True)
    spec_kwargs = dict(rows=grid[0], cols=grid[1], width=resolution[0], height=resolution[1], baseline=scene.baseline)
    placed = None
    if dynamic:
        from .dynamic import place_rigs

        placed = place_rigs(scene, rigs, spec_kwargs,
                            lambda i: add_rigs(scene, 1, site.rig_position, site.look_at, spec_kwargs, first=i))
    if placed is None:
        add_rigs(scene, rigs, site.rig_position, site.look_at, spec_kwargs)
    if dynamic:
        from .dynamic import finish

        finish(scene)  # the rulebook over every frame; a mover that breaks a rule goes
    _say_unplaced(scene, template)
    round_layer(stage.GetRootLayer())  # the same bytes from one seed on every CPU
    stage.GetRootLayer().Save()


def _say_unplaced(scene: Scene, template: str) -> None:
    """Warn of each catalogue class the template drew from but placed nothing of (every try
    collided or did not fit: an asset far too large, say), instead of a scene silently without it.
    People are placed by the dynamic variant's walkers, not here."""
    from ..catalogue import placed_size

    for cls, pool in sorted(scene.assets.items()):
        if cls == "person" or cls not in scene.assets_drawn or cls in scene.assets_placed:
            continue
        longest = max(max(placed_size(a)) for a in pool)
        log.warning("the %s scene has no %s: none of the catalogue's %d %s asset%s found room (the largest is %.3g m long); "
                    "check their sizes with `lfusd assets list`", template, cls, len(pool), cls, "s" if len(pool) > 1 else "", longest)


def _load_templates() -> None:
    """Import every module of this package (each template registers itself), then order the
    registry by seed key."""
    for info in pkgutil.iter_modules(__path__):
        if info.name != "dynamic":  # people and movers: heavy, imported when a dynamic stage is made
            importlib.import_module(f"{__name__}.{info.name}")
    ordered = sorted(TEMPLATES.values(), key=lambda t: t.seed_key)
    TEMPLATES.clear()
    TEMPLATES.update((t.name, t) for t in ordered)


_load_templates()
