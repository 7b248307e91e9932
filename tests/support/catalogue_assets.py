"""USD assets shaped like real ones, for the asset catalogue's tests (lfusd.author.catalogue).

- a car (``.usdc``): Y-up, centimetres, a converter's rotation on its root (rotateY 90: its length
  along the file's z axis), a body with a foreign UsdPreviewSurface material reading a PNG
  texture beside it, four wheels as scene-graph instances of one class prim; no lights;
- a tree (``.usdz`` with its texture inside): Y-up, centimetres, a textured trunk and a crown of
  leaf boxes drawn by a PointInstancer;
- a bench (``.usda``): Z-up metres, no class label (added with ``--class bench``).

The dimensions are module constants, so tests compare what lfusd records and places against
closed-form numbers.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from PIL import Image
from pxr import Gf, Sdf, Usd, UsdGeom, UsdSemantics, UsdShade, UsdUtils, Vt

CAR_LENGTH, CAR_WIDTH, CAR_HEIGHT = 420.0, 2 * 96.0, 140.0  # cm: body 420 long, wheels' outer faces 96 off the middle
WHEEL_R, WHEEL_W = 30.0, 20.0
TREE_HEIGHT = 360.0  # cm: trunk 0-300, leaf boxes (centres at 340) up to 360
LEAF = 40.0  # cm: leaf box edge
LEAF_RING = 80.0  # cm: the leaves' ring radius, centres at y = 340
TREE_WIDTH = 2 * LEAF_RING + LEAF  # cm: the crown is wider than the trunk


def _texture(path: Path, colour) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    img = np.zeros((16, 16, 3), np.uint8)
    img[:] = colour
    img[::4] = (np.array(colour) * 0.6).astype(np.uint8)  # stripes: a texture, not a flat colour
    Image.fromarray(img).save(path)


def _mesh(stage, path: str, lo, hi) -> UsdGeom.Mesh:
    """An axis-aligned box mesh lo..hi (outward quads), with face-varying UVs."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    pts = [[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)]
    faces = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    m = UsdGeom.Mesh.Define(stage, path)
    m.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*p) for p in pts]))
    m.CreateFaceVertexCountsAttr([4] * 6)
    m.CreateFaceVertexIndicesAttr([i for f in faces for i in f])
    m.CreateSubdivisionSchemeAttr("none")
    m.CreateExtentAttr([Gf.Vec3f(*lo), Gf.Vec3f(*hi)])
    st = UsdGeom.PrimvarsAPI(m).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    st.Set([Gf.Vec2f(u, v) for _ in faces for u, v in ((0, 0), (1, 0), (1, 1), (0, 1))])
    return m


def _wheel(stage, path: str, segments: int = 8) -> UsdGeom.Mesh:
    """A prism of radius WHEEL_R along z (width WHEEL_W) centred on the origin; a vertex at the bottom."""
    a = -math.pi / 2 + np.arange(segments) * 2 * math.pi / segments
    ring = np.c_[WHEEL_R * np.cos(a), WHEEL_R * np.sin(a)]
    pts = [(x, y, z) for z in (-WHEEL_W / 2, WHEEL_W / 2) for x, y in ring]
    n = segments
    faces = [[k, (k + 1) % n, n + (k + 1) % n, n + k][::-1] for k in range(n)]
    faces += [list(range(n))[::-1], list(range(n, 2 * n))]
    m = UsdGeom.Mesh.Define(stage, path)
    m.CreatePointsAttr([Gf.Vec3f(*p) for p in pts])
    m.CreateFaceVertexCountsAttr([len(f) for f in faces])
    m.CreateFaceVertexIndicesAttr([i for f in faces for i in f])
    m.CreateSubdivisionSchemeAttr("none")
    return m


def _material(stage, path: str, texture: str | None, colour=(0.2, 0.2, 0.2)) -> UsdShade.Material:
    """A converter-style UsdPreviewSurface material (its own shader names), textured or plain."""
    mat = UsdShade.Material.Define(stage, path)
    pbr = UsdShade.Shader.Define(stage, f"{path}/PBRShader")
    pbr.CreateIdAttr("UsdPreviewSurface")
    pbr.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.5)
    if texture:
        reader = UsdShade.Shader.Define(stage, f"{path}/TexCoordReader")
        reader.CreateIdAttr("UsdPrimvarReader_float2")
        reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
        tex = UsdShade.Shader.Define(stage, f"{path}/BaseColorTex")
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(texture)
        tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
        tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
        tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
        pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
    else:
        pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*colour))
    mat.CreateSurfaceOutput().ConnectToSource(pbr.ConnectableAPI(), "surface")
    return mat


def _bind(prim, mat) -> None:
    UsdShade.MaterialBindingAPI.Apply(prim).Bind(mat)


def _y_up_cm(path: Path) -> Usd.Stage:
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    return stage


def write_car(folder: str | Path, name: str = "sedan", label: str | None = "car", licence: str = "CC-BY-4.0") -> Path:
    """The car asset (see the module docstring) as ``folder/name.usdc`` with ``folder/textures/``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    _texture(folder / "textures" / f"{name}_paint.png", (180, 30, 30))
    path = folder / f"{name}.usdc"
    stage = _y_up_cm(path)
    stage.GetRootLayer().customLayerData = {"license": licence}
    root = UsdGeom.Xform.Define(stage, "/Car")
    stage.SetDefaultPrim(root.GetPrim())
    root.AddRotateYOp().Set(90.0)  # the converter's turn: the car's length runs along the file's z axis
    if label:
        UsdSemantics.LabelsAPI.Apply(root.GetPrim(), "class").CreateLabelsAttr().Set([label])
    geo = UsdGeom.Xform.Define(stage, "/Car/Geo")
    body = _mesh(stage, "/Car/Geo/Body", (-CAR_LENGTH / 2, WHEEL_R, -75.0), (CAR_LENGTH / 2, CAR_HEIGHT, 75.0))
    _bind(body.GetPrim(), _material(stage, "/Car/Materials/M_CarPaint", f"./textures/{name}_paint.png"))
    proto = stage.CreateClassPrim("/_WheelProto")
    _wheel(stage, "/_WheelProto/Tyre")
    _bind(stage.GetPrimAtPath("/_WheelProto/Tyre"), _material(stage, "/_WheelProto/M_Rubber", None))
    for k, (x, z) in enumerate([(-140, -86), (-140, 86), (140, -86), (140, 86)]):
        w = UsdGeom.Xform.Define(stage, f"/Car/Geo/Wheel_{k}")
        w.AddTranslateOp().Set(Gf.Vec3d(x, WHEEL_R, z))
        w.GetPrim().GetReferences().AddInternalReference(proto.GetPath())
        w.GetPrim().SetInstanceable(True)
    del geo
    stage.GetRootLayer().Save()
    return path


def write_tree(folder: str | Path, name: str = "oak") -> Path:
    """The tree asset (see the module docstring) as ``folder/name.usdz`` (texture packaged inside)."""
    folder = Path(folder)
    work = folder / f".{name}_src"
    work.mkdir(parents=True, exist_ok=True)
    _texture(work / "bark.png", (110, 80, 50))
    src = work / f"{name}.usdc"
    stage = _y_up_cm(src)
    stage.GetRootLayer().customLayerData = {"license": "CC0-1.0"}
    root = UsdGeom.Xform.Define(stage, "/Tree")
    stage.SetDefaultPrim(root.GetPrim())
    UsdSemantics.LabelsAPI.Apply(root.GetPrim(), "class").CreateLabelsAttr().Set(["tree"])
    trunk = _mesh(stage, "/Tree/Trunk", (-15, 0, -15), (15, 300, 15))
    _bind(trunk.GetPrim(), _material(stage, "/Tree/Looks/Bark", "bark.png"))
    inst = UsdGeom.PointInstancer.Define(stage, "/Tree/Leaves")
    leaf = _mesh(stage, "/Tree/Leaves/Protos/Leaf", (-LEAF / 2,) * 3, (LEAF / 2,) * 3)
    _bind(leaf.GetPrim(), _material(stage, "/Tree/Looks/Leaf", None, (0.2, 0.5, 0.15)))
    inst.CreatePrototypesRel().SetTargets([leaf.GetPath()])
    a = np.arange(6) * 2 * math.pi / 6
    pos = [Gf.Vec3f(LEAF_RING * math.cos(t), 340.0, LEAF_RING * math.sin(t)) for t in a]
    inst.CreatePositionsAttr(pos)
    inst.CreateProtoIndicesAttr([0] * len(pos))
    stage.GetRootLayer().Save()
    out = folder / f"{name}.usdz"
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(src)), str(out))
    for f in sorted(work.iterdir()):
        f.unlink()
    work.rmdir()
    return out


def write_bench(folder: str | Path, name: str = "park_bench", length: float = 1.6) -> Path:
    """A Z-up metre bench without a class label: a ``length`` x 0.5 m seat at 0.42-0.47 m on two legs."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.usda"
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    root = UsdGeom.Xform.Define(stage, "/Bench")
    stage.SetDefaultPrim(root.GetPrim())
    _mesh(stage, "/Bench/Seat", (-length / 2, -0.25, 0.42), (length / 2, 0.25, 0.47))
    for k, x in enumerate((-length / 2 + 0.1, length / 2 - 0.1)):
        _mesh(stage, f"/Bench/Leg_{k}", (x - 0.03, -0.2, 0.0), (x + 0.03, 0.2, 0.42))
    stage.GetRootLayer().Save()
    return path


def write_bad(folder: str | Path, kind: str) -> Path:
    """A refused asset: ``unlabelled``, ``sphere`` (implicit), ``index`` (face out of range),
    ``nan`` (non-finite point), ``flat`` (empty bounds), ``nomesh``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"bad_{kind}.usda"
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    root = UsdGeom.Xform.Define(stage, "/Thing")
    stage.SetDefaultPrim(root.GetPrim())
    if kind != "unlabelled":
        UsdSemantics.LabelsAPI.Apply(root.GetPrim(), "class").CreateLabelsAttr().Set(["bench"])
    if kind == "sphere":
        UsdGeom.Sphere.Define(stage, "/Thing/Ball")
    elif kind == "nomesh":
        UsdGeom.Xform.Define(stage, "/Thing/Empty")
    else:
        m = _mesh(stage, "/Thing/Box", (0, 0, 0), (1, 1, 1))
        if kind == "index":
            m.GetFaceVertexIndicesAttr().Set([0, 1, 3, 2, 4, 6, 7, 5, 0, 4, 5, 1, 2, 3, 7, 6, 0, 2, 6, 4, 1, 5, 7, 42])
        elif kind == "nan":
            pts = list(m.GetPointsAttr().Get())
            pts[3] = Gf.Vec3f(float("nan"), 0, 0)
            m.GetPointsAttr().Set(pts)
        elif kind == "flat":
            m.GetPointsAttr().Set([Gf.Vec3f(0, 0, 0)] * 8)
    stage.GetRootLayer().Save()
    return path
