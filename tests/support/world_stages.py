"""One small moving scene authored on stages of any up axis and unit (Y-up centimetres, ...).

The scene is designed in lfusd's world (Z-up, metres): a ground quad at z = 0, a box of edge
``BOX_EDGE`` resting on it and translating by ``BOX_STEP`` metres per frame, a distant light, and a
rig. It is written in the stage's own axes and units through :func:`to_stage` (the inverse of
the convention's map, written out here by hand, not taken from lfusd), so that every test knows
each stage point's world position in closed form: :func:`to_world` of it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pxr import Gf, Usd, UsdGeom, UsdLux

from lfusd.author.labels import set_class_label
from lfusd.author.rigs import add_rig
from lfusd.camera import RigSpec

GROUND_HALF = 3.0  # metres
BOX_EDGE = 0.8
BOX_START = np.array([0.0, 0.0, BOX_EDGE / 2])  # box centre at frame 1, world metres
BOX_STEP = np.array([0.12, 0.05, 0.0])  # world metres per frame
RIG_AT = np.array([0.3, -2.6, 1.6])  # world metres
RIG_LOOK_AT = np.array([0.0, 0.0, 0.4])
FRAMES = 3


def to_world(points, up: str, mpu: float) -> np.ndarray:
    """Stage coordinates -> lfusd's world, by the convention: Y-up (x, y, z) -> (x, -z, y), then * metersPerUnit."""
    p = np.asarray(points, float)
    if up == "Y":
        p = np.stack([p[..., 0], -p[..., 2], p[..., 1]], -1)
    return p * mpu


def to_stage(points, up: str, mpu: float) -> np.ndarray:
    """World metres -> stage coordinates (the inverse of :func:`to_world`)."""
    p = np.asarray(points, float) / mpu
    if up == "Y":
        p = np.stack([p[..., 0], p[..., 2], -p[..., 1]], -1)
    return p


def axes_metres(points, up: str) -> tuple[float, float, float]:
    """World metres -> metres along the stage's own axes (what ``rig add --at`` takes)."""
    return tuple(float(x) for x in to_stage(points, up, 1.0))


def box_centre(frame: int) -> np.ndarray:
    """World centre of the box at ``frame`` (metres)."""
    return BOX_START + BOX_STEP * (frame - 1)


def _mesh(stage, path: str, points_world: np.ndarray, faces: list[list[int]], up: str, mpu: float) -> UsdGeom.Mesh:
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr([Gf.Vec3f(*p) for p in to_stage(points_world, up, mpu)])
    mesh.CreateFaceVertexCountsAttr([len(f) for f in faces])
    mesh.CreateFaceVertexIndicesAttr([i for f in faces for i in f])
    return mesh


def write_world_stage(path: str | Path, up: str, mpu: float, rig: RigSpec | None = None) -> Usd.Stage:
    """The scene on a stage with ``upAxis = up`` and ``metersPerUnit = mpu``, frames 1..FRAMES."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, up)
    UsdGeom.SetStageMetersPerUnit(stage, mpu)
    stage.SetTimeCodesPerSecond(24)
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(FRAMES)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    h = GROUND_HALF
    ground = _mesh(stage, "/World/Ground", np.array([(-h, -h, 0), (h, -h, 0), (h, h, 0), (-h, h, 0)]), [[0, 1, 2, 3]], up, mpu)
    set_class_label(ground.GetPrim(), "ground")
    # The box mesh is centred on its prim's origin; the prim translates (time samples, stage units).
    xf = UsdGeom.Xform.Define(stage, "/World/Box")
    e = BOX_EDGE / 2
    corners = np.array([[x, y, z] for x in (-e, e) for y in (-e, e) for z in (-e, e)])
    faces = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    box = _mesh(stage, "/World/Box/Geom", corners, faces, up, mpu)
    # Flat faces: one normal per face corner (shared corners would be shaded smooth), in stage axes.
    normals = [to_stage(np.mean(corners[f], 0) / e * (np.abs(np.mean(corners[f], 0)) > e / 2), up, 1.0) for f in faces]
    box.CreateNormalsAttr([Gf.Vec3f(*n) for n in normals for _ in range(4)])
    box.SetNormalsInterpolation(UsdGeom.Tokens.faceVarying)
    box.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    op = xf.AddTranslateOp()
    for f in range(1, FRAMES + 1):
        op.Set(Gf.Vec3d(*to_stage(box_centre(f), up, mpu)), f)
    set_class_label(xf.GetPrim(), "crate")
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(1.0)
    sun.CreateNormalizeAttr(True)
    UsdGeom.XformCommonAPI(sun).SetRotate(Gf.Vec3f(30.0, 20.0, 0.0))
    if rig is not None:
        add_rig(stage, rig)
    stage.Save()
    return stage


def world_rig(up: str, **kw) -> RigSpec:
    """A small rig at RIG_AT looking at RIG_LOOK_AT, given (as ``rig add`` takes them) in the stage's axes."""
    values = dict(name="main", rows=2, cols=2, width=32, height=32, baseline=0.1, focal_length_mm=50.0,
                  at=axes_metres(RIG_AT, up), look_at=axes_metres(RIG_LOOK_AT, up))
    return RigSpec(**{**values, **kw})
