"""A stage of scenegraph instances and (nested) PointInstancers, with its authored placements.

Layout (Z-up, metres, frames 1-3):

    /TreeProto (class, label 'tree')          Trunk, Crown (box meshes), Bushes (PointInstancer:
                                              3 instances of 2 prototypes Small / Big, label 'bush')
    /World/Forest/Tree_0..2                   instanceable references of /TreeProto; Tree_1 moves
    /World/Forest/Trees                       PointInstancer of 3 pines (prototype Pine, label
                                              'pine'), time-sampled positions; Pine holds a nested
                                              PointInstancer Cones (2 instances, label 'cone')

Everything here is closed form: :data:`TREES` etc. give each instance's translation per frame.
"""

from __future__ import annotations

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, Vt

from lfusd.author.labels import set_class_label
from lfusd.author.stage import new_stage

FRAMES = (1, 2, 3)
# Scenegraph instances: translation per frame (only Tree_1 moves).
TREES = {f"/World/Forest/Tree_{k}": (lambda f, k=k: np.array([-1.6 + 1.6 * k, 0.0 + (0.15 * (f - 1) if k == 1 else 0.0), 0.0])) for k in range(3)}
TRUNK = ((0.0, 0.0, 0.5), 0.4)  # (centre in the prototype, edge)
CROWN = ((0.0, 0.0, 1.3), 1.0)
# Bushes inside every tree: (proto index, translation in the tree's frame)
BUSHES = [(0, (0.6, -0.6, 0.1)), (1, (-0.6, -0.6, 0.15)), (0, (0.0, -0.8, 0.1))]
BUSH_SIZE = (0.2, 0.3)
# Pines of the outer PointInstancer: translation per frame (pine 2 moves)
PINES = [(lambda f, i=i: np.array([-1.2 + 1.2 * i + (0.1 * (f - 1) if i == 2 else 0.0), 3.0, 0.0])) for i in range(3)]
PINE = ((0.0, 0.0, 0.6), 0.5)
CONES = [(0.0, 0.45, 0.15), (0.0, -0.45, 0.15)]  # nested instances, in the pine's frame
CONE_SIZE = 0.3


def box_mesh(stage: Usd.Stage, path: str, centre, edge: float) -> UsdGeom.Mesh:
    """An axis-aligned box mesh with outward faces."""
    c, h = np.asarray(centre, float), edge / 2.0
    pts = [c + h * np.array([x, y, z]) for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)]
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr([Gf.Vec3f(*map(float, p)) for p in pts])
    mesh.CreateFaceVertexCountsAttr([4] * 6)
    mesh.CreateFaceVertexIndicesAttr([0, 2, 3, 1, 4, 5, 7, 6, 0, 1, 5, 4, 2, 6, 7, 3, 0, 4, 6, 2, 1, 3, 7, 5])
    return mesh


def _instancer(stage, path, protos: list[str], indices, positions_of_frame, label=None):
    pi = UsdGeom.PointInstancer.Define(stage, path)
    rel = pi.CreatePrototypesRel()
    for p in protos:
        rel.AddTarget(Sdf.Path(p))
    pi.CreateProtoIndicesAttr(Vt.IntArray(list(indices)))
    attr = pi.CreatePositionsAttr()
    for f, pos in positions_of_frame.items():
        attr.Set(Vt.Vec3fArray([Gf.Vec3f(*map(float, p)) for p in pos]), Usd.TimeCode.Default() if f is None else f)
    if label:
        set_class_label(pi.GetPrim(), label)
    return pi


def author_instances(stage: Usd.Stage, scenegraph: bool = True, points: bool = True) -> None:
    """Author the prototypes and instances described in the module docstring into ``stage``
    (``scenegraph``: the trees; ``points``: the pines)."""
    UsdGeom.Xform.Define(stage, "/World/Forest")
    if scenegraph:
        _author_trees(stage)
    if points:
        _author_pines(stage)


def _author_trees(stage: Usd.Stage) -> None:
    proto = stage.CreateClassPrim("/TreeProto")
    UsdGeom.Xform.Define(stage, "/TreeProto")
    stage.GetPrimAtPath("/TreeProto").SetSpecifier(Sdf.SpecifierClass)
    set_class_label(proto, "tree")
    box_mesh(stage, "/TreeProto/Trunk", *TRUNK)
    box_mesh(stage, "/TreeProto/Crown", *CROWN)
    UsdGeom.Scope.Define(stage, "/TreeProto/Bushes/Protos")
    box_mesh(stage, "/TreeProto/Bushes/Protos/Small", (0, 0, 0), BUSH_SIZE[0])
    box_mesh(stage, "/TreeProto/Bushes/Protos/Big", (0, 0, 0), BUSH_SIZE[1])
    _instancer(stage, "/TreeProto/Bushes", ["/TreeProto/Bushes/Protos/Small", "/TreeProto/Bushes/Protos/Big"],
               [b[0] for b in BUSHES], {None: [b[1] for b in BUSHES]}, label="bush")
    for path, pos in TREES.items():
        tree = UsdGeom.Xform.Define(stage, path)
        tree.GetPrim().GetReferences().AddInternalReference("/TreeProto")
        tree.GetPrim().SetInstanceable(True)
        op = tree.AddTranslateOp()
        if path.endswith("_1"):
            for f in FRAMES:
                op.Set(Gf.Vec3d(*pos(f)), f)
        else:
            op.Set(Gf.Vec3d(*pos(1)))


def _author_pines(stage: Usd.Stage) -> None:
    pines = _instancer(stage, "/World/Forest/Trees", ["/World/Forest/Trees/Protos/Pine"], [0, 0, 0],
                       {f: [p(f) for p in PINES] for f in FRAMES})
    UsdGeom.Scope.Define(stage, "/World/Forest/Trees/Protos")
    pine = UsdGeom.Xform.Define(stage, "/World/Forest/Trees/Protos/Pine")
    set_class_label(pine.GetPrim(), "pine")
    box_mesh(stage, "/World/Forest/Trees/Protos/Pine/Body", *PINE)
    UsdGeom.Scope.Define(stage, "/World/Forest/Trees/Protos/Pine/Cones/Protos")
    box_mesh(stage, "/World/Forest/Trees/Protos/Pine/Cones/Protos/Cone", (0, 0, 0), CONE_SIZE)
    _instancer(stage, "/World/Forest/Trees/Protos/Pine/Cones", ["/World/Forest/Trees/Protos/Pine/Cones/Protos/Cone"],
               [0, 0], {None: CONES}, label="cone")
    assert pines


def write_instances_stage(path, rig=None, ground: bool = True, scenegraph: bool = True, points: bool = True) -> Usd.Stage:
    """The stage of the module docstring (plus a ground, a sun and ``rig`` when given), saved."""
    stage = new_stage(path, FRAMES[0], FRAMES[-1])
    author_instances(stage, scenegraph, points)
    if ground:
        g = UsdGeom.Mesh.Define(stage, "/World/Ground")
        g.CreatePointsAttr([(-8, -6, 0), (8, -6, 0), (8, 10, 0), (-8, 10, 0)])
        g.CreateFaceVertexCountsAttr([4])
        g.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
        set_class_label(g.GetPrim(), "ground")
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(1.0)
    UsdGeom.XformCommonAPI(sun).SetRotate(Gf.Vec3f(30.0, 20.0, 0.0))
    if rig is not None:
        from lfusd.author.rigs import add_rig

        add_rig(stage, rig)
    stage.Save()
    return stage


def expected_objects(scenegraph: bool = True, points: bool = True) -> dict[str, tuple[str, object]]:
    """{object path: (label, translation(frame))} of every object, from the authored placements."""
    out = {}
    for tree, pos in TREES.items() if scenegraph else ():
        out[tree] = ("tree", pos)
        for j, (_, t) in enumerate(BUSHES):
            out[f"{tree}/Bushes[{j}]"] = ("bush", lambda f, pos=pos, t=t: pos(f) + np.array(t))
    for i, pos in enumerate(PINES if points else ()):
        out[f"/World/Forest/Trees[{i}]"] = ("pine", pos)
        for j, t in enumerate(CONES):
            out[f"/World/Forest/Trees[{i}]/Cones[{j}]"] = ("cone", lambda f, pos=pos, t=t: pos(f) + np.array(t))
    out["/World/Ground"] = ("ground", lambda f: np.zeros(3))
    return out
