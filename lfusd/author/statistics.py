"""Per-scene content statistics: triangles drawn, distinct assets, textured materials.

``lfusd check`` prints them in its summary line (:func:`stage_statistics`, :meth:`SceneStatistics.line`).

- triangles: every drawn gprim's triangles (fan triangulation, as lfusd's geometry and Blender
  draw them), each instance and point instance counted, at the stage's first frame;
- distinct assets: the distinct sources of the labelled objects' geometry: a catalogue asset
  (``lfusd:asset``, its content hash) counts once however often it is placed, as does the
  prototype of scene-graph instances or point instances; any other object is an asset of its own;
- textured materials: materials bound to drawn gprims whose shader network reads an image
  (a ``UsdUVTexture`` with a file).
"""

from __future__ import annotations

from dataclasses import dataclass

from pxr import Usd, UsdGeom, UsdShade

from .vocabulary import ASSET

_PROXIES = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)


@dataclass(frozen=True)
class SceneStatistics:
    objects: int
    triangles: int
    distinct_assets: int
    catalogue_assets: int
    textured_materials: int
    materials: int

    def line(self) -> str:
        return (f"{self.triangles} triangles, {self.objects} objects from {self.distinct_assets} distinct assets "
                f"({self.catalogue_assets} from catalogues), {self.textured_materials} of {self.materials} materials textured")


def _textured(material: UsdShade.Material) -> bool:
    for p in Usd.PrimRange(material.GetPrim(), _PROXIES):
        if p.IsA(UsdShade.Shader):
            shader = UsdShade.Shader(p)
            if shader.GetIdAttr().Get() == "UsdUVTexture":
                f = shader.GetInput("file")
                v = f.Get() if f else None
                if v is not None and v.path:
                    return True
    return False


def _key(mat: UsdShade.Material) -> str:
    """A material's identity: its prototype's path for one seen through an instance; its path in
    its asset for one of a catalogue asset (however often placed); else its path."""
    prim = mat.GetPrim()
    if prim.IsInstanceProxy():
        return str(prim.GetPrimInPrototype().GetPath())
    p = prim.GetParent()
    while p and not p.IsPseudoRoot():
        attr = p.GetAttribute(ASSET)
        if attr and attr.HasAuthoredValue():
            return f"{attr.Get()}:{prim.GetPath().MakeRelativePath(p.GetPath())}"
        p = p.GetParent()
    return str(prim.GetPath())


def _bound_materials(gprims) -> dict[str, UsdShade.Material]:
    out = {}
    for g in gprims:
        mats = [UsdShade.MaterialBindingAPI(g).ComputeBoundMaterial()[0]]
        mats += [UsdShade.MaterialBindingAPI(s.GetPrim()).ComputeBoundMaterial()[0]
                 for s in UsdGeom.Subset.GetAllGeomSubsets(UsdGeom.Imageable(g))]
        for m in mats:
            if m:
                out.setdefault(_key(m), m)
    return out


def textured_materials(stage: Usd.Stage) -> int:
    """How many materials bound to the stage's drawn gprims read an image texture."""
    from .labels import scene_parts

    gprims = {str(p.prim.GetPath()): p.prim for p in scene_parts(stage)}
    return sum(_textured(m) for m in _bound_materials(gprims.values()).values())


def _triangles(prim: Usd.Prim, t: Usd.TimeCode) -> int:
    if prim.IsA(UsdGeom.Cube):
        return 12
    if not prim.IsA(UsdGeom.Mesh):
        return 0
    counts = UsdGeom.Mesh(prim).GetFaceVertexCountsAttr().Get(t)
    return int(sum(max(int(c) - 2, 0) for c in counts)) if counts is not None else 0


def stage_statistics(stage: Usd.Stage) -> SceneStatistics:
    """The stage's :class:`SceneStatistics` (see the module docstring)."""
    from .labels import _Walk

    walk = _Walk(stage)
    t = Usd.TimeCode(stage.GetStartTimeCode())
    per_prim: dict[str, int] = {}
    triangles = 0
    sources: dict[str, str] = {}
    catalogue: set[str] = set()
    for part in walk.parts:
        key = str(part.prim.GetPath())
        if key not in per_prim:
            per_prim[key] = _triangles(part.prim, t)
        triangles += per_prim[key]
        if part.owner in sources:
            continue
        owner = stage.GetPrimAtPath(part.owner) if "[" not in part.owner else None
        attr = owner.GetAttribute(ASSET) if owner else None
        if attr and attr.HasAuthoredValue():
            sources[part.owner] = "asset:" + str(attr.Get())
            catalogue.add(sources[part.owner])
        elif part.placement is not None:
            sources[part.owner] = "proto:" + str(part.placement.proto_root.GetPath())
        elif owner and owner.IsInstance():
            sources[part.owner] = "proto:" + str(owner.GetPrototype().GetPath())
        else:
            sources[part.owner] = "own:" + part.owner
    mats = _bound_materials({str(p.prim.GetPath()): p.prim for p in walk.parts}.values())
    return SceneStatistics(objects=len(sources), triangles=triangles, distinct_assets=len(set(sources.values())),
                           catalogue_assets=len(catalogue), textured_materials=sum(_textured(m) for m in mats.values()),
                           materials=len(mats))
