"""Semantic placement constraints: a default rulebook keyed on class labels, rules stored in the
stage, rules from a JSON/TOML file, and their evaluation at every frame.

Rules (``kind``: value):

- ``on``: classes whose surface must support the object (ray casts down from its lowest points)
- ``not_on``: classes that must never support it
- ``floats_on``: classes of water it floats on, its lowest points ``draft`` (min, max metres) below
  the water surface
- ``no_interpenetration``: classes (``any`` = every labelled object that is not a ground or water
  surface) whose objects it must not intersect
- ``inside``: prim paths of regions whose world bounds must contain it
- ``in_bounds``: true: stay inside the stage's ``lfusd:bounds`` (default prim; min and max corner, stage coordinates),
  or inside the x/y extent of its ground and water surfaces when the stage has none

Each kind is a Checker method registered with ``@rule(kind)`` (:data:`RULES`); class names and
property names come from lfusd.author.vocabulary.

Where rules live (later ones override earlier ones, per object and kind):

1. the default rulebook (``DEFAULT_RULES``),
2. a rules file (``lfusd check --rules FILE``): ``{"rules": {"person": {"on": [...]}, "/World/Boat": {...}}}``,
   keys being class labels, ``any``, or prim paths,
3. class rules in the stage: ``token[] lfusd:rule:<class>:<kind>`` on the default prim,
4. rules of one prim: ``lfusd:constraint:<kind>`` on the object prim (a relationship for ``inside``).

An empty list (or ``false``) switches a rule off. ``draft`` (float2) and ``tolerance`` (metres
of gap or sinking allowed for support, default 0.05) are parameters, set the same ways.
Class ``any`` rules apply to every labelled object that is not a surface; the default ``any``
rule, ``no_interpenetration``, applies only to objects that move (dynamic objects).
Unlabelled geometry (an object of its own, see lfusd.author.labels) gets only rules keyed on its path.

Evaluation: at every integer frame of the stage's range; objects whose geometry cannot change
(no time-varying transform, points or skinning) are evaluated once, at the first frame, unless
something moving passes above or below them. Support is tested by ray casts (Open3D) straight
down from an object's lowest points; interpenetration by casting every mesh edge of one object
against the other (crossings within 1 mm of an end point are contact) plus a parity test for
one object wholly inside another. Each (object, rule) is reported once, at its first bad frame.
"""

from __future__ import annotations

import json
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdSkel

from ..errors import LfusdError
from ..processes import native_stderr_silenced
from .geometry import StageGeometry
from .labels import Part, object_prim, object_table
from .stage import frame_range
from .vocabulary import ANY, BOUNDS, CONSTRAINT, GROUND, RULE, SURFACES, WATER, constraint_attr, rule_attr

PARAMS = ("draft", "tolerance")

DEFAULT_RULES: dict[str, dict] = {
    "person": {"on": list(GROUND), "not_on": list(WATER), "in_bounds": True},
    "boat": {"floats_on": list(WATER), "in_bounds": True},
    "car": {"on": ["road"], "in_bounds": True},
    ANY: {"no_interpenetration": [ANY]},  # for dynamic objects only (see module docstring)
}
DEFAULT_DRAFT = (0.0, 1.5)
DEFAULT_TOLERANCE = 0.05
CONTACT_BAND = 0.02  # vertices this close to an object's lowest point are its contact points
EDGE_TOL = 1e-3  # edge crossings within 1 mm of a vertex are contact, not interpenetration
MAX_CONTACTS = 64


@dataclass(frozen=True)
class Violation:
    """One broken rule: the object, the rule, the first frame it breaks, and why."""

    prim_path: str
    rule: str
    frame: int
    detail: str

    def line(self) -> str:
        return f"{self.prim_path}: {self.rule} broken at frame {self.frame}: {self.detail}"


@dataclass
class ObjectRules:
    """The rules in force for one object after every override."""

    prim_path: str
    label: str
    rules: dict = field(default_factory=dict)
    source: dict = field(default_factory=dict)  # kind -> where it was set (for messages)


# -- the rule kinds -------------------------------------------------------------------------
@dataclass(frozen=True)
class Rule:
    """How one kind of rule is evaluated: ``check(checker, i, rules, scene, owner, frame)`` gives
    object i's violation text or None; a ``pairwise`` rule's ``check(checker, scene, owner, frame,
    is_first)`` gives the violations of every pair of objects at once."""

    kind: str
    check: Callable
    pairwise: bool = False


RULES: dict[str, Rule] = {}  # kind -> Rule, in registration order (filled by @rule on Checker's methods)


def rule(kind: str, pairwise: bool = False):
    """Decorator: register a Checker method as the evaluator of rule ``kind``."""

    def register(fn):
        if kind in RULES or kind in PARAMS:
            raise LfusdError(f"rule kind {kind!r} is taken; register the new rule under another name")
        RULES[kind] = Rule(kind, fn, pairwise)
        return fn

    return register


# -- reading rules ---------------------------------------------------------------------------
def _check_kind(kind: str, where: str) -> None:
    if kind not in RULES and kind not in PARAMS:
        raise LfusdError(f"unknown rule {kind!r} in {where}; known rules: {', '.join((*RULES, *PARAMS))}")


def _normalise(kind: str, value, where: str):
    """Validate one rule value; returns it in canonical form."""
    if kind == "in_bounds":
        return bool(value)
    if kind in ("draft",):
        v = [float(x) for x in value]
        if len(v) != 2 or v[0] > v[1]:
            raise LfusdError(f"draft in {where} must be [min, max] metres with min <= max, got {list(value)}")
        return tuple(v)
    if kind == "tolerance":
        return float(value)
    if isinstance(value, str):
        value = [value]
    return tuple(str(x) for x in value)


def load_rules_file(path: str | Path) -> dict[str, dict]:
    """Rules from a JSON or TOML file: ``{"rules": {key: {kind: value}}}`` (the top ``rules`` table optional)."""
    p = Path(path)
    if not p.is_file():
        raise LfusdError(f"rules file {p} does not exist; give a .json or .toml file")
    try:
        text = p.read_text()
        data = tomllib.loads(text) if p.suffix.lower() == ".toml" else json.loads(text)
    except (json.JSONDecodeError, tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise LfusdError(f"rules file {p} is not valid {'TOML' if p.suffix.lower() == '.toml' else 'JSON'} ({e}); fix it") from None
    data = data.get("rules", data) if isinstance(data, dict) else data
    if not isinstance(data, dict) or not all(isinstance(v, dict) for v in data.values()):
        raise LfusdError(f"rules file {p} must map class labels or prim paths to tables of rules")
    out = {}
    for key, rules in data.items():
        for kind, value in rules.items():
            _check_kind(kind, f"rules file {p} ({key})")
        out[str(key)] = {k: _normalise(k, v, f"rules file {p}") for k, v in rules.items()}
    return out


def stage_class_rules(stage: Usd.Stage) -> dict[str, dict]:
    """``lfusd:rule:<class>:<kind>`` attributes of the default prim (or of /World)."""
    prim = stage.GetDefaultPrim() or stage.GetPrimAtPath("/World")
    out: dict[str, dict] = {}
    if not prim:
        return out
    for attr in prim.GetAttributes():
        name = attr.GetName()
        if not name.startswith(RULE):
            continue
        parts = name.split(":")
        if len(parts) != 4:
            raise LfusdError(f"attribute {prim.GetPath()}.{name} is not lfusd:rule:<class>:<kind>; rename it")
        cls, kind = parts[2], parts[3]
        _check_kind(kind, f"{prim.GetPath()}.{name}")
        out.setdefault(cls, {})[kind] = _normalise(kind, attr.Get(), f"{prim.GetPath()}.{name}")
    for rel in prim.GetRelationships():
        parts = rel.GetName().split(":")
        if rel.GetName().startswith(RULE) and len(parts) == 4:
            _check_kind(parts[3], f"{prim.GetPath()}.{rel.GetName()}")
            out.setdefault(parts[2], {})[parts[3]] = tuple(str(t) for t in rel.GetTargets())
    return out


def prim_rules(prim: Usd.Prim) -> dict:
    """``lfusd:constraint:<kind>`` attributes and relationships authored on one prim."""
    out = {}
    for prop in prim.GetProperties():
        name = prop.GetName()
        if not name.startswith(CONSTRAINT):
            continue
        kind = name[len(CONSTRAINT):]
        _check_kind(kind, f"{prim.GetPath()}.{name}")
        if isinstance(prop, Usd.Relationship):
            out[kind] = tuple(str(t) for t in prop.GetTargets())
        else:
            out[kind] = _normalise(kind, prop.Get(), f"{prim.GetPath()}.{name}")
    return out


def set_constraint(prim: Usd.Prim, kind: str, value) -> None:
    """Author one rule on ``prim`` (``inside``: prim paths as a relationship)."""
    _check_kind(kind, f"set_constraint on {prim.GetPath()}")
    name = constraint_attr(kind)
    if kind == "inside":
        prim.CreateRelationship(name, custom=True).SetTargets([Sdf.Path(p) for p in ([value] if isinstance(value, str) else value)])
    else:
        _write_rule(prim, name, kind, value)


def _write_rule(prim: Usd.Prim, name: str, kind: str, value) -> None:
    """One rule value as an attribute of the type its kind takes."""
    if kind == "in_bounds":
        prim.CreateAttribute(name, Sdf.ValueTypeNames.Bool, custom=True).Set(bool(value))
    elif kind == "draft":
        prim.CreateAttribute(name, Sdf.ValueTypeNames.Float2, custom=True).Set(tuple(float(v) for v in value))
    elif kind == "tolerance":
        prim.CreateAttribute(name, Sdf.ValueTypeNames.Float, custom=True).Set(float(value))
    else:
        prim.CreateAttribute(name, Sdf.ValueTypeNames.TokenArray, custom=True).Set([value] if isinstance(value, str) else list(value))


def set_class_rule(stage: Usd.Stage, cls: str, kind: str, value) -> None:
    """Author a class rule ``lfusd:rule:<cls>:<kind>`` on the default prim."""
    _check_kind(kind, f"set_class_rule {cls}")
    prim = stage.GetDefaultPrim()
    if not prim:
        raise LfusdError("the stage has no default prim to hold class rules; set one")
    _write_rule(prim, rule_attr(cls, kind), kind, value)


def resolve_rules(stage: Usd.Stage, objects, dynamic: dict[str, bool], file_rules: dict | None = None) -> list[ObjectRules]:
    """The rules in force for every labelled object, after default < file < stage class < prim."""
    layers = [("default rulebook", DEFAULT_RULES), ("rules file", file_rules or {}), ("stage", stage_class_rules(stage))]
    paths = {o.prim_path for o in objects}
    for where, layer in layers[1:]:
        for key in layer:
            if key.startswith("/") and key not in paths:
                raise LfusdError(f"the {where} has rules for prim {key}, which is not an object of the stage; fix the path")
    out = []
    for o in objects:
        r = ObjectRules(o.prim_path, o.label)
        for where, layer in layers if o.label else ():
            # 'any' first, then the class, then the prim path: the most specific key wins.
            for key in (ANY, o.label, o.prim_path):
                if key == ANY and o.label in SURFACES:
                    continue
                for kind, value in layer.get(key, {}).items():
                    if where == "default rulebook" and key == ANY and not dynamic.get(o.prim_path):
                        continue
                    r.rules[kind], r.source[kind] = value, where
        if not o.label:  # unlabelled geometry: only rules keyed on its path apply
            for where, layer in layers[1:]:
                for kind, value in layer.get(o.prim_path, {}).items():
                    r.rules[kind], r.source[kind] = value, where
        for kind, value in prim_rules(object_prim(stage, o.prim_path)).items():
            r.rules[kind], r.source[kind] = value, "prim"
        r.rules = {k: v for k, v in r.rules.items() if v not in ((), False, None)}
        if r.rules:
            out.append(r)
    # Rules authored on a prim that is no object (e.g. on a mesh below a labelled Xform) would be ignored.
    for prim in stage.Traverse():
        if str(prim.GetPath()) not in paths and any(n.startswith(CONSTRAINT) for n in prim.GetPropertyNames()):
            raise LfusdError(f"prim {prim.GetPath()} has lfusd:constraint rules but is not an object (a labelled prim "
                             "with geometry below it); move the rules to its labelled ancestor or label it")
    return out


# -- geometry helpers ------------------------------------------------------------------------
def _time_varying(prim: Usd.Prim) -> bool:
    """True when anything that places the prim's geometry may change over time."""
    p = prim
    while p and not p.IsPseudoRoot():
        if p.IsA(UsdGeom.Xformable) and UsdGeom.Xformable(p).TransformMightBeTimeVarying():
            return True
        p = p.GetParent()
    for d in Usd.PrimRange(prim):
        if d.IsA(UsdGeom.Xformable) and UsdGeom.Xformable(d).TransformMightBeTimeVarying():
            return True
        if d.IsA(UsdGeom.PointBased) and UsdGeom.PointBased(d).GetPointsAttr().ValueMightBeTimeVarying():
            return True
        if d.HasAPI(UsdSkel.BindingAPI):
            return True
    return False


def _edges(tris: np.ndarray) -> np.ndarray:
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    return np.unique(np.sort(e, axis=1), axis=0)


@dataclass
class _Obj:
    path: str
    label: str
    gprims: list
    dynamic: bool
    verts: np.ndarray | None = None
    tris: np.ndarray | None = None
    lo: np.ndarray | None = None
    hi: np.ndarray | None = None
    contacts: np.ndarray | None = None
    rigid: list = field(default_factory=list)  # per gprim: (local vertices, triangles) or None


# -- checking --------------------------------------------------------------------------------
class Checker:
    """Evaluates the rules of one stage at every frame of its range."""

    def __init__(self, stage: Usd.Stage, file_rules: dict | None = None):
        import open3d as o3d  # heavy: only when checking

        self.o3d = o3d
        self.stage = stage
        self.geometry = StageGeometry(stage)
        objects, _ = object_table(stage)
        self.labelled = [o for o in objects if o.label]
        self.objs: list[_Obj] = []
        for o in objects:
            gprims = self.geometry.parts_of(o.prim_path)  # instance proxies and point instances too
            # A point instance (/A[i]) moves with its instancer's arrays: always re-meshed.
            self.objs.append(_Obj(o.prim_path, o.label, gprims, "[" in o.prim_path or _time_varying(object_prim(stage, o.prim_path))))
        self.index = {o.path: i for i, o in enumerate(self.objs)}
        dynamic = {o.path: o.dynamic for o in self.objs}
        self.rules = resolve_rules(stage, objects, dynamic, file_rules)
        for r in self.rules:
            for target in r.rules.get("inside", ()):
                tp = stage.GetPrimAtPath(target) if Sdf.Path.IsValidPathString(target) else None
                if not tp:
                    raise LfusdError(f"{r.prim_path}: rule 'inside' names prim {target}, which does not exist; fix the target")
        self.bounds = self._bounds()
        self.unusable: dict[str, Violation] = {}  # gprims lfusd cannot mesh, with the reason

    def _bounds(self):
        prim = self.stage.GetDefaultPrim()
        attr = prim.GetAttribute(BOUNDS) if prim else None
        if attr and attr.HasAuthoredValue():
            v = np.array(attr.Get(), float)  # stage coordinates, like everything in the stage
            return _world_box(self.geometry.frame, v[0], v[1])
        return None

    def _rigid(self, g: Usd.Prim) -> bool:
        """A gprim whose shape is fixed (only its transform may move): meshed once, moved per frame."""
        if str(g.GetPath()) in getattr(self.geometry, "_skinning", {}):
            return False
        p = g
        while p and not p.IsPseudoRoot():
            if p.HasAPI(UsdSkel.BindingAPI):
                return False
            p = p.GetParent()
        if g.IsA(UsdGeom.Mesh):
            m = UsdGeom.Mesh(g)
            attrs = (m.GetPointsAttr(), m.GetFaceVertexCountsAttr(), m.GetFaceVertexIndicesAttr())
        elif g.IsA(UsdGeom.Cube):
            attrs = (UsdGeom.Cube(g).GetSizeAttr(),)
        else:
            return False
        return not any(a.ValueMightBeTimeVarying() for a in attrs)

    def _update(self, frame: int, first: bool) -> None:
        xf = UsdGeom.XformCache(Usd.TimeCode(frame))
        world = self.geometry.frame
        for o in self.objs:
            if o.verts is not None and not o.dynamic and not first:
                continue
            if first:
                o.rigid = [None] * len(o.gprims)
            parts = []
            for k, g in enumerate(o.gprims):
                if o.rigid[k] is not None:
                    local, tris = o.rigid[k]
                    m = np.array(xf.GetLocalToWorldTransform(g), dtype=np.float64)
                    parts.append((world.points(local @ m[:3, :3] + m[3, :3]), tris))
                    continue
                if isinstance(g, Part):  # a point instance: meshed with its instance transform every frame
                    wm = self.geometry.mesh(g, frame)
                    parts.append((wm.vertices, wm.triangles))
                    continue
                if str(g.GetPath()) in self.unusable:
                    continue
                try:
                    wm = self.geometry.mesh(g, frame)
                except LfusdError as e:  # e.g. a Sphere: report it, check everything else
                    self.unusable[str(g.GetPath())] = Violation(str(g.GetPath()), "geometry", frame, str(e))
                    continue
                parts.append((wm.vertices, wm.triangles))
                if first and o.dynamic and self._rigid(g):
                    # Local points in scene units: USD's transforms act in the stage's axes and units.
                    m = np.array(xf.GetLocalToWorldTransform(g), dtype=np.float64)
                    local = (world.stage_points(wm.vertices) - m[3, :3]) @ np.linalg.inv(m[:3, :3])
                    o.rigid[k] = (local, wm.triangles)
            if parts:
                offs = np.cumsum([0] + [len(v) for v, _ in parts])[:-1]
                o.verts = np.concatenate([v for v, _ in parts])
                o.tris = np.concatenate([t + k for (_, t), k in zip(parts, offs)])
                o.lo, o.hi = o.verts.min(0), o.verts.max(0)
            else:
                o.verts, o.tris = np.zeros((0, 3)), np.zeros((0, 3), np.int64)
                o.lo, o.hi = np.full(3, np.inf), np.full(3, -np.inf)
            o.contacts = None

    def _scene(self, members: list[int]):
        scene = self.o3d.t.geometry.RaycastingScene()
        owner = []
        for i in members:
            o = self.objs[i]
            if len(o.tris):
                scene.add_triangles(o.verts.astype(np.float32), o.tris.astype(np.uint32))
                owner.append(i)
        return scene, np.array(owner, dtype=np.int64)

    def check(self, progress=None) -> list[Violation]:
        """Every violation, each at the first frame its (object, rule) breaks."""
        first, last = frame_range(self.stage)
        found: dict[tuple[str, str], Violation] = {}
        any_dynamic = any(o.dynamic for o in self.objs)
        for frame in range(first, last + 1):
            is_first = frame == first
            if not is_first and not any_dynamic:
                break
            self._update(frame, is_first)
            scene, owner = self._scene(list(range(len(self.objs))))
            self._support_cache = {}  # this frame's supports: an object's "on" and "not_on" rules cast the same rays
            self._moving = self._moving_columns()
            for r in self.rules:
                i = self.index[r.prim_path]
                o = self.objs[i]
                if not len(o.tris):
                    continue  # no geometry lfusd can read (reported as a geometry problem)
                for kind, evaluator in RULES.items():
                    if evaluator.pairwise or kind not in r.rules or (r.prim_path, kind) in found:
                        continue
                    if not is_first and not self._may_change(o, kind, r):
                        continue
                    detail = evaluator.check(self, i, r, scene, owner, frame)
                    if detail:
                        found[(r.prim_path, kind)] = Violation(r.prim_path, kind, frame, detail)
            for evaluator in RULES.values():
                if evaluator.pairwise:
                    for v in evaluator.check(self, scene, owner, frame, is_first):
                        found.setdefault((v.prim_path, v.rule), v)
            if progress:
                progress(frame)
        self._support_cache = self._moving = None
        for path, v in self.unusable.items():
            found[(path, "geometry")] = v
        return sorted(found.values(), key=lambda v: (v.frame, v.prim_path, v.rule))

    def _moving_columns(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi), (N, 2) each: the horizontal boxes of the dynamic objects now."""
        moving = [x for x in self.objs if x.dynamic]
        return (np.array([x.lo[:2] for x in moving]).reshape(-1, 2), np.array([x.hi[:2] for x in moving]).reshape(-1, 2))

    def _may_change(self, o: _Obj, kind: str, r: ObjectRules) -> bool:
        if o.dynamic:
            return True
        if kind in ("on", "not_on", "floats_on"):
            # only something moving through the column above or below it can change its support
            lo, hi = getattr(self, "_moving", None) or self._moving_columns()
            return bool(np.any(np.all(lo <= o.hi[:2], axis=1) & np.all(hi >= o.lo[:2], axis=1)))
        if kind == "inside":
            return any(self.objs[self.index[t]].dynamic for t in r.rules["inside"] if t in self.index)
        return False

    # -- support -------------------------------------------------------------------------------
    def _contacts(self, o: _Obj) -> np.ndarray:
        """Points the object rests on: its vertices within CONTACT_BAND of its lowest point, pulled
        1 cm towards their centre (a box flush with a support's edge must not straddle it), and
        the centroids of its lowest triangles."""
        if o.contacts is not None:
            return o.contacts
        z0 = o.verts[:, 2].min()
        band = o.verts[:, 2] <= z0 + CONTACT_BAND
        pts = o.verts[band]
        centre = pts.mean(0)
        d = centre[:2] - pts[:, :2]
        n = np.linalg.norm(d, axis=1, keepdims=True)
        pts = pts.copy()
        pts[:, :2] += d * np.minimum(1.0, 0.01 / np.maximum(n, 1e-9))
        low = o.tris[band[o.tris].all(axis=1)]
        if len(low):
            pts = np.concatenate([pts, o.verts[low].mean(axis=1)])
        pts = np.unique(np.round(pts, 6), axis=0)
        if len(pts) > MAX_CONTACTS:
            pts = pts[np.linspace(0, len(pts) - 1, MAX_CONTACTS).astype(int)]
        o.contacts = pts
        return pts

    def _intersections(self, origins: np.ndarray, direction, scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every hit of the rays from ``origins`` along ``direction``: (ray splits, geometry ids, distances)."""
        rays = np.zeros((len(origins), 6), np.float32)
        rays[:, :3] = origins
        rays[:, 3:] = direction
        hits = scene.list_intersections(self.o3d.core.Tensor(rays))
        return hits["ray_splits"].numpy(), hits["geometry_ids"].numpy(), hits["t_hit"].numpy()

    def _cast(self, i: int, origins: np.ndarray, direction, scene, owner) -> list[list[tuple[float, int]]]:
        """Per ray from ``origins`` along ``direction``: sorted (distance, object) hits, not on object i."""
        splits, gids, ts = self._intersections(origins, direction, scene)
        out = []
        for k in range(len(origins)):
            sel = slice(splits[k], splits[k + 1])
            out.append(sorted((float(t), int(owner[g])) for t, g in zip(ts[sel], gids[sel]) if owner[g] != i))
        return out

    def _supports(self, i: int, scene, owner, up: float):
        """For each contact point p: (class of the first surface below p + ``up`` or None, its height, p),
        ignoring the object itself."""
        cache = getattr(self, "_support_cache", None)  # set by check() for one frame's scene
        if cache is not None and (i, up) in cache:
            return cache[(i, up)]
        pts = self._contacts(self.objs[i])
        splits, gids, ts = self._intersections(pts + [0.0, 0.0, up], (0.0, 0.0, -1.0), scene)
        # the first hit of each ray that is not on object i (ties: the lower object index), as _cast's first
        ray, own = np.repeat(np.arange(len(pts)), np.diff(splits)), owner[gids]
        keep = own != i
        ray, t, own = ray[keep], ts[keep], own[keep]
        order = np.lexsort((own, t, ray))
        ray, t, own = ray[order], t[order], own[order]
        first = np.r_[True, ray[1:] != ray[:-1]] if len(ray) else np.zeros(0, bool)
        found = {int(k): (float(tk), int(j)) for k, tk, j in zip(ray[first], t[first], own[first])}
        out = []
        for k, p in enumerate(pts):
            if k not in found:
                out.append((None, None, p))
            else:
                t, j = found[k]
                out.append((self.objs[j].label, float(p[2] + up - t), p))
        if cache is not None:
            cache[(i, up)] = out
        return out

    @rule("on")
    def _rule_on(self, i, r, scene, owner, frame):
        tol = r.rules.get("tolerance", DEFAULT_TOLERANCE)
        allowed = set(r.rules["on"])
        sup = self._supports(i, scene, owner, up=max(0.3, 2 * tol))
        resting = [(lab, p[2] - h) for lab, h, p in sup if lab is not None and -tol <= p[2] - h <= tol]
        if not resting:
            below = [p[2] - h for lab, h, p in sup if lab is not None]
            if not below:
                return f"nothing below it; it needs support by {_names(allowed)}"
            gap = min(below, key=abs)
            where = f"{gap:.2f} m above" if gap > 0 else f"{-gap:.2f} m sunk into"
            return f"not supported: its lowest point is {where} the surface below; it must rest on {_names(allowed)}"
        bad = sorted({lab for lab, _ in resting if lab not in allowed})
        if bad:
            return f"supported by {_names(bad)}; it must rest on {_names(allowed)}"
        return None

    @rule("not_on")
    def _rule_not_on(self, i, r, scene, owner, frame):
        tol = r.rules.get("tolerance", DEFAULT_TOLERANCE)
        banned = set(r.rules["not_on"])
        # A banned surface as the first thing below any contact point counts, however far below
        # (standing on water, stepping off a bank over it, or sunk into it).
        sup = self._supports(i, scene, owner, up=max(0.3, 2 * tol))
        bad = sorted({lab for lab, h, p in sup if lab in banned})
        return f"supported by {_names(bad)}, which it must never stand on" if bad else None

    @rule("floats_on")
    def _rule_floats_on(self, i, r, scene, owner, frame):
        tol = r.rules.get("tolerance", DEFAULT_TOLERANCE)
        lo, hi = r.rules.get("draft", DEFAULT_DRAFT)
        water = set(r.rules["floats_on"])
        pts = self._contacts(self.objs[i])
        drafts, below = [], set()
        ups = self._cast(i, pts, (0.0, 0.0, 1.0), scene, owner)
        downs = self._cast(i, pts, (0.0, 0.0, -1.0), scene, owner)
        for p, up, down in zip(pts, ups, downs):
            wet = [t for t, j in up if self.objs[j].label in water]
            if len(wet) % 2 == 1:  # odd crossings upwards: the point is under the water surface
                drafts.append(wet[0])
            elif down and self.objs[down[0][1]].label in water and down[0][0] <= tol:
                drafts.append(-down[0][0])  # just above the water: touching it
            else:
                below.add(self.objs[down[0][1]].label if down else "")
        if below:
            found = sorted(b for b in below if b)
            return f"not in {_names(water)} (below it: {_names(found) if found else 'nothing'}); it must float"
        if min(drafts) < lo - tol or max(drafts) > hi + tol:
            return f"draft {max(drafts):.2f} m outside {lo:g}..{hi:g} m: it must float on {_names(water)}"
        return None

    # -- interpenetration ------------------------------------------------------------------------
    @rule("no_interpenetration", pairwise=True)
    def _interpenetration(self, scene, owner, frame, is_first) -> list[Violation]:
        subjects = {self.index[r.prim_path]: set(r.rules["no_interpenetration"]) for r in self.rules
                    if "no_interpenetration" in r.rules and len(self.objs[self.index[r.prim_path]].tris)}
        if not subjects:
            return []

        def targets_of(i):
            classes = subjects[i]
            return {j for j, x in enumerate(self.objs) if j != i and x.label and x.label not in SURFACES and len(x.tris)
                    and (ANY in classes or x.label in classes)}

        pairs = set()
        for i in subjects:
            for j in targets_of(i):
                if not is_first and not (self.objs[i].dynamic or self.objs[j].dynamic):
                    continue  # static pairs: once
                pairs.add((min(i, j), max(i, j)))
        if not pairs:
            return []
        boxes = {k: (self.objs[k].lo, self.objs[k].hi) for p in pairs for k in p}
        pairs = {(a, b) for a, b in pairs if np.all(boxes[a][0] < boxes[b][1] - EDGE_TOL) and np.all(boxes[b][0] < boxes[a][1] - EDGE_TOL)}
        if not pairs:
            return []
        involved = sorted({k for p in pairs for k in p})
        crossings = self._edge_crossings(involved, scene, owner)
        out = []
        for a, b in sorted(pairs):
            if (a, b) in crossings or (b, a) in crossings or self._inside(a, b, scene, owner) or self._inside(b, a, scene, owner):
                for s, t in ((a, b), (b, a)):
                    if s in subjects and t in targets_of(s):
                        out.append(Violation(self.objs[s].path, "no_interpenetration", frame, f"intersects {self.objs[t].path}"))
        return out

    def _edge_crossings(self, involved, scene, owner) -> set[tuple[int, int]]:
        """(i, j): an edge of object i crosses a surface of object j away from its end points."""
        rays, src = [], []
        for i in involved:
            o = self.objs[i]
            e = _edges(o.tris)
            a, b = o.verts[e[:, 0]], o.verts[e[:, 1]]
            rays.append(np.c_[a, b - a])
            src.append(np.full(len(e), i))
        rays = np.concatenate(rays).astype(np.float32)
        src = np.concatenate(src)
        lengths = np.linalg.norm(rays[:, 3:], axis=1)
        hits = scene.list_intersections(self.o3d.core.Tensor(rays))
        splits = hits["ray_splits"].numpy()
        ray_of_hit = np.repeat(np.arange(len(rays)), np.diff(splits))
        t = hits["t_hit"].numpy()  # in units of the edge vector: 0..1 along the edge
        other = owner[hits["geometry_ids"].numpy()]
        margin = EDGE_TOL / np.maximum(lengths[ray_of_hit], 1e-9)
        keep = (t > margin) & (t < 1.0 - margin) & (other != src[ray_of_hit])
        return {(int(s), int(o)) for s, o in zip(src[ray_of_hit][keep], other[keep])}

    def _inside(self, a: int, b: int, scene, owner) -> bool:
        """Is a vertex of object a inside closed object b (odd crossings along a fixed ray)?"""
        p = self.objs[a].verts[0]
        d = np.array([0.5377, 0.2345, 0.8101])
        ray = np.array([[*p, *d]], np.float32)
        hits = scene.list_intersections(self.o3d.core.Tensor(ray))
        n = int(np.sum(owner[hits["geometry_ids"].numpy()] == b))
        return n % 2 == 1

    # -- regions ---------------------------------------------------------------------------------
    @rule("inside")
    def _rule_inside(self, i, r, scene, owner, frame):
        o = self.objs[i]
        lo, hi = o.lo, o.hi
        for target in r.rules["inside"]:
            purposes = [UsdGeom.Tokens.default_, UsdGeom.Tokens.render, UsdGeom.Tokens.proxy, UsdGeom.Tokens.guide]
            cache = UsdGeom.BBoxCache(Usd.TimeCode(frame), purposes, useExtentsHint=False)
            box = cache.ComputeWorldBound(self.stage.GetPrimAtPath(target)).ComputeAlignedRange()
            if box.IsEmpty():
                raise LfusdError(f"{r.prim_path}: region {target} of rule 'inside' has no extent; give it geometry or an extent")
            blo, bhi = _world_box(self.geometry.frame, box.GetMin(), box.GetMax())
            if np.all(lo >= blo - 1e-6) and np.all(hi <= bhi + 1e-6):
                return None
        return f"outside {_names(r.rules['inside'])}"

    @rule("in_bounds")
    def _rule_in_bounds(self, i, r, scene, owner, frame):
        o = self.objs[i]
        if self.bounds is None:
            surf = [x for x in self.objs if x.label in SURFACES and len(x.verts)]
            if not surf:
                return None
            allv = np.concatenate([x.verts for x in surf])
            blo, bhi = allv.min(0), allv.max(0)
            blo[2], bhi[2] = -np.inf, np.inf
        else:
            blo, bhi = self.bounds
        lo, hi = o.lo, o.hi
        if np.all(lo >= blo - 1e-6) and np.all(hi <= bhi + 1e-6):
            return None
        return f"leaves the stage bounds {tuple(np.round(blo, 2))}..{tuple(np.round(bhi, 2))}"


def _world_box(world, lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """An axis-aligned box of stage coordinates as (min, max) in lfusd's world (the map turns
    axes onto axes, so the box stays axis-aligned)."""
    corners = world.points(np.array([[a, b, c] for a in (lo[0], hi[0]) for b in (lo[1], hi[1]) for c in (lo[2], hi[2])], float))
    return corners.min(0), corners.max(0)


def _names(classes) -> str:
    classes = sorted(classes)
    return ", ".join(f"'{c}'" for c in classes) if classes else "nothing"


# -- USD's own validators --------------------------------------------------------------------
SKIP_VALIDATORS = {
    # usdz packaging rules do not apply to loose .usda stages with textures beside them
    "usdUtilsValidators:PackageEncapsulationValidator",
    "usdUtilsValidators:UsdzPackageValidator",
    "usdUtilsValidators:RootPackageValidator",
    "usdUtilsValidators:FileExtensionValidator",
}


def usd_validation(stage: Usd.Stage) -> list[str]:
    """Error lines from pxr.UsdValidation's registered validators (usdchecker's engine)."""
    from pxr import UsdValidation

    registry = UsdValidation.ValidationRegistry()
    validators = [v for v in registry.GetOrLoadAllValidators() if v.GetMetadata().name not in SKIP_VALIDATORS]
    # USD also prints each problem as a multi-line TF warning on fd 2; the errors come back as
    # objects, so keep stderr to one line per problem by muting it while validating.
    with native_stderr_silenced():
        errors = UsdValidation.ValidationContext(validators).Validate(stage)
    out = []
    for e in errors:
        if e.GetType() != UsdValidation.ValidationErrorType.Error:
            continue
        sites = [str(s.GetPrim().GetPath()) for s in e.GetSites() if s.IsPrim()]
        where = sites[0] if sites else "/"
        msg = " ".join(e.GetMessage().split())
        out.append(f"{where}: usd:{e.GetValidator().GetMetadata().name} ({e.GetName()}): {msg}")
    return sorted(set(out))


# -- `lfusd check` -------------------------------------------------------------------------------
@dataclass
class StageCheck:
    """What checking a stage found (:func:`check_stage`): ``problems`` are rule violations and USD
    validation errors, one line each; ``footage`` one line per rig on what its centre view sees move."""

    stage: str
    problems: list[str]
    footage: list[str]
    labelled: int  # labelled objects
    rules: int  # rules evaluated per object set (draft and tolerance settings not counted)
    frames: tuple[int, int]
    seconds: float
    usd_validated: bool
    content: str = ""  # triangles, distinct assets, textured materials (lfusd.author.statistics)

    def summary(self) -> str:
        """One line: what was checked, the scene's content and the verdict."""
        content = f"; {self.content}" if self.content else ""
        head = (f"{self.stage}: {self.labelled} labelled objects, {self.rules} rules, frames {self.frames[0]}-{self.frames[1]}"
                f"{content} ({self.seconds:.1f} s)")
        if self.problems:
            return f"{head}: {len(self.problems)} violation{'s' if len(self.problems) != 1 else ''}"
        return f"{head}: all constraints hold" + (", USD validation clean" if self.usd_validated else "")


def check_stage(path: str | Path, rules_file: str | Path | None = None, usd: bool = True, coverage: bool = True) -> StageCheck:
    """Check the stage at ``path`` (`lfusd check`): every constraint (default rulebook, ``rules_file``,
    the stage's own rules) at every frame, USD's validators unless ``usd`` is False, and, unless
    ``coverage`` is False, per rig what its centre view sees move (:func:`lfusd.author.choreography.rig_footage`).
    A broken mesh raises LfusdError before any rule runs; implicit shapes are reported as problems."""
    import logging
    import time

    from .stage import open_stage

    t0 = time.perf_counter()
    stage = open_stage(path)
    from .geometry import check_geometry

    check_geometry(StageGeometry(stage), implicit=False)
    checker = Checker(stage, load_rules_file(rules_file) if rules_file else None)
    if not checker.labelled:
        logging.getLogger(__name__).warning("stage %s has no class labels (UsdSemantics LabelsAPI, taxonomy 'class'); "
                                            "the label rulebook cannot apply, checking the rest", path)
    problems = [v.line() for v in checker.check()]
    if usd:
        problems += usd_validation(stage)
    footage = []
    if coverage:
        from .choreography import rig_footage

        footage = [f.line() for f in rig_footage(stage).values()]
    from .statistics import stage_statistics

    content = stage_statistics(stage).line()
    n_rules = sum(len([k for k in r.rules if k not in ("draft", "tolerance")]) for r in checker.rules)
    return StageCheck(str(path), problems, footage, len(checker.labelled), n_rules, frame_range(stage),
                      time.perf_counter() - t0, usd, content)
