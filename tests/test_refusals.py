"""Check before writing (issue 26 items 2 and 4): every refusal decidable from the stage and the options
comes before the output folder is created or touched, a refusal after that puts the folder back as it
was, and the same command after the fix succeeds. Implicit shapes (Sphere, Cylinder, Cone, Capsule,
Plane) get one decision everywhere: refused up front, in one line naming the prim; so do meshes lfusd
cannot draw and ray cast alike (face indices outside the points, non-finite points, degenerate faces).

Blender is stood in for (``fake_render``: the view folders a worker would commit), so these run in seconds."""

from __future__ import annotations

import json

import pytest
from pxr import Gf, Sdf, Usd, UsdGeom
from support.fake import fake_run_units
from support.cli import assert_one_line_error, run_cli
from support.scenes import write_box_stage

from lfusd.camera import RigSpec
from lfusd.errors import LfusdError
from lfusd.render import executors, job
from lfusd.truth import derive

RIG = RigSpec(name="main", rows=1, cols=2, width=16, height=12, baseline=0.1, at=(0, -5, 1), look_at=(0, 0, 0.5))
FAST = ("--samples", "1", "--device", "cpu", "--quiet")
IMPLICIT = {"Sphere": UsdGeom.Sphere, "Cylinder": UsdGeom.Cylinder, "Cone": UsdGeom.Cone, "Capsule": UsdGeom.Capsule,
            "Plane": UsdGeom.Plane}


@pytest.fixture
def fake_render(monkeypatch):
    """Blender workers stood in for: each unit's view folders appear with their completion record."""
    rendered = []

    run_units = fake_run_units(rendered)

    monkeypatch.setattr(executors, "run_units", run_units)
    monkeypatch.setattr(derive, "derive_dataset", lambda *a, **k: 0)
    return rendered


def snapshot(folder):
    return {str(p.relative_to(folder)): (None if p.is_dir() else p.read_bytes()) for p in sorted(folder.rglob("*"))}


def _stage(tmp_path, name="scene.usda"):
    path = tmp_path / name
    write_box_stage(path, [RIG])
    stage = Usd.Stage.Open(str(path))
    stage.SetEndTimeCode(4)
    return path, stage


def _triangle(stage, path):
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (1, 1, 0)])
    mesh.CreateFaceVertexCountsAttr([3])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2])
    return mesh


def _implicit(stage, kind, where):
    """A ``kind`` prim drawn plainly, inside a scenegraph instance's prototype, or as a point instancer's
    prototype; returns the path a refusal must name."""
    schema = IMPLICIT[kind]
    if where == "plain":
        schema.Define(stage, "/World/Thing")
        return "/World/Thing"
    if where == "instance":
        stage.CreateClassPrim("/Protos")
        UsdGeom.Xform.Define(stage, "/Protos/Lamp")
        _triangle(stage, "/Protos/Lamp/Pole")  # a mesh beside it does not hide it
        schema.Define(stage, "/Protos/Lamp/Shade")
        inst = UsdGeom.Xform.Define(stage, "/World/Lamp_01").GetPrim()
        inst.GetReferences().AddInternalReference("/Protos/Lamp")
        inst.SetInstanceable(True)
        return "/World/Lamp_01/Shade"
    pi = UsdGeom.PointInstancer.Define(stage, "/World/Scatter")
    UsdGeom.Scope.Define(stage, "/World/Scatter/Protos")
    schema.Define(stage, "/World/Scatter/Protos/Pebble")
    pi.CreatePrototypesRel().SetTargets([Sdf.Path("/World/Scatter/Protos/Pebble")])
    pi.CreatePositionsAttr([Gf.Vec3f(0, 0, 0), Gf.Vec3f(1, 0, 0)])
    pi.CreateProtoIndicesAttr([0, 0])
    return "/World/Scatter/Protos/Pebble"


@pytest.mark.parametrize("where", ["plain", "instance", "instancer"])
@pytest.mark.parametrize("kind", list(IMPLICIT))
def test_implicit_shapes_are_refused_up_front_naming_the_prim(capsys, tmp_path, kind, where, fake_render):
    path, stage = _stage(tmp_path)
    named = _implicit(stage, kind, where)
    stage.Save()
    for command in ("render", "render-video"):
        out = tmp_path / f"out-{command}"
        code, _, err = run_cli(capsys, command, path, "-o", out, *FAST)
        assert_one_line_error(code, err, named, f"is a {kind}", "convert it to a Mesh")
        assert code == 2 and not out.exists(), command  # nothing written, not even the folder
    assert not fake_render


BAD_MESHES = {
    "index out of range": (lambda m: m.CreateFaceVertexIndicesAttr([0, 1, 7]), "face index 7 outside its 3 points"),
    "negative index": (lambda m: m.CreateFaceVertexIndicesAttr([0, -1, 2]), "face index -1 outside"),
    "degenerate face": (lambda m: (m.CreateFaceVertexCountsAttr([2, 1]), m.CreateFaceVertexIndicesAttr([0, 1, 2])), "degenerate face"),
    "counts do not add up": (lambda m: m.CreateFaceVertexCountsAttr([4]), "add up to 4"),
    "NaN point": (lambda m: m.CreatePointsAttr([(0, 0, 0), (1, 0, float("nan")), (1, 1, 0)]), "non-finite points"),
    # animated points: the bad value only at frame 3
    "inf point in a time sample": (lambda m: [m.GetPointsAttr().Set([(0, 0, 0), (1, 0, 0), (1, 1, f == 3 and float("inf") or 0)], f)
                                             for f in (1, 2, 3, 4)], "non-finite points (NaN or inf) at frame 3"),
}


@pytest.mark.parametrize("case", list(BAD_MESHES))
def test_a_broken_mesh_is_one_line_naming_the_prim_in_render_and_check(capsys, tmp_path, case, fake_render):
    path, stage = _stage(tmp_path)
    mesh = _triangle(stage, "/World/Scan")
    damage, words = BAD_MESHES[case]
    damage(mesh)
    stage.Save()
    out = tmp_path / "out"
    code, _, err = run_cli(capsys, "render-video", path, "-o", out, *FAST)
    assert_one_line_error(code, err, "mesh /World/Scan", words)
    assert code == 2 and not out.exists()
    code, text, err = run_cli(capsys, "check", path, "--no-usd-validation", "--no-coverage")
    assert_one_line_error(code, err, "mesh /World/Scan", words)  # was an internal IndexError
    assert code == 2 and text == ""


NAN = float("nan")
BAD_TRANSFORMS = {
    # a mover whose translate is NaN at frame 3 only (the case of the issue)
    "translate at a frame": (lambda st: [UsdGeom.Xformable(st.GetPrimAtPath("/World/BoxB")).GetOrderedXformOps()[0].Set(
        Gf.Vec3d(0, 0, NAN if f == 3 else 0.5), f) for f in (1, 2, 3, 4)], "/World/BoxB", "at frame 3"),
    "scale default": (lambda st: UsdGeom.Xformable(_triangle(st, "/World/Scan")).AddScaleOp().Set(Gf.Vec3f(1, float("inf"), 1)),
                      "/World/Scan", "its default value"),
    "camera rotate": (lambda st: UsdGeom.Xformable(next(p for p in st.Traverse() if p.IsA(UsdGeom.Camera))).AddRotateZOp(
        opSuffix="tilt").Set(NAN), "", "xformOp:rotateZ:tilt"),
    "instancer position": (lambda st: _instancer(st, [(0, 0, 0), (NAN, 0, 0)]), "/World/Pi", "positions"),
}


def _instancer(stage, positions):
    pi = UsdGeom.PointInstancer.Define(stage, "/World/Pi")
    UsdGeom.Cube.Define(stage, "/World/Pi/Protos/Cube")
    pi.CreatePrototypesRel().SetTargets(["/World/Pi/Protos/Cube"])
    pi.CreateProtoIndicesAttr([0] * len(positions))
    pi.CreatePositionsAttr(positions)


@pytest.mark.parametrize("case", list(BAD_TRANSFORMS))
def test_a_non_finite_transform_is_refused_up_front_in_render_and_check(capsys, tmp_path, case, fake_render):
    """Issue 39 item 7: a NaN transform rendered, then failed with a hint to delete frame.json and left
    41 files, while `lfusd check` said nothing; refused before anything is written, in one line
    naming the prim, by render, render-video and check."""
    path, stage = _stage(tmp_path)
    damage, prim, words = BAD_TRANSFORMS[case]
    damage(stage)
    stage.Save()
    out = tmp_path / "out"
    for command in ("render", "render-video"):
        code, _, err = run_cli(capsys, command, path, "-o", out, *FAST)
        assert_one_line_error(code, err, prim, "not finite", words)
        assert code == 2 and not out.exists() and fake_render == []
    code, text, err = run_cli(capsys, "check", path, "--no-usd-validation", "--no-coverage")
    assert_one_line_error(code, err, prim, "not finite", words)
    assert code == 2 and text == ""


def _broken_reference(stage, path):
    stage.DefinePrim("/World/Chair").GetReferences().AddReference("./models/chair.usda")  # no such file


def _sublayer_cycle(stage, path):
    other = Sdf.Layer.CreateNew(str(path.with_name("lights.usda")))
    other.subLayerPaths.append(path.name)  # lights.usda -> scene.usda -> lights.usda
    other.Save()
    stage.GetRootLayer().subLayerPaths.append("lights.usda")


def _both(stage, path):
    _sublayer_cycle(stage, path)
    _broken_reference(stage, path)


@pytest.mark.parametrize("damage,words", [(_broken_reference, "Could not open asset @"), (_sublayer_cycle, "has cycles"),
                                          (_both, "(and 1 more: `lfusd check")])
def test_a_stage_that_does_not_compose_is_said_in_one_line_by_render(capsys, tmp_path, damage, words, fake_render):
    """Issue 39 item 9: a broken reference or a sublayer cycle rendered with exit 0 and pxr's raw
    diagnostics; render and render-video now say in one line that the stage does not compose, what
    that means for the render and the fix (the render goes on: a wild stage's missing reference
    renders as in issue 12, tests/render/test_wild_materials.py)."""
    path, stage = _stage(tmp_path)
    damage(stage, path)
    stage.Save()
    for command in ("render", "render-video"):
        code, _, err = run_cli(capsys, command, path, "-o", tmp_path / command, *FAST)
        assert code == 0, err
        said = [ln for ln in err.splitlines() if "compose" in ln or "Could not open" in ln or "cycles" in ln]
        assert len(said) == 1 and said[0].startswith("lfusd: warning: stage ") and "does not compose" in said[0], err
        assert words in said[0] and "fix or remove that reference or sublayer" in said[0]  # two errors: one line still


def test_the_issues_instanced_sphere_leaves_nothing_and_renders_once_converted(capsys, tmp_path, fake_render):
    """Main wrote .lock, manifest.json, objects.json and frame.json before refusing; the fixed stage was
    then told the dataset had changed."""
    path, stage = _stage(tmp_path)
    _implicit(stage, "Sphere", "instance")
    stage.Save()
    out = tmp_path / "out"
    out.mkdir()  # an empty folder the user made: it stays, empty
    code, _, err = run_cli(capsys, "render", path, "-o", out, *FAST)
    assert_one_line_error(code, err, "/World/Lamp_01/Shade", "convert it to a Mesh")
    assert list(out.iterdir()) == []
    # the fix: the shade becomes a mesh
    stage = Usd.Stage.Open(str(path))
    stage.RemovePrim("/Protos/Lamp/Shade")
    _triangle(stage, "/Protos/Lamp/Shade")
    stage.Save()
    code, _, err = run_cli(capsys, "render", path, "-o", out, *FAST)
    assert code == 0, err
    assert sorted(fake_render) == [(1, "00_00"), (1, "00_01")]


@pytest.mark.parametrize("start", ["absent", "empty", "dataset"])
def test_a_refusal_after_writing_started_puts_the_folder_back(capsys, tmp_path, monkeypatch, fake_render, start):
    """A refusal that comes after the folder is written (here: a frame's metadata cannot be computed)
    leaves it as it was: absent, empty, or the dataset it held with its manifest; the rerun succeeds."""
    path, stage = _stage(tmp_path)
    stage.Save()
    out = tmp_path / "out"
    if start == "empty":
        out.mkdir()
    if start == "dataset":
        assert run_cli(capsys, "render", path, "-o", out, "--frame", "1", *FAST)[0] == 0
    before = snapshot(out) if out.exists() else None
    real = job._write_static_metadata

    def failing(req, stage, rigs, frames, *a, **k):
        real(req, stage, rigs, frames, *a, **k)  # objects.json and frame.json written, then a refusal
        raise LfusdError("frame 3 cannot be evaluated; fix the stage")

    monkeypatch.setattr(job, "_write_static_metadata", failing)
    code, _, err = run_cli(capsys, "render", path, "-o", out, "--frame", "3", *FAST)
    assert_one_line_error(code, err, "frame 3 cannot be evaluated")
    assert (snapshot(out) if out.exists() else None) == before
    monkeypatch.setattr(job, "_write_static_metadata", real)
    code, _, err = run_cli(capsys, "render", path, "-o", out, "--frame", "3", *FAST)
    assert code == 0, err
    assert json.loads((out / "manifest.json").read_text())["frames"] == ([1, 3] if start == "dataset" else [3])


@pytest.mark.parametrize("argv, words", [
    (("--keys", "rgb,dpeth"), "dpeth"),
    (("--resolution", "100000x100000"), "--resolution"),
    (("--rig", "nosuchrig"), "nosuchrig"),
])
def test_refusals_from_the_options_touch_nothing(capsys, tmp_path, fake_render, argv, words):
    path, stage = _stage(tmp_path)
    stage.Save()
    out = tmp_path / "out"
    code, _, err = run_cli(capsys, "render", path, "-o", out, *FAST, *argv)
    assert_one_line_error(code, err, words)
    assert code == 2 and not out.exists()
