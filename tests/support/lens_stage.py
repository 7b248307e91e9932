"""A stage for defocus (issue 40): a matte plane tilted about the vertical axis (its planar depth varies
across the columns, closed-form) above a small emissive square nearer than the focus, on black (no
lights): the square's defocused image is a disc-blurred copy of its sharp one."""

from __future__ import annotations

import numpy as np
from pxr import Sdf, UsdGeom, UsdShade

from lfusd.author.rigs import add_rig
from lfusd.author.stage import new_stage
from lfusd.camera import RigSpec

RIG = RigSpec(name="main", rows=1, cols=1, width=48, height=40, baseline=0.1, focal_length_mm=50.0, at=(0.0, -3.0, 1.0),
              look_at=(0.0, 2.0, 1.0))
FSTOP, FOCUS = 0.4, 3.0  # aperture 50 mm / 0.4 = 125 mm; focused 3 m in front of the camera
# the tilted plane: through (0, PLANE_Y, *) with its normal rotated TILT degrees about z from -y; z in [1.1, 3]
PLANE_Y, TILT, PLANE_Z = 0.5, 35.0, (1.1, 3.0)
SQUARE = (0.0, -2.0, 0.88, 0.05)  # x, y, z of the centre, half side: planar depth 1 m, below the plane in the picture


def plane_points() -> list[tuple[float, float, float]]:
    a = np.radians(TILT)
    along = np.array([np.cos(a), np.sin(a), 0.0])  # the plane's horizontal direction
    c = np.array([0.0, PLANE_Y, 0.0])
    z0, z1 = PLANE_Z
    return [tuple(c + s * 4 * along + [0, 0, z]) for s, z in ((-1, z0), (1, z0), (1, z1), (-1, z1))]


def write_lens_stage(path) -> None:
    stage = new_stage(path)
    plane = UsdGeom.Mesh.Define(stage, "/World/Tilted")
    plane.CreatePointsAttr(plane_points())
    plane.CreateFaceVertexCountsAttr([4])
    plane.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    sq = UsdGeom.Mesh.Define(stage, "/World/Square")
    x, y, z, h = SQUARE
    sq.CreatePointsAttr([(x - h, y, z - h), (x + h, y, z - h), (x + h, y, z + h), (x - h, y, z + h)])
    sq.CreateFaceVertexCountsAttr([4])
    sq.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    mat = UsdShade.Material.Define(stage, "/World/Looks/lamp")
    shader = UsdShade.Shader.Define(stage, "/World/Looks/lamp/Surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set((0.0, 0.0, 0.0))
    shader.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set((1.0, 1.0, 1.0))
    shader.CreateInput("useSpecularWorkflow", Sdf.ValueTypeNames.Int).Set(1)
    shader.CreateInput("specularColor", Sdf.ValueTypeNames.Color3f).Set((0.0, 0.0, 0.0))
    mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(sq.GetPrim()).Bind(mat)
    add_rig(stage, RIG)
    stage.Save()
