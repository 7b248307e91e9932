"""The Infinigen baker (issue 25 item 5): lfusd.author.bake's clean-up on an asset the test authors
in Infinigen's export shape (tests/support/infinigen_assets.py), not on Infinigen itself, and
`lfusd assets bake` with a stand-in for Infinigen's interpreter, or without one. Expected values are
the authored asset's: its dimensions, and its own geometry as pxr computes it, moved by LIFT."""

from __future__ import annotations

import json
import os
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Usd, UsdGeom, UsdLux, UsdShade
from support.cli import assert_one_line_error, run_cli
from support.infinigen_assets import LEG, LIFT, PANE, TOP, TRIANGLES, write_infinigen_table

from lfusd.author.bake import LICENCE_INFINIGEN, PYTHON_ENV, clean_asset
from lfusd.author.catalogue import load_catalogue
from lfusd.errors import LfusdError

TESTS = Path(__file__).resolve().parents[1]


def _world_points(stage) -> np.ndarray:
    """Every drawn mesh point in the stage's frame, instances included, sorted (order-free comparison)."""
    cache = UsdGeom.XformCache()
    pts = []
    for prim in Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)):
        if prim.IsA(UsdGeom.Mesh):
            m = np.array(cache.GetLocalToWorldTransform(prim))
            p = np.asarray(UsdGeom.Mesh(prim).GetPointsAttr().Get(), float)
            pts.append(p @ m[:3, :3] + m[3, :3])
    p = np.concatenate(pts)
    return p[np.lexsort(p.T[::-1])]


def _texture_feeding(stage, material: str, input_name: str) -> UsdShade.Shader:
    surface = UsdShade.Material(stage.GetPrimAtPath(material)).ComputeSurfaceSource()[0]
    src = surface.GetInput(input_name).GetConnectedSources()[0][0]
    return UsdShade.Shader(src.source.GetPrim())


@pytest.fixture(scope="module")
def cleaned(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("bake")
    raw = write_infinigen_table(tmp / "export")
    report = clean_asset(raw, tmp / "clean" / "table.usdc", cls="table", licence=LICENCE_INFINIGEN)
    return raw, tmp / "clean" / "table.usdc", report


def test_clean_up_counts_each_fix(cleaned):
    _, _, report = cleaned
    # one dome; roughness, metallic, normal textures; one normal map (and its float3 input); one glass;
    # four identical legs and two identical twigs
    assert report.counts == {"lights": 1, "colour_spaces": 3, "normal_maps": 1, "types": 1, "glass": 1, "grounded": 1,
                             "instanced": 6}
    assert report.triangles == TRIANGLES
    assert report.ground_shift == pytest.approx(-LIFT, abs=1e-9)
    assert len(report.notes) == sum(report.counts.values()) - report.counts["instanced"] + 2  # one note per group


def test_data_textures_are_raw_and_normal_maps_get_scale_and_bias(cleaned):
    raw, clean, _ = cleaned
    before, after = Usd.Stage.Open(str(raw)), Usd.Stage.Open(str(clean))
    wood = "/World/_materials/wood"
    for name in ("roughness", "metallic", "normal"):
        assert _texture_feeding(before, wood, name).GetInput("sourceColorSpace").Get() == "sRGB"
        assert _texture_feeding(after, wood, name).GetInput("sourceColorSpace").Get() == "raw", name
    assert _texture_feeding(after, wood, "diffuseColor").GetInput("sourceColorSpace").Get() == "sRGB"  # a colour stays sRGB
    normal = _texture_feeding(after, wood, "normal")
    assert normal.GetInput("scale").Get() == Gf.Vec4f(2, 2, 2, 1)
    assert normal.GetInput("bias").Get() == Gf.Vec4f(-1, -1, -1, 0)
    # a flat texel (128, 128, 255)/255 now decodes to the surface's own normal
    texel = np.array([128, 128, 255, 255]) / 255.0
    decoded = texel * np.array(normal.GetInput("scale").Get()) + np.array(normal.GetInput("bias").Get())
    assert np.allclose(decoded[:3], [0, 0, 1], atol=0.01)
    surface = UsdShade.Material(after.GetPrimAtPath(wood)).ComputeSurfaceSource()[0]
    assert surface.GetInput("normal").GetTypeName() == "normal3f" and surface.GetInput("normal").HasConnectedSource()


def test_glass_becomes_lfusds_glass_and_lights_are_gone(cleaned):
    _, clean, _ = cleaned
    stage = Usd.Stage.Open(str(clean))
    glass = UsdShade.Material(stage.GetPrimAtPath("/World/_materials/glass")).ComputeSurfaceSource()[0]
    assert glass.GetInput("opacity").Get() == pytest.approx(0.3)
    assert glass.GetInput("ior").Get() == pytest.approx(1.5)
    assert glass.GetInput("roughness").Get() == pytest.approx(0.05)
    assert not [p for p in stage.Traverse() if p.HasAPI(UsdLux.LightAPI)]


def test_grounded_and_instanced_without_moving_a_point(cleaned):
    raw, clean, _ = cleaned
    before, after = Usd.Stage.Open(str(raw)), Usd.Stage.Open(str(clean))
    p0, p1 = _world_points(before), _world_points(after)
    assert p0[:, 2].min() == pytest.approx(LIFT, abs=1e-6)
    assert p1.shape == p0.shape
    assert np.allclose(p1, p0 - [0, 0, LIFT], atol=1e-6)  # the same surfaces, moved down by LIFT
    assert p1[:, 2].min() == pytest.approx(0.0, abs=1e-6)
    assert p1[:, 2].max() == pytest.approx(LEG + TOP[2] + PANE[2], abs=1e-6)
    twigs = [after.GetPrimAtPath(f"/World/twig_00{k}/twig_00{k}") for k in (1, 2)]
    legs = [after.GetPrimAtPath(f"/World/leg_00{k}/leg_00{k}") for k in range(4)]
    for group in (twigs, legs):
        assert all(p.IsInstance() for p in group)
        assert len({p.GetPrototype().GetPath() for p in group}) == 1  # one stored mesh per group
    assert not after.GetPrimAtPath("/World/top/top").IsInstance()  # unique meshes stay as they were
    # the twig inside its instance keeps its bark material (copied into the prototype)
    mesh = next(c for c in Usd.PrimRange(twigs[0], Usd.TraverseInstanceProxies()) if c.IsA(UsdGeom.Mesh))
    mat = UsdShade.MaterialBindingAPI(mesh).ComputeBoundMaterial()[0]
    colour = mat.ComputeSurfaceSource()[0].GetInput("diffuseColor").Get()
    assert np.allclose(colour, (0.1, 0.06, 0.03), atol=1e-6)
    # the legs' wood, copied into their prototype, is a defined material reading the fixed textures
    leg = next(c for c in Usd.PrimRange(legs[0], Usd.TraverseInstanceProxies()) if c.IsA(UsdGeom.Mesh))
    wood = UsdShade.MaterialBindingAPI(leg).ComputeBoundMaterial()[0]
    assert wood.GetPrim().IsDefined() and wood.GetPrim().IsInstanceProxy()
    tex = _texture_feeding(after, str(wood.GetPath()), "normal")
    assert tex.GetInput("sourceColorSpace").Get() == "raw" and tex.GetInput("file").Get().path == "./textures/top_NORMAL.png"
    assert all(not p.IsDefined() or p.IsAbstract() for p in Usd.PrimRange.AllPrims(after.GetPrimAtPath("/lfusd_prototypes")))


def test_cleaned_asset_passes_usd_validation(cleaned):
    from lfusd.author.rules import usd_validation

    raw, clean, _ = cleaned
    assert usd_validation(Usd.Stage.Open(str(raw)))  # Blender's float3 normal input
    assert usd_validation(Usd.Stage.Open(str(clean))) == []


def test_cleaned_asset_is_accepted_by_assets_add_and_check(cleaned, tmp_path, capsys):
    _, clean, _ = cleaned
    cat = tmp_path / "catalogue.json"
    code, out, err = run_cli(capsys, "assets", "add", clean, "--catalogue", cat)
    assert code == 0, err
    (a,) = load_catalogue(cat)
    # textured: the top's wood, and its copy inside the legs' prototype
    assert (a.cls, a.licence, a.triangles, a.textured_materials) == ("table", LICENCE_INFINIGEN, TRIANGLES, 2)
    assert a.ground == pytest.approx(0.0, abs=1e-6) and a.up_axis == "Z" and a.meters_per_unit == 1.0
    assert a.lights == ()
    size = np.subtract(a.bounds[1], a.bounds[0])
    assert size == pytest.approx([TOP[0], TOP[1], LEG + TOP[2] + PANE[2]], abs=1e-5)
    code, out, err = run_cli(capsys, "assets", "check", cat)
    assert code == 0 and "all as recorded" in out, out + err


def test_over_the_triangle_budget_is_refused_and_nothing_written(tmp_path):
    raw = write_infinigen_table(tmp_path / "export")
    with pytest.raises(LfusdError, match=f"has {TRIANGLES} triangles, over the budget of {TRIANGLES - 1}.*--max-triangles"):
        clean_asset(raw, tmp_path / "clean" / "table.usdc", max_triangles=TRIANGLES - 1)
    assert not (tmp_path / "clean").exists()


# -- `lfusd assets bake` --------------------------------------------------------------------------

def test_bake_without_infinigen_fails_in_one_line_and_leaves_nothing(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv(PYTHON_ENV, str(tmp_path / "no-venv" / "bin" / "python"))
    (tmp_path / "lib").mkdir()
    code, out, err = run_cli(capsys, "assets", "bake", "--generator", "infinigen", "ChairFactory", "--seed", "0",
                             "--catalogue", tmp_path / "lib" / "catalogue.json")
    assert code == 2
    assert_one_line_error(code, err, "Infinigen's environment is missing", "scripts/setup_infinigen.sh", "no-venv")
    assert sorted(tmp_path.rglob("*")) == [tmp_path / "lib"]  # nothing made
    monkeypatch.delenv(PYTHON_ENV)
    code, _, err = run_cli(capsys, "assets", "bake", "--generator", "infinigen", "ChairFactory", "--seed", "0",
                           "--catalogue", tmp_path / "lib" / "catalogue.json", "--python", tmp_path / "nope")
    assert_one_line_error(code, err, "scripts/setup_infinigen.sh")
    code, _, err = run_cli(capsys, "assets", "bake", "--generator", "infinigen", "RockFactory", "--seed", "0",
                           "--catalogue", tmp_path / "lib" / "catalogue.json")
    assert_one_line_error(code, err, "no class for Infinigen factory RockFactory", "--class")
    assert sorted(tmp_path.rglob("*")) == [tmp_path / "lib"]


def _stand_in(path: Path, fail: bool = False) -> Path:
    """An executable standing in for Infinigen's interpreter: it takes the runner's arguments and
    writes the test asset where Infinigen's exporter would, or fails like a broken factory."""
    path.write_text(textwrap.dedent(f"""\
        #!{sys.executable}
        import json, sys
        sys.path.insert(0, {str(TESTS)!r})
        args = dict(zip(sys.argv[2::2], sys.argv[3::2]))
        if {fail!r}:
            print("Traceback ...\\nValueError: factory blew up")
            sys.exit(1)
        from support.infinigen_assets import write_infinigen_table
        from pathlib import Path
        out = Path(args["--out"])
        usd = write_infinigen_table(out, out.name)
        print("LFUSD_BAKE " + json.dumps({{"usd": str(usd), "seconds": 0.1}}))
        """))
    path.chmod(0o755)
    return path


def test_bake_runs_the_generator_cleans_and_catalogues(tmp_path, capsys):
    python = _stand_in(tmp_path / "python")
    lib = tmp_path / "lib"
    lib.mkdir()
    code, out, err = run_cli(capsys, "assets", "bake", "--generator", "infinigen", "TableDiningFactory", "--seed", "3",
                             "--catalogue", lib / "catalogue.json", "--python", python)
    assert code == 0, err
    assert "cleaned: lights 1, colour spaces 3, normal maps 1, types 1, glass 1, grounded 1, instanced 6" in out
    folder = lib / "TableDiningFactory_3"
    # the cleaned asset and the textures it reads; Infinigen's raw export and log are gone (the dome's image too)
    assert sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*")) == [
        "TableDiningFactory_3.usdc", "textures", "textures/top_DIFFUSE.png", "textures/top_METAL.png",
        "textures/top_NORMAL.png", "textures/top_ROUGHNESS.png"]
    (a,) = load_catalogue(lib / "catalogue.json")
    assert (a.name, a.cls, a.licence, a.file) == ("TableDiningFactory_3", "table", LICENCE_INFINIGEN,
                                                  "TableDiningFactory_3/TableDiningFactory_3.usdc")
    assert run_cli(capsys, "assets", "check", lib / "catalogue.json")[0] == 0
    # the same factory and seed again: refused, nothing overwritten
    code, _, err = run_cli(capsys, "assets", "bake", "--generator", "infinigen", "TableDiningFactory", "--seed", "3",
                           "--catalogue", lib / "catalogue.json", "--python", python)
    assert_one_line_error(code, err, "already exists")
    assert json.loads((lib / "catalogue.json").read_text())["assets"][0]["sha256"] == a.sha256


def test_a_failing_generator_is_one_line_and_leaves_nothing(tmp_path, capsys):
    python = _stand_in(tmp_path / "python", fail=True)
    lib = tmp_path / "lib"
    lib.mkdir()
    code, _, err = run_cli(capsys, "assets", "bake", "--generator", "infinigen", "ChairFactory", "--seed", "0",
                           "--catalogue", lib / "catalogue.json", "--python", python)
    assert code == 2
    assert_one_line_error(code, err, "Infinigen failed on ChairFactory seed 0 (exit 1)", "factory blew up")
    assert os.listdir(lib) == []


def test_bake_never_runs_a_python_found_in_the_current_folder(tmp_path, capsys, monkeypatch):
    """Issue 39 item 2: a folder someone else made (with its own .venv-infinigen/bin/python) does
    not get its program run by `lfusd assets bake` without --python."""
    from lfusd.author.bake import infinigen_python

    planted = tmp_path / "theirs" / ".venv-infinigen" / "bin" / "python"
    planted.parent.mkdir(parents=True)
    ran = tmp_path / "ran"
    planted.write_text(f"#!/bin/sh\ntouch {ran}\n")
    planted.chmod(0o755)
    monkeypatch.chdir(tmp_path / "theirs")
    monkeypatch.delenv(PYTHON_ENV, raising=False)
    (tmp_path / "lib").mkdir()
    try:
        chosen = infinigen_python()
    except LfusdError:
        chosen = None
    assert chosen is None or chosen.resolve() != planted.resolve()
    code, _, err = run_cli(capsys, "assets", "bake", "--generator", "infinigen", "ChairFactory", "--seed", "0",
                           "--catalogue", tmp_path / "lib" / "catalogue.json")
    assert not ran.exists()
    if chosen is None:  # no Infinigen set up in this project: one line naming the set-up script
        assert_one_line_error(code, err, "scripts/setup_infinigen.sh")


def test_a_generator_that_reports_a_missing_file_is_one_line_and_leaves_nothing(tmp_path, capsys):
    """Issue 39 item 2: a runner line naming no file that exists is one line, exit 2 (was exit 3)."""
    python = tmp_path / "python"
    python.write_text(f"#!{sys.executable}\nprint('LFUSD_BAKE ' + '{{\"usd\": \"/nonexistent/x.usdc\"}}')\n")
    python.chmod(0o755)
    lib = tmp_path / "lib"
    lib.mkdir()
    code, _, err = run_cli(capsys, "assets", "bake", "--generator", "infinigen", "ChairFactory", "--seed", "0",
                           "--catalogue", lib / "catalogue.json", "--python", python)
    assert code == 2
    assert_one_line_error(code, err, "Infinigen reported no asset file for ChairFactory seed 0", "/nonexistent/x.usdc")
    assert os.listdir(lib) == []


def test_bake_over_the_budget_is_refused_in_one_line_and_leaves_nothing(tmp_path, capsys):
    python = _stand_in(tmp_path / "python")
    lib = tmp_path / "lib"
    lib.mkdir()
    code, _, err = run_cli(capsys, "assets", "bake", "--generator", "infinigen", "TableDiningFactory", "--seed", "3",
                           "--catalogue", lib / "catalogue.json", "--python", python, "--max-triangles", "50")
    assert code == 2
    assert_one_line_error(code, err, f"TableDiningFactory seed 3 has {TRIANGLES} triangles, over the budget of 50",
                          "--max-triangles")
    assert os.listdir(lib) == []


def test_a_y_up_centimetre_asset_is_grounded_along_its_own_up_axis(tmp_path):
    """Grounding follows the asset's up axis and units: a Y-up centimetre box 50 cm up, under a
    root turned 90 degrees about y, comes down 50 cm along y."""
    from lfusd.author.catalogue import inspect_asset

    path = tmp_path / "box.usda"
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    root = UsdGeom.Xform.Define(stage, "/Box")
    root.AddRotateYOp().Set(90.0)
    stage.SetDefaultPrim(root.GetPrim())
    box = UsdGeom.Mesh.Define(stage, "/Box/Geo")
    box.CreatePointsAttr([(x, y, z) for x in (-20, 20) for y in (50, 90) for z in (-10, 10)])
    box.CreateFaceVertexCountsAttr([4] * 6)
    box.CreateFaceVertexIndicesAttr([0, 1, 3, 2, 4, 6, 7, 5, 0, 4, 5, 1, 2, 3, 7, 6, 0, 2, 6, 4, 1, 5, 7, 3])
    stage.GetRootLayer().Save()
    report = clean_asset(path, tmp_path / "out" / "box.usda", cls="bench")
    assert report.counts["grounded"] == 1 and report.ground_shift == pytest.approx(-0.5, abs=1e-9)
    out = Usd.Stage.Open(str(tmp_path / "out" / "box.usda"))
    op = UsdGeom.Xformable(out.GetDefaultPrim()).GetOrderedXformOps()[0]
    assert op.GetOpName() == "xformOp:translate:lfusdGround" and tuple(op.Get()) == pytest.approx((0, -50, 0))
    a = inspect_asset(tmp_path / "out" / "box.usda")
    assert a.ground == pytest.approx(0.0, abs=1e-6) and a.cls == "bench"
    assert np.subtract(a.bounds[1], a.bounds[0])[2] == pytest.approx(0.4, abs=1e-6)  # 40 cm tall, still
