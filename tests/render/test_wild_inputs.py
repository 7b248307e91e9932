"""Any USD file is an input: .usdc and .usdz assets rigged in a new layer over them, payloads and
variant selections, and static stages rendered as videos and verified (issue 12).

Each stage is authored here; rigs go in through the CLI (`lfusd rig add ASSET ... -o scene.usda`);
:func:`support.wild.render_and_verify` renders and verifies, then one closed-form depth is
checked against the dataset: the planar depth of a box face's centre seen by each view.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, UsdUtils

from lfusd.author.labels import set_class_label
from lfusd.author.scenes.textures import write_png
from lfusd.cli import main
from lfusd.camera import RigSpec
from lfusd.truth.verify import verify
from support.cli import run_cli
from support.scenes import write_motion_stage
from support.wild import STATIC_KEYS, render_and_verify

pytestmark = pytest.mark.render

# A box standing on z = 0, its front face (towards -y) facing the rig.
EDGE = 1.0
RIG = ["--grid", "2x2", "--resolution", "32x32", "--baseline", "0.1", "--at", "0.05,-4,0.6", "--look-at", "0.05,0,0.6"]


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _box(stage: Usd.Stage, path: str, edge: float) -> UsdGeom.Mesh:
    """A box mesh x, y in [-edge/2, edge/2], z in [0, edge], with UVs on every face."""
    h = edge / 2
    corners = [(x, y, z) for z in (0.0, edge) for y in (-h, h) for x in (-h, h)]
    # Corner x + 2y + 4z; faces counter-clockwise seen from outside (USD's right-handed default).
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr([Gf.Vec3f(*c) for c in corners])
    mesh.CreateFaceVertexCountsAttr([4] * 6)
    mesh.CreateFaceVertexIndicesAttr([i for q in quads for i in q])
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    st.Set([Gf.Vec2f(*uv) for _ in quads for uv in ((0, 0), (1, 0), (1, 1), (0, 1))])
    return mesh


def _textured(stage: Usd.Stage, mesh: UsdGeom.Mesh, texture: str) -> None:
    """Bind a UsdPreviewSurface that emits the PNG ``texture`` (a path relative to the layer) and
    reflects nothing, so the rendered colour is the texture's whatever the lighting."""
    mat = UsdShade.Material.Define(stage, "/World/Looks/Checker")
    shader = UsdShade.Shader.Define(stage, "/World/Looks/Checker/Surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    reader = UsdShade.Shader.Define(stage, "/World/Looks/Checker/ST")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
    tex = UsdShade.Shader.Define(stage, "/World/Looks/Checker/Texture")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(texture)
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.0, 0.0, 0.0))
    shader.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
    mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)


def _world(path: Path, *, time_range: tuple[int, int] | None) -> Usd.Stage:
    """A Z-up metre stage with /World as default prim, a sun, and a time range only if given."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    if time_range:
        stage.SetStartTimeCode(time_range[0])
        stage.SetEndTimeCode(time_range[1])
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(1.0)
    sun.CreateNormalizeAttr(True)
    UsdGeom.XformCommonAPI(sun).SetRotate(Gf.Vec3f(30.0, 20.0, 0.0))
    return stage


def write_box_asset(path: Path, *, texture: bool = False, time_range: tuple[int, int] | None = None) -> None:
    """A static asset: one labelled EDGE box at the origin (textured with a PNG beside it if asked)."""
    stage = _world(path, time_range=time_range)
    mesh = _box(stage, "/World/Box", EDGE)
    set_class_label(mesh.GetPrim(), "crate")
    if texture:
        # Dark for u < 0.5, bright above: on the front face u runs along +x, left to right in the views.
        halves = np.where(np.arange(64)[None, :, None] < 32, 20, 235) * np.ones((64, 1, 3))
        write_png(path.parent / "halves.png", halves.astype(np.uint8))
        _textured(stage, mesh, "./halves.png")
    stage.GetRootLayer().Save()


def rig_over(asset: Path, scene: Path) -> None:
    """`lfusd rig add ASSET --name main ... -o scene`, asserting the asset's bytes stay the same."""
    before = _sha(asset)
    assert main(["rig", "add", str(asset), "--name", "main", *RIG, "-o", str(scene)]) == 0
    assert _sha(asset) == before, f"rig add -o changed {asset}"


def assert_face_depth(ds, centre: np.ndarray, frame: int = 1) -> None:
    """At the pixel nearest where ``centre`` (world, on a face seen head-on) projects, the rendered
    depth is the centre's planar depth in that view (the face is fronto-parallel: depth is the
    same over the whole pixel)."""
    for view in ds.views:
        K, c2w = ds.intrinsics(view), ds.cam_to_world(frame, view)
        p = np.linalg.inv(c2w) @ np.append(centre, 1.0)
        z = p[2]
        u, v = (K @ (p[:3] / z))[:2]
        depth = ds.read(frame, view, "depth")[int(round(v)), int(round(u))]
        assert abs(depth - z) <= 1e-4 * z, f"view {view}: depth {depth} at ({u:.1f}, {v:.1f}), expected {z}"


FRONT_CENTRE = np.array([0.0, -EDGE / 2, EDGE / 2])


def test_usdc_asset_rigged_in_a_new_layer_renders_static_sequence(tmp_path):
    asset = tmp_path / "asset" / "box.usdc"
    asset.parent.mkdir()
    write_box_asset(asset, time_range=(1, 1))  # a one-frame range, rendered over 1-3: static stages take any frames
    scene = tmp_path / "scene.usda"
    rig_over(asset, scene)
    assert Sdf.Layer.FindOrOpen(str(scene)).subLayerPaths == ["./asset/box.usdc"]
    ds, reports = render_and_verify(scene, tmp_path / "out", "--frames", "1-3")
    assert ds.frames == [1, 2, 3]
    assert_face_depth(ds, FRONT_CENTRE)
    # Nothing moves: the forward flow is zero wherever it is valid, and verify compared it.
    valid = 0
    for f in (1, 2):
        for view in ds.views:
            flow, ok = ds.read(f, view, "flow_fwd"), ds.read(f, view, "valid_fwd").astype(bool)
            assert np.abs(flow[ok]).max() < 1e-3
            valid += int(ok.sum())
    assert valid > 0
    assert reports["main"].compared()["flow_fwd"] > 0


def test_usdz_asset_with_texture_rigged_in_a_new_layer(tmp_path):
    src = tmp_path / "src" / "box.usda"
    src.parent.mkdir()
    write_box_asset(src, texture=True)  # no authored time range at all
    asset = tmp_path / "box.usdz"
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(src)), str(asset))
    scene = tmp_path / "scene.usda"
    rig_over(asset, scene)
    ds, _ = render_and_verify(scene, tmp_path / "out", "--frames", "1-3")
    assert_face_depth(ds, FRONT_CENTRE, frame=2)
    # The texture came through the package: the face's left half is dark, its right half bright.
    box = next(i for i, o in ds.objects.items() if o.prim_path == "/World/Box")
    rgb = ds.read(1, (0, 0), "rgb").astype(float).mean(axis=-1)
    face = ds.read(1, (0, 0), "instance") == box
    cols = np.nonzero(face)[1]
    mid, u = (cols.min() + cols.max()) / 2, np.arange(face.shape[1])[None, :]
    left, right = rgb[face & (u < mid - 1)].mean(), rgb[face & (u > mid + 1)].mean()
    assert left < 80 < 150 < right, f"the box does not show its texture (left half {left:.0f}, right half {right:.0f})"


def test_payload_with_selected_variant(tmp_path):
    """/World/Thing's payload is a unit box; its variant set `size` scales it (small 0.5, large 2)."""
    part = tmp_path / "parts" / "box.usda"
    part.parent.mkdir()
    write_box_asset(part)
    root = _world(tmp_path / "root.usda", time_range=None)
    thing = UsdGeom.Xform.Define(root, "/World/Thing")
    thing.GetPrim().GetPayloads().AddPayload("./parts/box.usda")  # its default prim, /World
    vset = thing.GetPrim().GetVariantSets().AddVariantSet("size")
    for name, scale in (("small", 0.5), ("large", 2.0)):
        vset.AddVariant(name)
        vset.SetVariantSelection(name)
        with vset.GetVariantEditContext():
            UsdGeom.XformCommonAPI(thing).SetScale(Gf.Vec3f(scale, scale, scale))
    vset.SetVariantSelection("large")
    root.GetRootLayer().Save()
    assert main(["rig", "add", str(root.GetRootLayer().realPath), "--name", "main", *RIG]) == 0  # in place: a .usda
    ds, _ = render_and_verify(tmp_path / "root.usda", tmp_path / "out", "--frames", "1-2")
    large = 2.0 * EDGE
    # Large: its front face's centre (0, -1, 1) at planar depth 3; the small box would not cover that pixel.
    assert_face_depth(ds, np.array([0.0, -large / 2, large / 2]))


# What verify checks on a frame without rendered neighbours besides STATIC_KEYS (issue 37): the
# normal's side, the semantic class, and that no pixel is called valid for motion.
LONE_FRAME_CHECKS = {"normal", "semantic", "valid_fwd", "valid_bwd"}


def test_static_asset_single_frame_verifies_static_keys(tmp_path):
    asset = tmp_path / "box.usdc"
    write_box_asset(asset)
    scene = tmp_path / "scene.usda"
    rig_over(asset, scene)
    ds, reports = render_and_verify(scene, tmp_path / "out", "--frames", "1", keys=STATIC_KEYS)
    assert ds.frames == [1]
    # the static keys, and the records of a lone frame: no motion value (valid_* must all be unset)
    assert set(reports["main"].compared()) == set(STATIC_KEYS) | LONE_FRAME_CHECKS
    assert_face_depth(ds, FRONT_CENTRE)


def test_verify_of_one_frame_of_an_animated_stage_compares_its_static_keys(tmp_path, capsys):
    stage, out = tmp_path / "moving.usda", tmp_path / "out"
    rig = RigSpec(name="main", rows=2, cols=2, width=64, height=48, baseline=0.1, at=(0.2, -5.0, 1.6), look_at=(0.0, 0.0, 0.6))
    write_motion_stage(stage, rig, frames=3)
    assert main(["render", str(stage), "-o", str(out), "--frame", "2", "--samples", "1", "--device", "cpu", "--quiet"]) == 0
    code, text, err = run_cli(capsys, "verify", out)
    assert code == 0, text + err
    assert "all checks passed" in text
    compared = verify(out)["main"].compared()
    # a still render has no motion keys at all: no valid_* to check either
    assert set(compared) == set(STATIC_KEYS) | {"normal", "semantic"} and all(n > 0 for n in compared.values()), compared


def test_subdivision_surface_renders_and_verifies_its_cage_with_one_warning_naming_it(tmp_path, capfd):
    """A catmullClark box with a crease (as in USD's sample assets): render-video and verify both
    see its control cage (the depth of the cage's front-face centre, which the smooth limit surface
    lies well behind) and each says so once, naming the prim."""
    import subprocess
    import sys

    asset = tmp_path / "box.usda"
    write_box_asset(asset)
    stage = Usd.Stage.Open(str(asset))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Box"))
    mesh.GetSubdivisionSchemeAttr().Set(UsdGeom.Tokens.catmullClark)
    mesh.CreateCreaseIndicesAttr([0, 2])
    mesh.CreateCreaseLengthsAttr([2])
    mesh.CreateCreaseSharpnessesAttr([10.0])
    stage.GetRootLayer().Save()
    scene = tmp_path / "scene.usda"
    rig_over(asset, scene)
    capfd.readouterr()
    ds, _ = render_and_verify(scene, tmp_path / "out", "--frames", "1", keys=STATIC_KEYS)
    assert_face_depth(ds, FRONT_CENTRE)
    rendered = capfd.readouterr().err
    needle = "mesh /World/Box has subdivisionScheme catmullClark: lfusd renders and verifies its control cage"
    assert rendered.count(needle) == 1, rendered
    # verify in a process of its own, as a user runs it after rendering
    run = subprocess.run([sys.executable, "-m", "lfusd", "verify", str(tmp_path / "out")], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert run.stderr.count(needle) == 1, run.stderr
