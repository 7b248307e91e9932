"""Regenerate stages/static_boxes.usda, the small static scene of the benchmarks: `python stages/make_static_boxes.py`."""

from pathlib import Path

from pxr import Gf, Sdf, UsdGeom, UsdLux, UsdShade

from lfusd.author.labels import set_class_label
from lfusd.camera import RigSpec
from lfusd.author.stage import new_stage
from lfusd.author.rigs import add_rig


def material(stage, name, rgb, roughness=0.6):
    mat = UsdShade.Material.Define(stage, f"/World/Looks/{name}")
    sh = UsdShade.Shader.Define(stage, f"/World/Looks/{name}/Surface")
    sh.CreateIdAttr("UsdPreviewSurface")
    sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*rgb))
    sh.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(roughness)
    mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
    return mat


def main(path=Path(__file__).with_name("static_boxes.usda")):
    stage = new_stage(str(path))
    ground = UsdGeom.Mesh.Define(stage, "/World/Ground")
    ground.CreatePointsAttr([(-30, -30, 0), (30, -30, 0), (30, 30, 0), (-30, 30, 0)])
    ground.CreateFaceVertexCountsAttr([4])
    ground.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    set_class_label(ground.GetPrim(), "ground")
    UsdShade.MaterialBindingAPI.Apply(ground.GetPrim()).Bind(material(stage, "Grass", (0.25, 0.45, 0.2), 0.9))
    looks = [material(stage, n, c) for n, c in (("Red", (0.7, 0.15, 0.1)), ("Blue", (0.1, 0.25, 0.7)), ("Wood", (0.55, 0.4, 0.25)))]
    for i, (name, pos, rot, size, label) in enumerate(
        [
            ("Crate", (0.0, 0.0, 0.5), 25.0, 1.0, "crate"),
            ("Box", (-1.6, 1.5, 0.4), -10.0, 0.8, "box"),
            ("Block", (1.5, 2.5, 0.75), 40.0, 1.5, "block"),
        ]
    ):
        # A Mesh, not a Cube: Blender drops material bindings of implicit prims on import.
        cube = UsdGeom.Mesh.Define(stage, f"/World/{name}")
        h = size / 2
        cube.CreatePointsAttr([(x, y, z) for z in (-h, h) for y in (-h, h) for x in (-h, h)])
        cube.CreateFaceVertexCountsAttr([4] * 6)
        cube.CreateFaceVertexIndicesAttr([0, 2, 3, 1, 4, 5, 7, 6, 0, 1, 5, 4, 2, 6, 7, 3, 0, 4, 6, 2, 1, 3, 7, 5])
        api = UsdGeom.XformCommonAPI(cube)
        api.SetTranslate(Gf.Vec3d(*pos))
        api.SetRotate(Gf.Vec3f(0, 0, rot))
        set_class_label(cube.GetPrim(), label)
        UsdShade.MaterialBindingAPI.Apply(cube.GetPrim()).Bind(looks[i])
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(0.6)
    sun.CreateNormalizeAttr(True)  # Blender reads un-normalized lights as radiance: far too dark
    UsdGeom.XformCommonAPI(sun).SetRotate(Gf.Vec3f(40.0, 15.0, 30.0))
    fill = UsdLux.SphereLight.Define(stage, "/World/Fill")
    fill.CreateIntensityAttr(40.0)
    fill.CreateRadiusAttr(0.5)
    fill.CreateNormalizeAttr(True)
    UsdGeom.XformCommonAPI(fill).SetTranslate(Gf.Vec3d(-3.0, -4.0, 4.0))
    add_rig(stage, RigSpec(name="main", rows=5, cols=5, baseline=0.1, width=256, height=256, at=(0.5, -7.0, 2.2), look_at=(0.0, 1.0, 0.6)))
    stage.Save()


if __name__ == "__main__":
    main()
