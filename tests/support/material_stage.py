"""A stage for the material masks (issue 40): a matte wall behind a glass pane, a mirror and a lamp,
and one two-material mesh (a GeomSubset of mirror faces beside matte ones), seen by a small rig looking
along +y. Every surface is an axis-aligned quad, so what each pixel sees is closed-form."""

from __future__ import annotations

from pxr import Sdf, UsdGeom, UsdShade

from lfusd.author.rigs import add_rig
from lfusd.author.stage import new_stage
from lfusd.camera import RigSpec

RIG = RigSpec(name="main", rows=1, cols=2, width=40, height=30, baseline=0.05, focal_length_mm=20.0, at=(0.0, -4.0, 1.0),
              look_at=(0.0, 2.0, 1.0))
WALL_Y = 2.0  # the wall: the plane y = 2, x in [-6, 6], z in [-4, 6]
# quads in planes y = const: name -> (y, x0, x1, z0, z1, material)
QUADS = {
    "Glass": (0.5, -2.2, -0.4, 0.2, 1.8, "glass"),
    "Mirror": (1.0, 0.2, 1.4, 1.1, 1.9, "mirror"),
    "Lamp": (1.2, 0.2, 1.4, 0.1, 0.8, "lamp"),
}
TWO_Y, TWO_X, TWO_Z = 1.5, (1.6, 2.4, 3.2), (0.3, 1.7)  # two quads side by side: left matte, right mirror (a subset)
# UsdPreviewSurface inputs of each material (the glass and water finishes of lfusd.author.scenes.build)
MATERIALS = {
    "matte": {"diffuseColor": (0.6, 0.6, 0.6), "roughness": 0.8},
    "glass": {"diffuseColor": (0.9, 0.9, 0.9), "roughness": 0.05, "opacity": 0.3, "ior": 1.5},
    "mirror": {"diffuseColor": (0.9, 0.9, 0.9), "roughness": 0.0, "metallic": 1.0},
    "lamp": {"diffuseColor": (1.0, 1.0, 1.0), "roughness": 0.8, "emissiveColor": (4.0, 4.0, 3.0)},
}
TRANSMISSIVE, MIRROR, EMISSIVE = "Glass", "Mirror", "Lamp"


def _material(stage, name: str) -> UsdShade.Material:
    path = Sdf.Path("/World/Looks").AppendChild(name)
    mat = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, path.AppendChild("Surface"))
    shader.CreateIdAttr("UsdPreviewSurface")
    for key, value in MATERIALS[name].items():
        kind = Sdf.ValueTypeNames.Color3f if isinstance(value, tuple) else Sdf.ValueTypeNames.Float
        shader.CreateInput(key, kind).Set(value)
    mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return mat


def _quad(stage, path: str, y: float, x0: float, x1: float, z0: float, z1: float) -> UsdGeom.Mesh:
    m = UsdGeom.Mesh.Define(stage, path)
    m.CreatePointsAttr([(x0, y, z0), (x1, y, z0), (x1, y, z1), (x0, y, z1)])
    m.CreateFaceVertexCountsAttr([4])
    m.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    return m


def write_material_stage(path, frames: int = 1) -> None:
    stage = new_stage(path, 1, frames)
    mats = {n: _material(stage, n) for n in MATERIALS}
    wall = _quad(stage, "/World/Wall", WALL_Y, -6.0, 6.0, -4.0, 6.0)
    UsdShade.MaterialBindingAPI.Apply(wall.GetPrim()).Bind(mats["matte"])
    for name, (y, x0, x1, z0, z1, mat) in QUADS.items():
        q = _quad(stage, f"/World/{name}", y, x0, x1, z0, z1)
        UsdShade.MaterialBindingAPI.Apply(q.GetPrim()).Bind(mats[mat])
    two = UsdGeom.Mesh.Define(stage, "/World/Two")
    (xa, xb, xc), (z0, z1) = TWO_X, TWO_Z
    two.CreatePointsAttr([(xa, TWO_Y, z0), (xb, TWO_Y, z0), (xb, TWO_Y, z1), (xa, TWO_Y, z1), (xc, TWO_Y, z0), (xc, TWO_Y, z1)])
    two.CreateFaceVertexCountsAttr([4, 4])
    two.CreateFaceVertexIndicesAttr([0, 1, 2, 3, 1, 4, 5, 2])
    binding = UsdShade.MaterialBindingAPI.Apply(two.GetPrim())
    # a subset per face: Blender 5.0's importer gives faces outside every subset the first subset's material
    for name, faces, mat in (("dull", [0], "matte"), ("shiny", [1], "mirror")):
        subset = binding.CreateMaterialBindSubset(name, faces, UsdGeom.Tokens.face)
        UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(mats[mat])
    add_rig(stage, RIG)
    stage.Save()
