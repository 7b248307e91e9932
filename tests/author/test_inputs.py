"""Any USD file is an input (issue 12): lfusd writes rigs and people into a new layer over an asset,
never into it; a stage with no time samples is static and takes any frame."""

from __future__ import annotations

import hashlib
import os

import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdSkel, UsdUtils

from lfusd.author.labels import set_class_label
from lfusd.author.rigs import rigs
from lfusd.author.stage import check_frames, frame_range, is_static, layer_over, open_for_edit
from lfusd.errors import LfusdError
from support.cli import assert_one_line_error, run_cli

RIG = ["--grid", "2x2", "--resolution", "32x32", "--at", "0,-3,1", "--look-at", "0,0,0.5"]


def _sha(path) -> str:
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


def y_up_cm_asset(path, *, samples: bool = False):
    """An asset as DCC tools write them: Y up, centimetres, 30 time codes per second, frames 10-40."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    stage.SetTimeCodesPerSecond(30)
    stage.SetFramesPerSecond(30)
    stage.SetStartTimeCode(10)
    stage.SetEndTimeCode(40)
    root = UsdGeom.Xform.Define(stage, "/Asset")
    stage.SetDefaultPrim(root.GetPrim())
    mesh = UsdGeom.Mesh.Define(stage, "/Asset/Ground")
    mesh.CreatePointsAttr([(-500, 0, -500), (500, 0, -500), (500, 0, 500), (-500, 0, 500)])
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 3, 2, 1])
    set_class_label(mesh.GetPrim(), "ground")
    if samples:
        op = UsdGeom.Xformable(root).AddTranslateOp()
        op.Set(Gf.Vec3d(0, 0, 0), 10)
        op.Set(Gf.Vec3d(0, 0, 100), 40)
    stage.GetRootLayer().Save()
    return path


def usdz_of(src, dest):
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(src)), str(dest))
    return dest


def test_rig_add_over_an_asset_writes_a_new_layer_keeping_its_metadata(tmp_path, capsys):
    (tmp_path / "assets").mkdir()
    asset = y_up_cm_asset(tmp_path / "assets" / "thing.usdc")
    before = _sha(asset)
    scene = tmp_path / "shots" / "scene.usda"
    scene.parent.mkdir()
    code, out, err = run_cli(capsys, "rig", "add", asset, "--name", "r", *RIG, "-o", scene)
    assert code == 0, err
    assert "scene.usda" in out and "thing.usdc" in out
    assert _sha(asset) == before
    layer = Sdf.Layer.FindOrOpen(str(scene))
    assert layer.subLayerPaths == ["../assets/thing.usdc"]  # relative: the pair moves together
    stage = Usd.Stage.Open(str(scene))
    src = Usd.Stage.Open(str(asset))
    assert UsdGeom.GetStageUpAxis(stage) == "Y" and UsdGeom.GetStageMetersPerUnit(stage) == 0.01
    assert (stage.GetTimeCodesPerSecond(), stage.GetFramesPerSecond()) == (30, 30)
    assert frame_range(stage) == frame_range(src) == (10, 40)
    assert stage.GetDefaultPrim().GetPath() == "/Asset"
    assert stage.GetPrimAtPath("/Asset/Ground").IsA(UsdGeom.Mesh)
    assert list(rigs(stage)) == ["r"] and not rigs(src)
    # The rig lives in the new layer only.
    assert layer.GetPrimAtPath("/Rigs/r") and not Sdf.Layer.FindOrOpen(str(asset)).GetPrimAtPath("/Rigs")


def test_rig_add_over_a_usdz_needs_o_and_then_leaves_the_package_alone(tmp_path, capsys):
    asset = usdz_of(y_up_cm_asset(tmp_path / "thing.usda"), tmp_path / "thing.usdz")
    before = _sha(asset)
    code, _, err = run_cli(capsys, "rig", "add", asset, "--name", "r", *RIG)
    assert_one_line_error(code, err, "thing.usdz", "package is read-only", "-o scene.usda")
    assert _sha(asset) == before
    scene = tmp_path / "scene.usda"
    code, _, err = run_cli(capsys, "rig", "add", asset, "--name", "r", *RIG, "-o", scene)
    assert code == 0, err
    assert _sha(asset) == before
    stage = Usd.Stage.Open(str(scene))
    assert list(rigs(stage)) == ["r"] and stage.GetPrimAtPath("/Asset/Ground")
    # A second rig goes into the new layer in place: it is a .usda.
    code, _, err = run_cli(capsys, "rig", "add", scene, "--name", "r2", *RIG)
    assert code == 0, err
    assert sorted(rigs(Usd.Stage.Open(str(scene)))) == ["r", "r2"] and _sha(asset) == before


@pytest.mark.parametrize("out,needle", [("existing.usda", "already exists; edit it in place by dropping -o"),
                                        ("scene.usdz", "is not a .usda/.usdc/.usd file"),
                                        ("missing/scene.usda", "does not exist")])
def test_bad_o_is_a_one_line_error_and_writes_nothing(tmp_path, capsys, out, needle):
    asset = y_up_cm_asset(tmp_path / "thing.usda")
    (tmp_path / "existing.usda").write_text("#usda 1.0\n")
    files = sorted(p.name for p in tmp_path.iterdir())
    code, _, err = run_cli(capsys, "rig", "add", asset, "--name", "r", *RIG, "-o", tmp_path / out)
    assert_one_line_error(code, err, needle)
    assert sorted(p.name for p in tmp_path.iterdir()) == files
    assert (tmp_path / "existing.usda").read_text() == "#usda 1.0\n"


def test_failed_rig_add_leaves_no_new_layer(tmp_path, capsys):
    asset = y_up_cm_asset(tmp_path / "thing.usda")
    assert run_cli(capsys, "rig", "add", asset, "--name", "r", *RIG)[0] == 0  # in place
    code, _, err = run_cli(capsys, "rig", "add", asset, "--name", "r", *RIG, "-o", tmp_path / "scene.usda")
    assert_one_line_error(code, err, "already has a rig named 'r'")
    assert not (tmp_path / "scene.usda").exists()


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root writes read-only files")
def test_read_only_stage_without_o_is_refused(tmp_path):
    asset = y_up_cm_asset(tmp_path / "thing.usda")
    asset.chmod(0o444)
    with pytest.raises(LfusdError, match="read-only.*-o scene.usda"):
        open_for_edit(asset)


def test_add_person_over_a_usdz_in_a_new_layer(tmp_path, capsys):
    src = tmp_path / "src" / "ground.usda"
    src.parent.mkdir()
    stage = Usd.Stage.CreateNew(str(src))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(24)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    mesh = UsdGeom.Mesh.Define(stage, "/World/Ground")
    mesh.CreatePointsAttr([(-10, -10, 0), (10, -10, 0), (10, 10, 0), (-10, 10, 0)])
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    set_class_label(mesh.GetPrim(), "ground")
    stage.Save()
    asset = usdz_of(src, tmp_path / "ground.usdz")
    before = _sha(asset)
    code, _, err = run_cli(capsys, "animate", "add-person", asset, "--path", "-2,0", "2,0")
    assert_one_line_error(code, err, "package is read-only", "-o scene.usda")
    scene = tmp_path / "scene.usda"
    code, out, err = run_cli(capsys, "animate", "add-person", asset, "--path", "-2,0", "2,0", "-o", scene)
    assert code == 0, err
    assert _sha(asset) == before
    composed = Usd.Stage.Open(str(scene))
    assert frame_range(composed) == (1, 24)
    assert composed.GetPrimAtPath("/World/People/Person_00").IsA(UsdSkel.Root)
    assert not is_static(composed)


def test_static_means_no_time_sample_in_any_used_layer(tmp_path):
    static = y_up_cm_asset(tmp_path / "static.usda")
    moving = y_up_cm_asset(tmp_path / "moving.usda", samples=True)
    assert is_static(Usd.Stage.Open(str(static))) and not is_static(Usd.Stage.Open(str(moving)))
    # Samples reached through a reference, a payload or a layer over the asset count.
    by_reference = Usd.Stage.CreateInMemory()
    by_reference.DefinePrim("/Thing").GetReferences().AddReference(str(moving))
    by_payload = Usd.Stage.CreateInMemory()
    by_payload.DefinePrim("/Thing").GetPayloads().AddPayload(str(moving))
    assert not is_static(by_reference) and not is_static(by_payload)
    assert not is_static(layer_over(moving, tmp_path / "over.usda"))
    assert is_static(layer_over(static, tmp_path / "over.usda"))


def test_static_stage_takes_any_frame_an_animated_one_only_its_range(tmp_path):
    static = Usd.Stage.Open(str(y_up_cm_asset(tmp_path / "static.usda")))
    moving = Usd.Stage.Open(str(y_up_cm_asset(tmp_path / "moving.usda", samples=True)))
    check_frames(static, [1, 2, 3, 500], "static.usda")  # its authored range is 10-40
    check_frames(moving, [10, 40], "moving.usda")
    with pytest.raises(LfusdError, match="frame 41 is outside stage moving.usda's range 10-40"):
        check_frames(moving, [40, 41], "moving.usda")
