"""A stage for defocus through a lens distortion (issue 40): the defocus stage of support.lens_stage (a
black plane tilted across the picture, an emissive square at planar depth 1 m, nearer than the focus)
with a second emissive square off-centre in the focus plane, seen through a strong barrel lens."""

from __future__ import annotations

from pxr import Usd, UsdGeom, UsdShade

from support.distortion_stage import LENS
from support.lens_stage import FOCUS, RIG, write_lens_stage

__all__ = ["FOCUS", "LENS", "RIG", "SHARP", "write_thinlens_stage"]

# x, y, z of the centre, half side: planar depth FOCUS (the camera is at y = -3), up and to the right
# of the image centre (normalised (0.2, -0.1)), in front of the tilted plane
SHARP = (0.6, FOCUS - 3.0, 1.3, 0.06)


def write_thinlens_stage(path) -> None:
    write_lens_stage(path)
    stage = Usd.Stage.Open(str(path))
    sq = UsdGeom.Mesh.Define(stage, "/World/Sharp")
    x, y, z, h = SHARP
    sq.CreatePointsAttr([(x - h, y, z - h), (x + h, y, z - h), (x + h, y, z + h), (x - h, y, z + h)])
    sq.CreateFaceVertexCountsAttr([4])
    sq.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    UsdShade.MaterialBindingAPI.Apply(sq.GetPrim()).Bind(UsdShade.Material(stage.GetPrimAtPath("/World/Looks/lamp")))
    stage.Save()
