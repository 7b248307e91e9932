"""An asset in the shape Infinigen exports (infinigen/tools/export.py through Blender 4.2's USD
exporter), for the bake clean-up's tests (lfusd.author.bake), authored here, not by Infinigen:

- Z-up, metres, root Xform ``/World`` (the default prim), each object an Xform with a
  ``xformOp:transform`` holding a Mesh of the same name (faceVarying normals and ``st``);
- materials under ``/World/_materials`` as Blender writes them: a ``Principled_BSDF``
  UsdPreviewSurface fed by ``Image_Texture*`` UsdUVTexture nodes reading the baked PNGs in
  ``textures/`` (DIFFUSE, ROUGHNESS, METAL, NORMAL), every one tagged ``sourceColorSpace = "sRGB"``,
  the normal map wired straight into ``inputs:normal`` with no scale or bias;
- a glass pane whose material has ``opacity`` 0 (Infinigen's glass: Alpha 0, transmission 1);
- the whole asset floating :data:`LIFT` above the ground (its lowest point at z = LIFT);
- two identical twig meshes as separate copies (different transforms, the same local points);
- Blender's world exported as a DomeLight ``env_light`` reading ``textures/color_121212.hdr``, a
  4x4 Radiance image of the world's grey, radiance :data:`DOME_RADIANCE` (the file's bytes as
  Blender 4.2 writes them); no class label.

``plain=True`` writes the same geometry with the textures' intended meaning as constants (the
diffuse texture kept, roughness :data:`ROUGHNESS`, metallic 0, no normal map, glass as lfusd
authors it, no lights): the reference an honest translation must match in brightness.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt

LIFT = 0.2  # m: the lowest point's height as exported
TOP = (0.8, 0.5, 0.06)  # m: the table top's size, its underside at LIFT + LEG
LEG = 0.5  # m: leg height
TWIG = (0.02, 0.02, 0.25)  # m: a twig's box
TWIG_AT = ((0.2, 0.1, LIFT + LEG + TOP[2]), (-0.2, -0.1, LIFT + LEG + TOP[2]))  # where the two copies stand
PANE = (0.4, 0.01, 0.3)  # m: the glass pane standing on the top
ROUGHNESS = 0.6
WOOD = (150, 100, 60)  # sRGB 8-bit: the baked diffuse colour
DOME_RADIANCE = 208.5 / 256 / 16  # RGBE (208, 208, 208, 124): mantissa (m + 0.5) / 256, exponent 124 - 128
TRIANGLES = 12 * 8  # the top, four legs, the pane and two twigs: eight boxes of 12 triangles


def _png(path: Path, rgb, stripes: bool = False) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    img = np.zeros((16, 16, 3), np.uint8)
    img[:] = rgb
    if stripes:
        img[::4] = (np.asarray(rgb) * 0.8).astype(np.uint8)
    Image.fromarray(img).save(path)


def _hdr(path: Path) -> None:
    """The 4x4 grey Radiance image Blender writes for a plain world colour (uncompressed RGBE)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 4 +X 4\n" + bytes([208, 208, 208, 124]) * 16)


def _box(stage, path: str, size, material: str) -> UsdGeom.Mesh:
    """A box mesh of ``size`` centred on x, y with its base at z = 0, in Blender's export form."""
    sx, sy, sz = size[0] / 2, size[1] / 2, size[2]
    pts = np.array([[x, y, z] for x in (-sx, sx) for y in (-sy, sy) for z in (0.0, sz)])
    faces = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    normals = [(-1, 0, 0), (1, 0, 0), (0, -1, 0), (0, 1, 0), (0, 0, -1), (0, 0, 1)]
    m = UsdGeom.Mesh.Define(stage, path)
    m.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*p) for p in pts.tolist()]))
    m.CreateFaceVertexCountsAttr([4] * 6)
    m.CreateFaceVertexIndicesAttr([i for f in faces for i in f])
    m.CreateNormalsAttr([Gf.Vec3f(*n) for n in normals for _ in range(4)])
    m.SetNormalsInterpolation(UsdGeom.Tokens.faceVarying)
    m.CreateSubdivisionSchemeAttr("none")
    m.CreateExtentAttr([Gf.Vec3f(*pts.min(0).tolist()), Gf.Vec3f(*pts.max(0).tolist())])
    st = UsdGeom.PrimvarsAPI(m).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    st.Set([Gf.Vec2f(u, v) for _ in faces for u, v in ((0, 0), (1, 0), (1, 1), (0, 1))])
    UsdShade.MaterialBindingAPI.Apply(m.GetPrim()).Bind(UsdShade.Material.Get(stage, material))
    return m


def _object(stage, name: str, size, at, material: str) -> None:
    x = UsdGeom.Xform.Define(stage, f"/World/{name}")
    x.AddTransformOp().Set(Gf.Matrix4d(1.0).SetTranslate(Gf.Vec3d(*at)))
    _box(stage, f"/World/{name}/{name}", size, material)


def _texture(stage, mat: str, node: str, file: str, uv) -> UsdShade.Shader:
    tex = UsdShade.Shader.Define(stage, f"{mat}/{node}")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(file)
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")  # Blender 4.2 writes the image's: sRGB
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(uv.ConnectableAPI(), "result")
    tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("repeat")
    tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("repeat")
    tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    tex.CreateOutput("r", Sdf.ValueTypeNames.Float)
    return tex


def _material(stage, name: str, textures: dict | None = None, **constants) -> None:
    path = f"/World/_materials/{name}"
    mat = UsdShade.Material.Define(stage, path)
    pbr = UsdShade.Shader.Define(stage, f"{path}/Principled_BSDF")
    pbr.CreateIdAttr("UsdPreviewSurface")
    pbr.CreateInput("clearcoat", Sdf.ValueTypeNames.Float).Set(0.0)
    pbr.CreateInput("ior", Sdf.ValueTypeNames.Float).Set(constants.pop("ior", 1.45))
    pbr.CreateInput("specular", Sdf.ValueTypeNames.Float).Set(0.5)
    for key, value in {"opacity": 1.0, "metallic": 0.0, "roughness": 0.5, **constants}.items():
        if key == "diffuseColor":
            pbr.CreateInput(key, Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*value))
        else:
            pbr.CreateInput(key, Sdf.ValueTypeNames.Float).Set(float(value))
    if textures:
        uv = UsdShade.Shader.Define(stage, f"{path}/uvmap")
        uv.CreateIdAttr("UsdPrimvarReader_float2")
        uv.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
        uv.CreateOutput("result", Sdf.ValueTypeNames.Float2)
        for k, (input_name, file) in enumerate(textures.items()):
            tex = _texture(stage, path, "Image_Texture" + (f"_{k:03d}" if k else ""), file, uv)
            if input_name == "diffuseColor":
                pbr.CreateInput(input_name, Sdf.ValueTypeNames.Color3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
            elif input_name == "normal":
                # Blender 4.2 writes the normal input as float3 (UsdPreviewSurface says normal3f)
                pbr.CreateInput(input_name, Sdf.ValueTypeNames.Float3).ConnectToSource(tex.ConnectableAPI(), "rgb")
            else:
                pbr.CreateInput(input_name, Sdf.ValueTypeNames.Float).ConnectToSource(tex.ConnectableAPI(), "r")
    mat.CreateSurfaceOutput().ConnectToSource(pbr.ConnectableAPI(), "surface")


def write_infinigen_table(folder: str | Path, name: str = "TableDiningFactory_0", plain: bool = False) -> Path:
    """The asset (see the module docstring) as ``folder/name.usdc`` with ``folder/textures/``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    tex = folder / "textures"
    _png(tex / "top_DIFFUSE.png", WOOD, stripes=True)
    _png(tex / "top_ROUGHNESS.png", (round(ROUGHNESS * 255),) * 3)
    _png(tex / "top_METAL.png", (0, 0, 0))
    _png(tex / "top_NORMAL.png", (128, 128, 255))  # flat: the tangent-space normal (0, 0, 1)
    if not plain:
        _hdr(tex / "color_121212.hdr")
    path = folder / f"{name}.usdc"
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    root = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(root.GetPrim())
    UsdGeom.Scope.Define(stage, "/World/_materials")
    if plain:
        _material(stage, "wood", {"diffuseColor": "./textures/top_DIFFUSE.png"}, roughness=ROUGHNESS)
        _material(stage, "glass", roughness=0.05, opacity=0.3, ior=1.5)
    else:
        _material(stage, "wood", {"diffuseColor": "./textures/top_DIFFUSE.png", "roughness": "./textures/top_ROUGHNESS.png",
                                  "metallic": "./textures/top_METAL.png", "normal": "./textures/top_NORMAL.png"})
        _material(stage, "glass", roughness=0.0, opacity=0.0, ior=1.5)  # Infinigen's glass: fully transparent
    _material(stage, "bark", diffuseColor=(0.1, 0.06, 0.03), roughness=0.8)
    top_z = LIFT + LEG
    _object(stage, "top", TOP, (0.0, 0.0, top_z), "/World/_materials/wood")
    for k, (x, y) in enumerate(((-0.35, -0.2), (0.35, -0.2), (-0.35, 0.2), (0.35, 0.2))):
        _object(stage, f"leg_{k:03d}", (0.05, 0.05, LEG), (x, y, LIFT), "/World/_materials/wood")
    _object(stage, "pane", PANE, (0.0, 0.0, top_z + TOP[2]), "/World/_materials/glass")
    for k, at in enumerate(TWIG_AT):
        _object(stage, f"twig_{k + 1:03d}", TWIG, at, "/World/_materials/bark")
    if not plain:
        dome = UsdLux.DomeLight.Define(stage, "/World/env_light")
        dome.CreateIntensityAttr(1.0)
        dome.CreateTextureFileAttr("./textures/color_121212.hdr")
        dome.AddRotateXYZOp().Set(Gf.Vec3f(90, 0, 90))
    stage.GetRootLayer().Save()
    return path
