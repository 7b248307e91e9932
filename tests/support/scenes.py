"""Small test stages, written with plain pxr plus lfusd's rig authoring."""

from __future__ import annotations

import numpy as np
from pxr import Gf, UsdGeom, UsdLux

from lfusd.author.labels import set_class_label
from lfusd.camera import RigSpec
from lfusd.author.stage import new_stage
from lfusd.author.rigs import add_rig

GROUND_HALF = 20.0
# name: (translate, rotateXYZ degrees, edge size, label)
BOXES = {
    "BoxA": ((0.3, 0.0, 0.5), (0.0, 0.0, 30.0), 1.0, "crate"),
    "BoxB": ((-0.9, 0.6, 1.3), (20.0, 0.0, 45.0), 0.6, "drone"),
}


def box_matrix(translate, rotate_deg) -> np.ndarray:
    """4x4 column-vector pose of a box: rotate about X, then Y, then Z, then translate."""
    rx, ry, rz = np.radians(rotate_deg)
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    m = np.eye(4)
    m[:3, :3] = Rz @ Ry @ Rx
    m[:3, 3] = translate
    return m


def boxes_world() -> dict[str, tuple[np.ndarray, float]]:
    return {f"/World/{n}": (box_matrix(t, r), s) for n, (t, r, s, _) in BOXES.items()}


def write_box_stage(path, rigs: list[RigSpec], labelled_ground: bool = True) -> None:
    """Ground square z = 0 (label 'ground'), two labelled cubes, a sun; the given rigs."""
    stage = new_stage(path)
    g = UsdGeom.Mesh.Define(stage, "/World/Ground")
    h = GROUND_HALF
    g.CreatePointsAttr([(-h, -h, 0), (h, -h, 0), (h, h, 0), (-h, h, 0)])
    g.CreateFaceVertexCountsAttr([4])
    g.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    if labelled_ground:
        set_class_label(g.GetPrim(), "ground")
    for name, (t, r, size, label) in BOXES.items():
        if name == "BoxA":
            # A labelled Xform with one geometry child: Blender merges the two into one object
            # that its prim map knows by the Xform's path only.
            xf = UsdGeom.Xform.Define(stage, f"/World/{name}")
            cube = UsdGeom.Cube.Define(stage, f"/World/{name}/Geom")
            placed = xf
        else:
            cube = placed = UsdGeom.Cube.Define(stage, f"/World/{name}")
        cube.CreateSizeAttr(size)
        api = UsdGeom.XformCommonAPI(placed)
        api.SetTranslate(Gf.Vec3d(*t))
        api.SetRotate(Gf.Vec3f(*r), UsdGeom.XformCommonAPI.RotationOrderXYZ)
        set_class_label(placed.GetPrim(), label)
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(1.0)
    sun.CreateNormalizeAttr(True)
    UsdGeom.XformCommonAPI(sun).SetRotate(Gf.Vec3f(30.0, 20.0, 0.0))
    for spec in rigs:
        add_rig(stage, spec)
    stage.Save()


PLANE_RIG = RigSpec(name="main", rows=3, cols=3, width=64, height=48, baseline=0.1, at=(0.2, -5.0, 1.6), look_at=(0.0, 0.0, 0.6))
SPHERE_RIG = RigSpec(
    name="dome", rows=2, cols=3, width=40, height=40, baseline=0.4, at=(3.0, -4.0, 2.5), look_at=(0.0, 0.0, 0.5),
    layout="sphere", spacing="linear",
)


# Moving scene: name -> (pose(frame) -> 4x4, edge size, label). Motion per frame is large enough
# to see (several pixels) and small enough that t+1 stays in view.
def _slider(f):
    return box_matrix((-1.0 + 0.25 * f, 0.5 + 0.15 * f, 0.5 + 0.08 * f), (0.0, 0.0, 15.0))


def _spinner(f):
    return box_matrix((1.0, 0.2, 0.6), (0.0, 0.0, 12.0 * f))


MOVERS = {"Slider": (_slider, 0.8, "crate"), "Spinner": (_spinner, 0.9, "drone")}


def rig_offset(f, per_frame):
    """Translation of a moving rig at frame f (zero at frame 1)."""
    return np.asarray(per_frame, float) * (f - 1)


def write_motion_stage(path, rig: RigSpec, frames: int = 3, rig_motion=(0.0, 0.0, 0.0)) -> None:
    """Ground plane, a translating box and a spinning box as time-sampled transforms; the rig
    prim itself translates by ``rig_motion`` metres per frame."""
    stage = new_stage(path, 1, frames)
    g = UsdGeom.Mesh.Define(stage, "/World/Ground")
    h = GROUND_HALF
    g.CreatePointsAttr([(-h, -h, 0), (h, -h, 0), (h, h, 0), (-h, h, 0)])
    g.CreateFaceVertexCountsAttr([4])
    g.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    set_class_label(g.GetPrim(), "ground")
    for name, (pose, size, label) in MOVERS.items():
        cube = UsdGeom.Cube.Define(stage, f"/World/{name}")
        cube.CreateSizeAttr(size)
        op = cube.AddTransformOp()
        for f in range(1, frames + 1):
            op.Set(Gf.Matrix4d(*pose(f).T.ravel().tolist()), f)
        set_class_label(cube.GetPrim(), label)
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(1.0)
    sun.CreateNormalizeAttr(True)
    UsdGeom.XformCommonAPI(sun).SetRotate(Gf.Vec3f(30.0, 20.0, 0.0))
    prim = add_rig(stage, rig)
    if any(rig_motion):
        op = UsdGeom.Xformable(prim).GetOrderedXformOps()[0]
        rest = np.array(op.Get()).T
        for f in range(1, frames + 1):
            m = rest.copy()
            m[:3, 3] += rig_offset(f, rig_motion)
            op.Set(Gf.Matrix4d(*m.T.ravel().tolist()), f)
    stage.Save()


def movers_world(frame) -> dict[str, tuple[np.ndarray, float]]:
    return {f"/World/{n}": (pose(frame), size) for n, (pose, size, _) in MOVERS.items()}
