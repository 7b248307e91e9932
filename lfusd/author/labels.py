"""Semantic class labels (UsdSemantics.LabelsAPI, taxonomy ``class``) and the object table.

An *object* (one instance id) is a labelled prim that has geometry below it; geometry with
no labelled ancestor is an object of its own with the empty label (class 0, unlabelled).
Instances are objects too (docs/CONVENTIONS.md): a scenegraph instance prim (its geometry is
reached through instance proxies) unless a labelled prim inside it is nearer to the geometry,
labelled as itself or else as its labelled ancestor; every PointInstancer instance, named
``/path/to/Instancer[i]`` (nested: ``/A[i]/B[j]``), labelled as its instancer or the instancer's
labelled ancestor, else as its prototype. A catalogue asset placed in a generated stage (a child
of the default prim carrying ``lfusd:asset``, lfusd.author.catalogue) is one object, whatever it
instances or labels inside. Ids are assigned in path order (instance indices in numeric order),
so the same stage always gives the same ids.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdSemantics

from ..errors import LfusdError
from .vocabulary import ASSET

TAXONOMY = "class"


def class_labels(prim: Usd.Prim, time: Usd.TimeCode = Usd.TimeCode.Default()) -> list[str]:
    """The prim's own ``class`` labels (not inherited); empty when it has none."""
    if TAXONOMY not in UsdSemantics.LabelsAPI.GetDirectTaxonomies(prim):
        return []
    value = UsdSemantics.LabelsAPI(prim, TAXONOMY).GetLabelsAttr().Get(time)
    return [str(v) for v in value] if value else []


def class_label(prim: Usd.Prim) -> str:
    """The prim's first own ``class`` label, or '' when unlabelled."""
    labels = class_labels(prim)
    return labels[0] if labels else ""


def set_class_label(prim: Usd.Prim, *labels: str) -> None:
    """Apply LabelsAPI:class to ``prim`` with ``labels``."""
    UsdSemantics.LabelsAPI.Apply(prim, TAXONOMY).CreateLabelsAttr().Set(list(labels))


def labelled_ancestor(prim: Usd.Prim) -> Usd.Prim | None:
    """The nearest prim at or above ``prim`` that carries a class label."""
    p = prim
    while p and not p.IsPseudoRoot():
        if class_labels(p):
            return p
        p = p.GetParent()
    return None


@dataclass(frozen=True)
class ObjectEntry:
    """One instance: id, the prim that carries its identity, its class label and class id."""

    instance_id: int
    prim_path: str
    label: str
    class_id: int
    mesh_paths: tuple[str, ...]


def renderable_gprims(stage: Usd.Stage) -> list[Usd.Prim]:
    """Every active, non-guide Gprim (meshes and implicit shapes) that a renderer draws."""
    out = []
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Gprim):
            continue
        purpose = UsdGeom.Imageable(prim).ComputePurpose()
        if purpose in (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy):
            continue
        out.append(prim)
    return out




# -- instances ------------------------------------------------------------------------------
# Scenegraph instances are reached as instance proxies (real prim paths below the instance prim).
# Point instances have no prim: instance i of the PointInstancer at P is named P[i], and a prim
# inside its prototype is named P[i] + its path relative to the prototype root (so a nested
# instancer's instances are /A[i]/B[j], and /A[i] itself when B is the prototype root: /A[i][j]).

_PROXIES = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)


@dataclass(frozen=True, eq=False)
class Placement:
    """Where one point instance sits: instance ``index`` of ``instancer``, drawing ``proto_root``;
    ``outer`` is the point instance whose prototype holds the instancer (None: a stage prim)."""

    instancer: Usd.Prim
    index: int
    proto_root: Usd.Prim
    outer: "Placement | None"
    path: str  # its name, /path/to/Instancer[i]


@dataclass(frozen=True, eq=False)
class Part:
    """One drawn gprim: its name (the prim path, or a point-instance name), the prim holding its
    points, the point instance that places it (None: the prim's own world transform), its
    owner object's path and the outermost instancing prim above it (Blender's instancer; '' when
    the gprim is not instanced)."""

    path: str
    prim: Usd.Prim
    placement: Placement | None
    owner: str
    anchor: str


def _renderable(prim: Usd.Prim) -> bool:
    return prim.IsA(UsdGeom.Gprim) and UsdGeom.Imageable(prim).ComputePurpose() not in (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy)


def _rel(path: Sdf.Path, root: Sdf.Path) -> str:
    return "" if path == root else "/" + str(path.MakeRelativePath(root))


class _Walk:
    """One pass over the stage (instance proxies and point instances included): parts and objects."""

    def __init__(self, stage: Usd.Stage):
        self.stage = stage
        self.parts: list[Part] = []
        self.labels: dict[str, str] = {}  # owner path -> label
        self.placements: dict[str, Placement] = {}  # point-instance name -> placement
        self._label_cache: dict[Sdf.Path, list[str]] = {}
        instancers, gprims = [], []
        world = stage.GetDefaultPrim()
        self._has_assets = any(c.HasAttribute(ASSET) for c in (world.GetChildren() if world else []))
        it = iter(Usd.PrimRange.Stage(stage, _PROXIES))
        for prim in it:
            if prim.IsA(UsdGeom.PointInstancer):
                it.PruneChildren()  # its children are prototypes (or unreachable): drawn by instance only
                instancers.append(prim)
            elif _renderable(prim):
                gprims.append(prim)
        # Prototypes kept outside their instancer are drawn only through it (as Blender does).
        protos = {t for pi in instancers for t in UsdGeom.PointInstancer(pi).GetPrototypesRel().GetForwardedTargets()}
        for g in gprims:
            if protos and any(a in protos for a in g.GetPath().GetAncestorsRange()):
                continue
            owner = self._owner(g)
            key = str(owner.GetPath())
            if key not in self.labels:
                self.labels[key] = self._label(owner)
            anchor = self._anchor(g)
            self.parts.append(Part(str(g.GetPath()), g, None, key, anchor))
        for pi in instancers:
            whole = self._whole(pi) if self._has_assets else None
            if whole is not None:
                self.labels.setdefault(str(whole.GetPath()), self._label(whole))
            self._instances(pi, str(pi.GetPath()), None, self._anchor(pi) or str(pi.GetPath()),
                            str(whole.GetPath()) if whole else None)

    def _own(self, prim: Usd.Prim) -> list[str]:
        path = prim.GetPath()
        if path not in self._label_cache:
            self._label_cache[path] = class_labels(prim)
        return self._label_cache[path]

    def _up_label(self, prim: Usd.Prim) -> str:
        p = prim
        while p and not p.IsPseudoRoot():
            if labels := self._own(p):
                return labels[0]
            p = p.GetParent()
        return ""

    def _whole(self, prim: Usd.Prim) -> Usd.Prim | None:
        """The outermost catalogue asset (a prim with ``lfusd:asset``) at or above ``prim``, or None."""
        out, p = None, prim
        while p and not p.IsPseudoRoot():
            if p.HasAttribute(ASSET):
                out = p
            p = p.GetParent()
        return out

    def _owner(self, g: Usd.Prim) -> Usd.Prim:
        """The catalogue asset placed above ``g`` (one object, whatever it instances), else the
        nearest labelled or instance prim at or above ``g``; else ``g`` itself."""
        if self._has_assets and (whole := self._whole(g)):
            return whole
        p = g
        while p and not p.IsPseudoRoot():
            if p.IsInstance() or self._own(p):
                return p
            p = p.GetParent()
        return g

    def _label(self, owner: Usd.Prim) -> str:
        # An unlabelled instance inherits its labelled ancestor's label.
        return self._up_label(owner)

    @staticmethod
    def _anchor(prim: Usd.Prim) -> str:
        """The outermost instance prim above an instance proxy ('' for a plain prim)."""
        if not prim.IsInstanceProxy():
            return ""
        out, p = "", prim.GetParent()
        while p and not p.IsPseudoRoot():
            if p.IsInstance():
                out = str(p.GetPath())
            p = p.GetParent()
        return out

    def _proto_label(self, root: Usd.Prim) -> str:
        if labels := self._own(root):
            return labels[0]
        for p in Usd.PrimRange(root, _PROXIES):
            if labels := self._own(p):
                return labels[0]
        return ""

    def _instances(self, pi: Usd.Prim, name: str, outer: Placement | None, anchor: str, whole: str | None = None) -> None:
        """Objects and parts of every instance of PointInstancer ``pi`` (named ``name``); ``whole``:
        the catalogue asset that owns them all (None: each instance is an object)."""
        inst = UsdGeom.PointInstancer(pi)
        roots = [self.stage.GetPrimAtPath(t) for t in inst.GetPrototypesRel().GetForwardedTargets()]
        indices = inst.GetProtoIndicesAttr().Get(Usd.TimeCode.EarliestTime())
        if indices is None or not roots:
            return
        own = self._up_label(pi)
        # Per prototype: its gprims and nested instancers, relative names (walked once, reused per instance).
        content: dict[int, tuple[list[tuple[str, Usd.Prim]], list[tuple[str, Usd.Prim]], str]] = {}
        for k, root in enumerate(roots):
            gprims, nested = [], []
            it = iter(Usd.PrimRange(root, _PROXIES)) if root else iter(())
            for prim in it:
                if prim.IsA(UsdGeom.PointInstancer):
                    it.PruneChildren()
                    nested.append((_rel(prim.GetPath(), root.GetPath()), prim))
                elif _renderable(prim):
                    gprims.append((_rel(prim.GetPath(), root.GetPath()), prim))
            content[k] = (gprims, nested, own or (self._proto_label(root) if root else ""))
        for i, k in enumerate(indices):
            if not 0 <= k < len(roots) or not roots[k]:
                continue
            path = f"{name}[{i}]"
            place = Placement(pi, i, roots[k], outer, path)
            self.placements[path] = place
            gprims, nested, label = content[int(k)]
            if gprims and whole is None:
                self.labels[path] = label
            for rel, g in gprims:
                self.parts.append(Part(path + rel, g, place, whole or path, anchor))
            for rel, sub in nested:
                self._instances(sub, path + rel, place, anchor, whole)

    def objects(self) -> tuple[list[ObjectEntry], list[str]]:
        owners: dict[str, list[str]] = {}
        for p in self.parts:
            owners.setdefault(p.owner, []).append(p.path)
        classes = [""] + sorted({lab for lab in self.labels.values() if lab})
        index = {c: k for k, c in enumerate(classes)}
        objects = [
            ObjectEntry(i + 1, path, self.labels[path], index[self.labels[path]], tuple(sorted(owners[path])))
            for i, path in enumerate(sorted(owners, key=_path_key))
        ]
        return objects, classes


def _path_key(path: str) -> tuple:
    """Sort key of an object or part name: path order, with instance indices compared as numbers."""
    tokens = re.split(r"\[(\d+)\]", path)
    return tuple((tokens[j], int(tokens[j + 1]) if j + 1 < len(tokens) else -1) for j in range(0, len(tokens), 2))


def object_prim(stage: Usd.Stage, path: str) -> Usd.Prim:
    """The prim that carries an object's identity and rules: the prim at ``path``, or for a point
    instance (``/A[i]``, ``/A[i]/B[j]``) its instancer (a prototype prim when nested)."""
    m = re.fullmatch(r"(.*)\[(\d+)\](.*)", path)  # the last instance index
    if not m:
        return stage.GetPrimAtPath(path)
    head, index, rest = m.groups()
    instancer = object_prim(stage, head)
    if not rest or not instancer or not instancer.IsA(UsdGeom.PointInstancer):
        return instancer
    inst = UsdGeom.PointInstancer(instancer)
    roots = inst.GetPrototypesRel().GetForwardedTargets()
    indices = inst.GetProtoIndicesAttr().Get(Usd.TimeCode.EarliestTime())
    k = int(indices[int(index)]) if indices is not None and int(index) < len(indices) else -1
    if not 0 <= k < len(roots):
        return Usd.Prim()
    return stage.GetPrimAtPath(roots[k].AppendPath(Sdf.Path(rest.lstrip("/"))) if rest.strip("/") else roots[k])


def scene_parts(stage: Usd.Stage) -> list[Part]:
    """Every drawn gprim of the stage, instanced ones included: the stage's (and instance proxies')
    gprims in traversal order, then each PointInstancer's instances."""
    return _Walk(stage).parts


def object_table(stage: Usd.Stage) -> tuple[list[ObjectEntry], list[str]]:
    """(objects, classes): the instance table and the class names, class id = index (0 = '')."""
    return _Walk(stage).objects()


class ObjectPoses:
    """World poses of a stage's objects (prims and point instances) at any frame; walks the stage once."""

    def __init__(self, stage: Usd.Stage):
        from .stage import world_frame

        self.stage = stage
        self.world = world_frame(stage)
        self.placements = _Walk(stage).placements
        self._time: float | None = None

    def usd_matrix(self, path: str, frame: float) -> np.ndarray:
        """The object's local-to-world matrix in stage coordinates (USD row vectors)."""
        self._at(frame)
        place = self.placements.get(path)
        if place is not None:
            return self._resolver.placement(place)
        return np.array(self._resolver.xf.GetLocalToWorldTransform(self.stage.GetPrimAtPath(path)), np.float64)

    def at(self, paths, frame: float) -> dict[str, np.ndarray]:
        """{path: 4x4 column-vector world pose (metres)} of each object path at ``frame``."""
        return {p: self.world.pose(self.usd_matrix(p, frame)) for p in paths}

    def _at(self, frame: float) -> None:
        if self._time != frame:
            self._resolver, self._time = Resolver(frame), frame


class Resolver:
    """Stage-space transforms at one time code, cached: prims, point instances, parts."""

    def __init__(self, time: float):
        self.time = Usd.TimeCode(time)
        self.xf = UsdGeom.XformCache(self.time)
        self._inst: dict[Sdf.Path, np.ndarray] = {}
        self._mask: dict[Sdf.Path, np.ndarray] = {}
        self._place: dict[int, np.ndarray] = {}

    def relative(self, prim: Usd.Prim, root: Usd.Prim) -> np.ndarray:
        """Transform of ``prim`` below ``root``, root's own transform excluded (identity for root)."""
        if prim.GetPath() == root.GetPath():
            return np.eye(4)
        return np.array(self.xf.ComputeRelativeTransform(prim, root)[0], np.float64)

    def instance_transforms(self, instancer: Usd.Prim) -> np.ndarray:
        """(N,4,4) instance transforms (prototype root transform included) in the instancer's space."""
        key = instancer.GetPath()
        if key not in self._inst:
            xfs = UsdGeom.PointInstancer(instancer).ComputeInstanceTransformsAtTime(
                self.time, self.time, UsdGeom.PointInstancer.IncludeProtoXform, UsdGeom.PointInstancer.IgnoreMask)
            self._inst[key] = np.array(xfs, np.float64).reshape(-1, 4, 4)
        return self._inst[key]

    def shown(self, place: Placement) -> bool:
        """False when the point instance is in its instancer's invisibleIds / inactiveIds at this time,
        or the instancer is invisible."""
        key = place.instancer.GetPath()
        if key not in self._mask:
            inst = UsdGeom.PointInstancer(place.instancer)
            n = len(self.instance_transforms(place.instancer))
            mask = np.array(inst.ComputeMaskAtTime(self.time) or [True] * n, bool)
            if UsdGeom.Imageable(place.instancer).ComputeVisibility(self.time) == UsdGeom.Tokens.invisible:
                mask[:] = False
            self._mask[key] = mask
        mask = self._mask[key]
        return place.index < len(mask) and bool(mask[place.index])

    def placement(self, place: Placement) -> np.ndarray:
        """Stage-space local-to-world matrix of a point instance (USD row vectors)."""
        key = id(place)
        if key not in self._place:
            if place.outer is None:
                base = np.array(self.xf.GetLocalToWorldTransform(place.instancer), np.float64)
            else:
                base = self.relative(place.instancer, place.outer.proto_root) @ self.placement(place.outer)
            xfs = self.instance_transforms(place.instancer)
            if place.index >= len(xfs):
                raise LfusdError(f"PointInstancer {place.instancer.GetPath()} has fewer instances at frame {self.time.GetValue():g} "
                                 f"than at its first; lfusd needs a fixed instance count: author every instance at every frame")
            self._place[key] = xfs[place.index] @ base
        return self._place[key]

    def part(self, part: Part) -> np.ndarray:
        """Stage-space local-to-world matrix of a part's gprim."""
        if part.placement is None:
            return np.array(self.xf.GetLocalToWorldTransform(part.prim), np.float64)
        return self.relative(part.prim, part.placement.proto_root) @ self.placement(part.placement)


def object_poses(stage: Usd.Stage, paths, frame: int) -> dict[str, list]:
    """World pose (4x4, column vectors, metres) of each object path at ``frame`` (prims and point instances)."""
    return {p: m.tolist() for p, m in ObjectPoses(stage).at(paths, frame).items()}
