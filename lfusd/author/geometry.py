"""World-space triangle meshes of a stage at a time code, built with pxr alone (no Blender).

This is the independent geometry that constraint checks and ground-truth verification use:
mesh points (skinned with UsdSkel where bound to a skeleton) transformed to world space in
metres and triangulated. Cubes are meshed exactly; other implicit shapes are refused, since
Blender tessellates them in its own way (author them as meshes).

Skinning follows UsdSkel's linear blend skinning: ``UsdSkel.SkinningQuery.ComputeSkinnedPoints``
gives points in the skeleton's space (the mesh's geomBindTransform already applied, the mesh's
own transform ignored), and the skeleton's local-to-world transform takes them to world space.
Rigidly deformed meshes (constant joint influences) use ``ComputeSkinnedTransform``. Blend
shapes are not applied (lfusd refuses meshes that have them).
"""

from __future__ import annotations

import logging
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from pxr import Usd, UsdGeom, UsdSkel, Vt

from ..errors import LfusdError
from .labels import Part, Resolver, renderable_gprims, scene_parts
from .stage import world_frame

log = logging.getLogger(__name__)
_WARNED_SUBDIVISION: set[tuple[str, ...]] = set()

_CUBE_FACES = np.array([[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]])


@dataclass
class WorldMesh:
    """One gprim at one time: world-space vertices (N,3, metres) and triangles (M,3) into them."""

    prim_path: str
    vertices: np.ndarray
    triangles: np.ndarray


def triangulate(counts: np.ndarray, indices: np.ndarray, points: np.ndarray | None = None, left_handed: bool = False) -> np.ndarray:
    """Triangulate polygons given USD faceVertexCounts / faceVertexIndices as Blender does (bpy 5.0,
    measured on bent, concave and left-handed quads): a ``left_handed`` mesh's faces are reversed
    (the importer's winding), then each face is a fan from its first corner, except a quad whose
    diagonal 0-2 lies outside it (corners 1 and 3 on one side of it, Blender's
    is_quad_flip_v3_first_third_fast; needs ``points``), which is split along 1-3. A non-planar
    quad's surface therefore follows its first corner, not its shorter diagonal. A face of 5 or
    more corners (with ``points``) is ear-clipped as Blender's polyfill does (:func:`_polyfill`);
    without ``points``, every face is a fan."""
    counts = np.asarray(counts, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    # A stage's meshes are triangulated again at every time verify traces, mostly with the same
    # points (static meshes): the same input gives the same triangles, kept by digest.
    import xxhash

    h = xxhash.xxh3_128()
    for a in (counts, indices, np.asarray(points, np.float64) if points is not None else np.zeros(0), np.array([left_handed])):
        h.update(np.ascontiguousarray(a).tobytes())
        h.update(b"|")
    key = h.digest()
    if key in _TRIANGULATED:
        _TRIANGULATED.move_to_end(key)
        return _TRIANGULATED[key]
    tris = _triangulate(counts, indices, points, left_handed)
    tris.flags.writeable = False  # shared by every caller with the same input
    _TRIANGULATED[key] = tris
    if len(_TRIANGULATED) > TRIANGULATED_MAX:
        _TRIANGULATED.popitem(last=False)
    return tris


_TRIANGULATED: "OrderedDict[bytes, np.ndarray]" = OrderedDict()
TRIANGULATED_MAX = 4096  # meshes whose triangles are kept (a few scenes' worth)


def _triangulate(counts: np.ndarray, indices: np.ndarray, points: np.ndarray | None, left_handed: bool) -> np.ndarray:
    """:func:`triangulate`'s work (int64 counts and indices)."""
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    if left_handed and indices.size:
        # reverse each face's corners: position j of a face of n corners takes corner n-1-j
        face_of = np.repeat(np.arange(counts.size), counts)
        j = np.arange(indices.size) - starts[face_of]
        indices = indices[starts[face_of] + counts[face_of] - 1 - j]
    if points is not None and indices.size:
        quads = starts[counts == 4]
        if quads.size:
            P = np.asarray(points, np.float64)
            v0, v1, v2, v3 = (P[indices[quads + k]] for k in range(4))
            flip = (np.cross(v1 - v0, v2 - v0) * np.cross(v3 - v0, v2 - v0)).sum(-1) > 0
            if flip.any():  # rotate the corners by one: the fan then runs from corner 1, along 1-3
                q = quads[flip]
                indices = indices.copy()
                indices[q], indices[q + 1], indices[q + 2], indices[q + 3] = indices[q + 1], indices[q + 2], indices[q + 3], indices[q]
    tris = []
    for k in range(1, int(counts.max(initial=0)) - 1):
        sel = counts > k + 1
        s = starts[sel]
        tris.append(np.stack([indices[s], indices[s + k], indices[s + k + 1]], axis=1))
    if not tris:
        return np.zeros((0, 3), dtype=np.int64)
    # Keep each polygon's triangles together, in face order, for stable triangle ids.
    tri = np.concatenate(tris)
    face = np.concatenate([np.nonzero(counts > k + 1)[0] for k in range(1, int(counts.max()) - 1)])
    order = np.argsort(face, kind="stable")
    tri, face = tri[order], face[order]
    if points is not None:
        P = np.asarray(points, np.float64)
        first = np.concatenate([[0], np.cumsum(counts - 2)[:-1]])  # each face's first triangle
        for f in np.flatnonzero(counts >= 5):
            corners = indices[starts[f]:starts[f] + counts[f]]
            tri[first[f]:first[f] + counts[f] - 2] = corners[_polyfill(P[corners])]
    return tri


def _polyfill(P: np.ndarray) -> np.ndarray:
    """(n-2, 3) corner positions of the triangles Blender (bpy 5.0) makes of one face of n >= 5
    corners ``P`` (n, 3): its ear clipping (BLI_polyfill_calc as mesh tessellation calls it) in the
    plane of the face's Newell normal. Ears are tried first at corner 0, then, after each cut, two
    corners on along the search direction; where that corner is not convex, one further and the
    direction reverses (Blender's sweep about convex ears). An ear tip is a convex corner with no
    reflex or flat corner inside or on its triangle (any corner once none is reflex); a second pass
    accepts flat tips, then any corner not reflex. Measured with bpy 5.0: Blender's loop triangles
    of 448 random star-shaped, mostly concave, non-planar faces of 5-12 corners (right- and
    left-handed) and of convex, L, star and folded faces are these
    (tests/author/test_triangulation.py)."""
    n = len(P)
    P = np.asarray(P, np.float64)
    a, b = np.roll(P, 1, axis=0), P  # Newell's normal: the plane Blender projects the face onto
    normal = np.array([((a[:, 1] - b[:, 1]) * (a[:, 2] + b[:, 2])).sum(), ((a[:, 2] - b[:, 2]) * (a[:, 0] + b[:, 0])).sum(),
                       ((a[:, 0] - b[:, 0]) * (a[:, 1] + b[:, 1])).sum()])
    if not normal.any():
        normal = np.array([0.0, 0.0, 1.0])
    # coordinates in the face's plane, on axes (e1, e2) with e1 x e2 along the normal: the sign
    # of a projected triangle's area is that of its 3D cross product along the normal
    e1 = np.cross(normal, np.eye(3)[int(np.argmin(np.abs(normal)))])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal / np.linalg.norm(normal), e1)
    X, Y = (P @ e1).tolist(), (P @ e2).tolist()

    def sign(a: int, b: int, c: int) -> int:
        s = (X[b] - X[a]) * (Y[c] - Y[a]) - (Y[b] - Y[a]) * (X[c] - X[a])
        return 1 if s > 0 else (0 if s == 0 else -1)

    nxt = [(i + 1) % n for i in range(n)]
    prv = [(i - 1) % n for i in range(n)]
    sg = [sign(prv[i], i, nxt[i]) for i in range(n)]
    alive = n
    concave = sum(s != 1 for s in sg)

    def tip_ok(e: int, accept: int) -> bool:
        if concave == 0:
            return True
        if sg[e] != accept:
            return False
        a, b, c = prv[e], e, nxt[e]
        q = nxt[c]
        while q != a:  # a reflex or flat corner inside or on the ear's triangle spoils it
            if sg[q] != 1 and sign(a, b, q) >= 0 and sign(b, c, q) >= 0 and sign(c, a, q) >= 0:
                return False
            q = nxt[q]
        return True

    def find(init: int, reverse: bool) -> int:
        for accept in (1, 0):
            e = init
            for _ in range(alive):
                if tip_ok(e, accept):
                    return e
                e = prv[e] if reverse else nxt[e]
        e = init  # degenerate: any corner that is not reflex
        for _ in range(alive):
            if sg[e] != -1:
                return e
            e = nxt[e]
        return e

    out = []
    init, reverse, head = 0, False, 0
    while alive > 3:
        e = find(init, reverse)
        if sg[e] != 1:
            concave -= 1
        a, c = prv[e], nxt[e]
        out.append((a, e, c))
        nxt[a], prv[c] = c, a
        head = c if e == head else head
        alive -= 1
        for m in (a, c):
            if sg[m] != 1:
                sg[m] = sign(prv[m], m, nxt[m])
                concave -= sg[m] == 1
        init = prv[a] if reverse else nxt[c]
        if sg[init] != 1:
            init = prv[init] if reverse else nxt[init]
            reverse = not reverse
    out.append((head, nxt[head], nxt[nxt[head]]))
    return np.array(out, np.int64)


def _transform(points: np.ndarray, matrix) -> np.ndarray:
    m = np.array(matrix, dtype=np.float64)  # USD: row vectors, p' = p @ M
    return points @ m[:3, :3] + m[3, :3]


def _unsupported(prim: Usd.Prim) -> LfusdError:
    return LfusdError(
        f"prim {prim.GetPath()} is a {prim.GetTypeName()}; lfusd needs Mesh or Cube geometry (Blender tessellates other "
        "implicit shapes its own way): convert it to a Mesh"
    )


def subdivision_surfaces(gprims) -> list[str]:
    """Paths of the Mesh prims among ``gprims`` that author a subdivisionScheme other than
    ``none`` (catmullClark, loop, bilinear): they are drawn as their control cage, both by
    Blender's USD import (lfusd leaves its ``import_subdivision`` off) and by this module. An
    unauthored scheme (USD's fallback is catmullClark) is read as a polygon mesh, as converters
    that leave it out mean it."""
    out = []
    for prim in gprims:
        if prim.IsA(UsdGeom.Mesh):
            attr = UsdGeom.Mesh(prim).GetSubdivisionSchemeAttr()
            if attr.HasAuthoredValue() and attr.Get() != UsdGeom.Tokens.none:
                out.append(str(prim.GetPath()))
    return out


def warn_subdivision(stage: Usd.Stage, gprims) -> None:
    """Log, once per stage and process, one warning naming the subdivision surfaces of
    :func:`subdivision_surfaces`: renders and ground truth show their control cages."""
    found = subdivision_surfaces(gprims)
    key = (stage.GetRootLayer().identifier, *found)
    if not found or key in _WARNED_SUBDIVISION:
        return
    _WARNED_SUBDIVISION.add(key)
    scheme = UsdGeom.Mesh(stage.GetPrimAtPath(found[0])).GetSubdivisionSchemeAttr().Get()
    more = f" (as do {len(found) - 1} more meshes)" if len(found) > 1 else ""
    log.warning("mesh %s has subdivisionScheme %s%s: lfusd renders and verifies its control cage, not the smooth limit "
                "surface; subdivide it into polygons, or author subdivisionScheme = \"none\" to accept the cage",
                found[0], scheme, more)
def check_mesh(path: str, points: np.ndarray, counts, indices, time: float | None = None) -> None:
    """Refuse, in one line naming the prim, a mesh that cannot be drawn or ray cast as authored: a face
    of fewer than 3 vertices, face counts that do not add up to the indices, an index outside the
    points, or a point that is not finite."""
    at = f" at frame {time:g}" if time is not None else ""
    counts = np.asarray(counts if counts is not None else [], dtype=np.int64)
    indices = np.asarray(indices if indices is not None else [], dtype=np.int64)
    if counts.size and counts.min() < 3:
        k = int(np.argmax(counts < 3))
        raise LfusdError(f"mesh {path} has a degenerate face (face {k} has {int(counts[k])} vertices){at}; "
                         "remove faces of fewer than 3 vertices")
    if int(counts.sum()) != indices.size:
        raise LfusdError(f"mesh {path}'s faceVertexCounts add up to {int(counts.sum())} but it has {indices.size} "
                         f"faceVertexIndices{at}; fix its topology")
    if indices.size and (indices.min() < 0 or indices.max() >= len(points)):
        bad = int(indices[(indices < 0) | (indices >= len(points))][0])
        raise LfusdError(f"mesh {path} has a face index {bad} outside its {len(points)} points{at}; fix its faceVertexIndices")
    if not np.isfinite(points).all():
        raise LfusdError(f"mesh {path} has non-finite points (NaN or inf){at}; fix its points")


def _mesh_arrays(prim: Usd.Prim, t: Usd.TimeCode) -> tuple[np.ndarray, np.ndarray]:
    """(points in the mesh's own space, triangles) of a Mesh prim, checked by :func:`check_mesh`."""
    mesh = UsdGeom.Mesh(prim)
    path = str(prim.GetPath())
    pts = mesh.GetPointsAttr().Get(t)
    if pts is None:
        raise LfusdError(f"mesh {path} has no points; author its points attribute")
    pts = np.array(pts, dtype=np.float64).reshape(-1, 3)
    counts, indices = mesh.GetFaceVertexCountsAttr().Get(t), mesh.GetFaceVertexIndicesAttr().Get(t)
    check_mesh(path, pts, counts, indices, None if t.IsDefault() else t.GetValue())
    left = mesh.GetOrientationAttr().Get(t) == UsdGeom.Tokens.leftHanded
    return pts, triangulate(counts if counts is not None else [], indices if indices is not None else [], pts, left)


# Implicit shapes Blender's USD importer tessellates in its own way (Cube alone is meshed exactly, by
# both sides): refused everywhere, with one line naming the prim.
IMPLICIT_SHAPES = frozenset({"Sphere", "Cylinder", "Cylinder_1", "Cone", "Capsule", "Capsule_1", "Plane"})


def check_transforms(stage: Usd.Stage) -> None:
    """Refuse, in one line naming the prim, a transform that is not finite (NaN or inf) at its default
    or at any authored time sample: every xform op of every prim (prototypes of instances included:
    their ops are those of every instance), and point instancers' positions, orientations and scales.
    Blender renders such a stage, and the ground truth of that frame cannot be made."""
    prims = list(stage.Traverse())
    for proto in stage.GetPrototypes():
        prims += list(Usd.PrimRange(proto))
    for prim in prims:
        ops = UsdGeom.Xformable(prim).GetOrderedXformOps() if prim.IsA(UsdGeom.Xformable) else []
        for op in ops:
            attr = op.GetAttr()
            for t in [Usd.TimeCode.Default(), *map(Usd.TimeCode, attr.GetTimeSamples())]:
                if attr.Get(t) is not None and not np.isfinite(np.array(op.GetOpTransform(t), dtype=np.float64)).all():
                    raise _not_finite(prim, op.GetOpName(), t)
        if prim.IsA(UsdGeom.PointInstancer):
            pi = UsdGeom.PointInstancer(prim)
            for attr in (pi.GetPositionsAttr(), pi.GetOrientationsAttr(), pi.GetScalesAttr()):
                for t in [Usd.TimeCode.Default(), *map(Usd.TimeCode, attr.GetTimeSamples())]:
                    v = attr.Get(t)
                    if v is not None and len(v) and not np.isfinite(_floats(v)).all():
                        raise _not_finite(prim, attr.GetName(), t)


def _floats(v) -> np.ndarray:
    """An array attribute's values as floats (quaternions as their four components)."""
    try:
        return np.array(v, dtype=np.float64)
    except (TypeError, ValueError):
        return np.array([[q.GetReal(), *q.GetImaginary()] for q in v], dtype=np.float64)


def _not_finite(prim: Usd.Prim, what: str, t: Usd.TimeCode) -> LfusdError:
    at = "its default value" if t.IsDefault() else f"frame {t.GetValue():g}"
    return LfusdError(f"{prim.GetPath()} has a transform that is not finite (NaN or inf in {what} at {at}); "
                      "fix that value in the stage")


def check_geometry(geometry: "StageGeometry", implicit: bool = True) -> None:
    """Refuse, before anything is written, a stage whose drawn geometry lfusd cannot render and verify
    alike: a transform that is not finite (:func:`check_transforms`); an implicit shape
    (:data:`IMPLICIT_SHAPES`), instance proxies and point instances' prototypes included
    (``implicit=False``: skip them); or a mesh :func:`check_mesh` refuses, at its default and every
    authored time sample. Other gprims are left as before (the render worker warns about those
    Blender does not import)."""
    check_transforms(geometry.stage)
    seen: set[str] = set()
    for part in geometry.parts:
        prim = part.prim
        key = str(prim.GetPath())
        if key in seen:
            continue
        seen.add(key)
        if prim.IsA(UsdGeom.Cube):
            continue
        if not prim.IsA(UsdGeom.Mesh):
            if implicit and prim.GetTypeName() in IMPLICIT_SHAPES:
                raise _unsupported(prim)
            continue
        mesh = UsdGeom.Mesh(prim)
        times = sorted(set(mesh.GetPointsAttr().GetTimeSamples()) | set(mesh.GetFaceVertexIndicesAttr().GetTimeSamples())
                       | set(mesh.GetFaceVertexCountsAttr().GetTimeSamples()))
        # the default where nothing is animated, else every sample (a time sample hides the default)
        for t in [Usd.TimeCode(x) for x in times] or [Usd.TimeCode.Default()]:
            _mesh_arrays(prim, t)
    check_divergence(geometry)


WEIGHT_TOL = 1e-3  # |sum of a point's skin weights - 1| above this: Blender and UsdSkel skin it differently
SHEAR_TOL = 1e-5  # cosine between two axes of an instance's transform above this: a shear


def check_divergence(geometry: "StageGeometry") -> None:
    """Refuse, in one line naming the prim, what Blender renders otherwise than USD (and so than the
    ground truth and verify) defines it (issue 37): skin weights that do not sum to 1 (Blender
    normalises them, UsdSkel does not), a PointInstancer's velocities, accelerations or angular
    velocities (USD moves its instances by them between samples, Blender ignores them) and an
    instance (point instance or scenegraph instance) whose transform is sheared (Blender's
    instancing keeps only rotation and scale)."""
    for path, (skin, _) in geometry._skinning.items():
        indices, weights = skin.ComputeJointInfluences(Usd.TimeCode.EarliestTime()) or (None, None)
        n = skin.GetNumInfluencesPerComponent()
        if weights is None or not n:
            continue
        sums = np.asarray(weights, np.float64).reshape(-1, n).sum(1)
        bad = np.flatnonzero(np.abs(sums - 1) > WEIGHT_TOL)
        if bad.size:
            raise LfusdError(f"mesh {path}'s skin weights sum to {sums[bad[0]]:.3g} at point {int(bad[0])} (and {bad.size - 1} more), "
                             "not 1: Blender normalises them, UsdSkel does not; normalise its primvars:skel:jointWeights")
    instancers: dict[str, Usd.Prim] = {}
    first = geometry.stage.GetStartTimeCode() if geometry.stage.HasAuthoredTimeCodeRange() else 0.0
    res = geometry.resolver(first)
    sheared = None
    for part in geometry.parts:
        place = part.placement
        while place is not None:
            instancers.setdefault(str(place.instancer.GetPath()), place.instancer)
            place = place.outer
        if sheared is None and (part.placement is not None or part.prim.IsInstanceProxy()):
            rows = res.part(part)[:3, :3]
            rows = rows / np.linalg.norm(rows, axis=1, keepdims=True)
            cos = np.abs(rows @ rows.T - np.eye(3)).max()
            if cos > SHEAR_TOL:
                sheared = (part.path, cos)
    for path, prim in instancers.items():
        inst = UsdGeom.PointInstancer(prim)
        for name, attr in (("velocities", inst.GetVelocitiesAttr()), ("accelerations", inst.GetAccelerationsAttr()),
                           ("angularVelocities", inst.GetAngularVelocitiesAttr())):
            if attr and attr.HasAuthoredValue() and any(len(attr.Get(t) or []) for t in (attr.GetTimeSamples() or [Usd.TimeCode.Default()])):
                raise LfusdError(f"PointInstancer {path} has {name}, which Blender ignores and USD moves its instances by; "
                                 f"remove them and author its positions and orientations at every frame")
    if sheared is not None:
        raise LfusdError(f"instance {sheared[0]} has a sheared transform (axes {90 - np.degrees(np.arccos(min(1.0, sheared[1]))):.3g} degrees "
                         "off square), which Blender's instancing drops; remove the shear (bake it into the prototype's points)")


class StageGeometry:
    """Evaluates every renderable gprim of a stage at any time code (caches skeleton bindings).

    ``gprims``: the stage's own gprims (``stage.Traverse()``); ``parts``: everything drawn,
    instance proxies and every point instance's prototype gprims included
    (:func:`lfusd.author.labels.scene_parts`), which :meth:`meshes` returns."""

    def __init__(self, stage: Usd.Stage):
        self.stage = stage
        self.frame = world_frame(stage)
        self.gprims = renderable_gprims(stage)
        self.parts = scene_parts(stage)
        warn_subdivision(stage, list({str(p.prim.GetPath()): p.prim for p in self.parts}.values()))
        self._resolver: Resolver | None = None
        self._skel_cache = UsdSkel.Cache()
        self._skinning: dict[str, tuple[UsdSkel.SkinningQuery, UsdSkel.SkeletonQuery]] = {}
        for root in (p for p in stage.Traverse() if p.IsA(UsdSkel.Root)):
            self._skel_cache.Populate(UsdSkel.Root(root), Usd.TraverseInstanceProxies())
            for binding in self._skel_cache.ComputeSkelBindings(UsdSkel.Root(root), Usd.TraverseInstanceProxies()):
                skel_query = self._skel_cache.GetSkelQuery(binding.GetSkeleton())
                for target in binding.GetSkinningTargets():
                    self._skinning[str(target.GetPrim().GetPath())] = (target, skel_query)

    def is_skinned(self, prim_path: str) -> bool:
        """True when the gprim is deformed by a UsdSkel skeleton."""
        return prim_path in self._skinning

    def parts_of(self, owner: str) -> list:
        """The drawn gprims of one object (by its path): prims (instance proxies included), and
        :class:`~lfusd.author.labels.Part` for point instances, which have no prim of their own."""
        if not hasattr(self, "_by_owner"):
            self._by_owner: dict[str, list] = {}
            for p in self.parts:
                self._by_owner.setdefault(p.owner, []).append(p.prim if p.placement is None else p)
        return self._by_owner.get(owner, [])

    def resolver(self, time: float) -> Resolver:
        """Transforms at ``time`` (cached until another time is asked for)."""
        if self._resolver is None or self._resolver.time != Usd.TimeCode(time):
            self._resolver = Resolver(time)
        return self._resolver

    def mesh(self, prim: Usd.Prim | Part, time: float) -> WorldMesh:
        """World-space mesh of one gprim (or part) at ``time``."""
        if isinstance(prim, Part):
            if prim.placement is None:
                m = self.mesh(prim.prim, time)
                return WorldMesh(prim.path, m.vertices, m.triangles)
            pts, tris = self.local(prim.prim, time)
            return WorldMesh(prim.path, self.frame.points(_transform(pts, self.resolver(time).part(prim))), tris)
        t = Usd.TimeCode(time)
        path = str(prim.GetPath())
        xf = UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(t)
        if prim.IsA(UsdGeom.Mesh):
            pts, tris = _mesh_arrays(prim, t)
            if path in self._skinning:
                skinned = self._skinned(path, pts, t, time)
                # Blender splits the deformed quads: the concave test on the skinned points
                mesh = UsdGeom.Mesh(prim)
                tris = triangulate(mesh.GetFaceVertexCountsAttr().Get(t), mesh.GetFaceVertexIndicesAttr().Get(t), skinned,
                                   mesh.GetOrientationAttr().Get(t) == UsdGeom.Tokens.leftHanded)
                return WorldMesh(path, skinned, tris)
            return WorldMesh(path, self.frame.points(_transform(pts, xf)), tris)
        if prim.IsA(UsdGeom.Cube):
            size = UsdGeom.Cube(prim).GetSizeAttr().Get(t)
            corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * (size / 2.0)
            tris = triangulate(np.full(6, 4), _CUBE_FACES.ravel())
            return WorldMesh(path, self.frame.points(_transform(corners, xf)), tris)
        raise _unsupported(prim)

    def local(self, prim: Usd.Prim, time: float) -> tuple[np.ndarray, np.ndarray]:
        """(points in the gprim's own space, triangles): what a point instance places (no skinning)."""
        t = Usd.TimeCode(time)
        path = str(prim.GetPath())
        if path in self._skinning:
            raise LfusdError(f"skinned mesh {path} is a PointInstancer prototype, which lfusd does not evaluate; bake it")
        if prim.IsA(UsdGeom.Mesh):
            return _mesh_arrays(prim, t)
        if prim.IsA(UsdGeom.Cube):
            size = UsdGeom.Cube(prim).GetSizeAttr().Get(t)
            corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * (size / 2.0)
            return corners, triangulate(np.full(6, 4), _CUBE_FACES.ravel())
        raise _unsupported(prim)

    def _skinned(self, path: str, pts: np.ndarray, t: Usd.TimeCode, time: float) -> np.ndarray:
        skin, skel_query = self._skinning[path]
        if skin.HasBlendShapes():
            raise LfusdError(f"mesh {path} has UsdSkel blend shapes, which lfusd does not evaluate; bake them into its points")
        xforms = skel_query.ComputeSkinningTransforms(t)
        if skin.IsRigidlyDeformed():
            # Constant influences: one rigid skel-space transform for the whole mesh.
            m = skin.ComputeSkinnedTransform(xforms, t)
            if m is None:
                raise LfusdError(f"UsdSkel could not skin {path} at frame {time:g}; check its joint indices and weights")
            skel_pts = _transform(pts, m)
        else:
            points = Vt.Vec3fArray.FromNumpy(pts.astype(np.float32))
            if not skin.ComputeSkinnedPoints(xforms, points, t):
                raise LfusdError(f"UsdSkel could not skin {path} at frame {time:g}; check its joint indices and weights")
            skel_pts = np.array(points, dtype=np.float64)
        # Skinned points are in the skeleton's space; the skeleton's world transform applies.
        skel_xf = UsdGeom.Xformable(skel_query.GetPrim()).ComputeLocalToWorldTransform(t)
        return self.frame.points(_transform(skel_pts, skel_xf))

    def visible(self, prim: Usd.Prim | Part, time: float) -> bool:
        """False when the gprim (or an ancestor, or for a part an instancer or its invisibleIds) is
        invisible at ``time``: Blender does not render it."""
        t = Usd.TimeCode(time)
        if isinstance(prim, Part):
            place, res = prim.placement, self.resolver(time)
            while place is not None:
                if not res.shown(place):
                    return False
                place = place.outer
            prim = prim.prim
        return UsdGeom.Imageable(prim).ComputeVisibility(t) != UsdGeom.Tokens.invisible

    def meshes(self, time: float) -> list[WorldMesh]:
        """Every part (:attr:`parts`) at ``time``; a prototype gprim is read once for all its instances."""
        local: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        res = self.resolver(time)
        out = []
        for part in self.parts:
            if part.placement is None:
                out.append(self.mesh(part, time))
                continue
            key = str(part.prim.GetPath())
            if key not in local:
                local[key] = self.local(part.prim, time)
            pts, tris = local[key]
            out.append(WorldMesh(part.path, self.frame.points(_transform(pts, res.part(part))), tris))
        return out


def render_instances(geometry: StageGeometry, objects, frame: float) -> tuple[dict[str, int], list[list]]:
    """What a render worker needs to give every drawn gprim its object's id: ({gprim path: id} for
    plain gprims, [[anchor prim path, id, vertex count, centroid x, y, z, part path], ...] for
    instanced ones). Blender draws an instanced gprim as a copy under its anchor (the outermost
    instance prim or PointInstancer); the centroid of its points in the anchor's own space at
    ``frame`` tells the copies apart, independent of how the importer maps the stage's axes."""
    id_of = {m: o.instance_id for o in objects for m in o.mesh_paths}
    plain: dict[str, int] = {}
    instanced: list[list] = []
    res = geometry.resolver(frame)
    anchors: dict[str, np.ndarray] = {}
    local: dict[str, np.ndarray] = {}
    for part in geometry.parts:
        iid = id_of.get(part.path)
        if iid is None:
            continue
        if not part.anchor:
            plain[part.path] = iid
            continue
        if part.anchor not in anchors:
            anchors[part.anchor] = np.linalg.inv(np.array(res.xf.GetLocalToWorldTransform(geometry.stage.GetPrimAtPath(part.anchor)), np.float64))
        key = str(part.prim.GetPath())
        if key not in local:
            local[key] = geometry.local(part.prim, frame)[0]
        pts = local[key]
        c = _transform(pts.mean(axis=0, keepdims=True), res.part(part) @ anchors[part.anchor])[0]
        instanced.append([part.anchor, iid, len(pts), *map(float, c), part.path])
    return plain, instanced


def local_to_world(stage: Usd.Stage, prim_path: str, time: float) -> np.ndarray:
    """4x4 column-vector pose of a prim at ``time`` in lfusd's world (translation in metres)."""
    return world_frame(stage).pose(UsdGeom.Xformable(stage.GetPrimAtPath(prim_path)).ComputeLocalToWorldTransform(Usd.TimeCode(time)))


__all__ = ["StageGeometry", "WorldMesh", "check_geometry", "check_transforms", "check_mesh", "triangulate", "local_to_world", "render_instances"]
