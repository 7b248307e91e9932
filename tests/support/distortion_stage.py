"""A stage for lens distortion (issue 40 item 4): a box that slides and turns over a ground plane in
front of a tilted wall, seen by a 1x2 rig looking down at it, so that every pixel of a strongly
distorted image sees a surface and the motion varies across the picture."""

from __future__ import annotations

from pxr import Gf, UsdGeom

from lfusd.author.rigs import add_rig
from lfusd.author.stage import new_stage
from lfusd.camera import Distortion, RigSpec

RIG = RigSpec(name="main", rows=1, cols=2, width=40, height=30, baseline=0.2, focal_length_mm=30.0, at=(0.3, -3.0, 1.6),
              look_at=(0.0, 0.5, 0.3))
LENS = Distortion(k1=-0.25, k2=0.05, p1=0.003, p2=-0.004, k3=0.002)  # strong barrel with a little decentring


def write_distortion_stage(path, frames: int = 3) -> None:
    stage = new_stage(path, 1, frames)
    ground = UsdGeom.Mesh.Define(stage, "/World/Ground")
    ground.CreatePointsAttr([(-8, -8, 0), (8, -8, 0), (8, 8, 0), (-8, 8, 0)])
    ground.CreateFaceVertexCountsAttr([4])
    ground.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    wall = UsdGeom.Mesh.Define(stage, "/World/Wall")
    wall.CreatePointsAttr([(-8, 3, 0), (8, 1.5, 0), (8, 1.5, 6), (-8, 3, 6)])
    wall.CreateFaceVertexCountsAttr([4])
    wall.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    box = UsdGeom.Cube.Define(stage, "/World/Box")
    box.CreateSizeAttr(0.6)
    xf = UsdGeom.Xformable(box)
    move, turn = xf.AddTranslateOp(), xf.AddRotateZOp()
    for f in range(1, frames + 1):
        move.Set(Gf.Vec3d(-0.4 + 0.15 * (f - 1), 0.1 * (f - 1), 0.3), f)
        turn.Set(12.0 * (f - 1), f)
    add_rig(stage, RIG)
    stage.Save()
