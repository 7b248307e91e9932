"""Normal maps as lfusd authors them (tangent space, x along u, y along v, raw 8-bit with scale 2 and
bias -1) shade in Blender as the normals they encode, and leave the ground-truth normal alone.

Four diffuse planes side by side, each with a constant normal map (flat, tilted 30 degrees towards
+u, towards -u, towards +v), lit by one sun 60 degrees high from +x (u runs along +x, v along +y):
Lambert's law gives their brightness ratios to the flat one, cos(0) : cos(30) : cos(60) : 0.75 over
cos(30). Marked ``render``: one 48x16 view at 16 samples.
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdLux, UsdShade

from lfusd import Dataset
from lfusd.author.labels import set_class_label
from lfusd.author.rigs import add_rig
from lfusd.author.scenes.textures import write_png
from lfusd.author.stage import new_stage
from lfusd.camera import RigSpec

pytestmark = pytest.mark.render

TILT = math.radians(30.0)
MAPS = {  # plane -> tangent-space normal
    "flat": (0.0, 0.0, 1.0),
    "plus_u": (math.sin(TILT), 0.0, math.cos(TILT)),
    "minus_u": (-math.sin(TILT), 0.0, math.cos(TILT)),
    "plus_v": (0.0, math.sin(TILT), math.cos(TILT)),
}
SUN_ELEVATION = math.radians(60.0)
TO_SUN = np.array([math.cos(SUN_ELEVATION), 0.0, math.sin(SUN_ELEVATION)])


def _plane(stage, name: str, x0: float, normal) -> None:
    mesh = UsdGeom.Mesh.Define(stage, f"/World/{name}")
    pts = [(x0, -1.0, 0.0), (x0 + 2.0, -1.0, 0.0), (x0 + 2.0, 1.0, 0.0), (x0, 1.0, 0.0)]
    mesh.CreatePointsAttr(pts)
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    st.Set([Gf.Vec2f(x - x0, y + 1.0) for x, y, _ in pts])  # u along +x, v along +y
    set_class_label(mesh.GetPrim(), "ground")
    png = Path(stage.GetRootLayer().realPath).parent / f"{name}_normal.png"
    write_png(png, np.full((4, 4, 3), np.round((np.asarray(normal) * 0.5 + 0.5) * 255), np.uint8))
    mat = UsdShade.Material.Define(stage, f"/World/Looks/{name}")
    surf = UsdShade.Shader.Define(stage, f"/World/Looks/{name}/Surface")
    surf.CreateIdAttr("UsdPreviewSurface")
    surf.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.5, 0.5, 0.5))
    surf.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(1.0)
    reader = UsdShade.Shader.Define(stage, f"/World/Looks/{name}/St")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    tex = UsdShade.Shader.Define(stage, f"/World/Looks/{name}/Normal")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(f"./{png.name}")
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("raw")
    tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(2, 2, 2, 1))
    tex.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(-1, -1, -1, 0))
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    surf.CreateInput("normal", Sdf.ValueTypeNames.Normal3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
    mat.CreateSurfaceOutput().ConnectToSource(surf.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)


def test_normal_maps_shade_as_encoded_and_leave_the_normal_key_alone(tmp_path):
    path = tmp_path / "planes.usda"
    stage = new_stage(path)
    for i, (name, normal) in enumerate(MAPS.items()):
        _plane(stage, name, -4.0 + 2.0 * i, normal)
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(1.0)
    sun.CreateNormalizeAttr(True)
    sun.CreateAngleAttr(0.0)
    # -Z of the light along minus the direction to the sun: turn +Z onto TO_SUN (about -y by 30 deg)
    UsdGeom.Xformable(sun).AddRotateYOp().Set(90.0 - math.degrees(SUN_ELEVATION))
    # straight down onto the row of planes (the rig's up is the stage's +y... any: a tiny tilt)
    add_rig(stage, RigSpec(name="top", rows=1, cols=1, width=96, height=24, focal_length_mm=36.0,
                           at=(0.0, 0.0, 8.0), look_at=(0.0, 0.001, 0.0)))
    stage.Save()
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "lfusd", "render", str(path), "-o", str(out), "--samples", "16", "--quiet",
                           "--keys", "rgb_linear,normal,instance"],
                          capture_output=True, text=True, timeout=600, cwd=Path(__file__).resolve().parents[2])
    assert proc.returncode == 0, proc.stderr[-3000:]
    d = Dataset(out)
    rgb, normal, inst = (d.read(1, (0, 0), k) for k in ("rgb_linear", "normal", "instance"))
    ids = {o.prim_path.rsplit("/", 1)[-1]: i for i, o in d.objects.items()}
    assert set(ids) >= set(MAPS), ids
    mean = {}
    for name in MAPS:
        mask = inst == ids[name]
        inner = mask & np.roll(mask, 1, 0) & np.roll(mask, -1, 0) & np.roll(mask, 1, 1) & np.roll(mask, -1, 1)
        assert inner.sum() > 20, name
        # ground truth: the mesh's own normal, not the map's
        assert np.allclose(normal[mask], (0.0, 0.0, 1.0), atol=1e-3), name
        mean[name] = float(rgb[inner].mean())
    for name, n in MAPS.items():
        expect = max(float(np.dot(n, TO_SUN)), 0.0) / float(np.dot(MAPS["flat"], TO_SUN))
        assert mean[name] / mean["flat"] == pytest.approx(expect, rel=0.05), (name, mean)
