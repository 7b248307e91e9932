"""`lfusd check` and lfusd.author.rules on stages written with plain pxr (no lfusd authoring).

The world: a road (x in [-10, 0]), grass (x in [0, 5]) with their tops at z = 0, and water
(x in [5, 15]) with its surface at z = -0.3. Objects are boxes placed 1 mm above a surface; the
expected outcome of every rule follows from these numbers alone.
"""

from __future__ import annotations

import json

import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdSemantics

from lfusd import cli
from lfusd.author.rules import Checker, check_stage, set_class_rule, set_constraint

WATER_Z = -0.3


def labelled_box(stage, path, label, lo, hi):
    """A Cube scaled to the box lo..hi under an Xform labelled ``label`` (plain pxr)."""
    x = UsdGeom.Xform.Define(stage, path)
    cx, cy, cz = [(a + b) / 2 for a, b in zip(lo, hi)]
    x.AddTranslateOp().Set(Gf.Vec3d(cx, cy, cz))
    cube = UsdGeom.Cube.Define(stage, f"{path}/geo")
    cube.CreateSizeAttr(1.0)
    cube.AddScaleOp().Set(Gf.Vec3f(*[b - a for a, b in zip(lo, hi)]))
    if label:
        UsdSemantics.LabelsAPI.Apply(x.GetPrim(), "class").CreateLabelsAttr([label])
    return x


def world(path, frames=1):
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(frames)
    w = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(w.GetPrim())
    labelled_box(stage, "/World/Road", "road", (-10, -5, -0.2), (0, 5, 0))
    labelled_box(stage, "/World/Grass", "grass", (0, -5, -0.2), (5, 5, 0))
    labelled_box(stage, "/World/River", "water", (5, -5, -2.0), (15, 5, WATER_Z))
    return stage


def person(stage, path, x, y=0.0, z=0.001):
    return labelled_box(stage, path, "person", (x - 0.2, y - 0.2, z), (x + 0.2, y + 0.2, z + 1.8))


def run_check(capsys, path, *extra):
    code = cli.main(["check", str(path), *extra])
    out, err = capsys.readouterr()
    return code, out.strip().splitlines(), err.strip().splitlines()


def test_check_stage_is_the_library_behind_lfusd_check(tmp_path, capsys):
    """check_stage finds what `lfusd check` prints: the walker over the river, and nothing on the road."""
    bad = world(tmp_path / "bad.usda", frames=2)
    person(bad, "/World/Walker", 10.0, z=WATER_Z + 0.001)
    bad.Save()
    found = check_stage(tmp_path / "bad.usda", usd=False, coverage=False)
    assert found.problems and all(p.startswith("/World/Walker:") for p in found.problems), found.problems
    assert (found.labelled, found.frames, found.footage) == (4, (1, 2), [])
    n = len(found.problems)
    assert found.summary().endswith(f": {n} violation{'s' if n != 1 else ''}")
    code, out, err = run_check(capsys, tmp_path / "bad.usda", "--no-usd-validation", "--no-coverage")
    assert code == 1 and out == found.problems and len(err) == 1 and err[0].endswith(f": {n} violation{'s' if n != 1 else ''}")
    good = world(tmp_path / "good.usda")
    person(good, "/World/Walker", -3.0)
    good.Save()
    found = check_stage(tmp_path / "good.usda", usd=False, coverage=False)
    assert found.problems == [] and found.summary().endswith(": all constraints hold")


def test_person_on_road_passes_and_on_river_fails(tmp_path, capsys):
    good = world(tmp_path / "good.usda")
    person(good, "/World/Walker", -3.0)
    good.Save()
    code, out, _ = run_check(capsys, tmp_path / "good.usda")
    assert code == 0 and len(out) == 1 and "all constraints hold" in out[0]

    bad = world(tmp_path / "bad.usda")
    person(bad, "/World/Walker", 10.0, z=WATER_Z + 0.001)
    bad.Save()
    code, out, _ = run_check(capsys, tmp_path / "bad.usda")
    assert code == 1
    lines = [ln for ln in out if ln.startswith("/World/Walker:")]
    assert any("not_on" in ln and "frame 1" in ln and "'water'" in ln for ln in lines), out
    assert any(ln.startswith("/World/Walker: on ") for ln in lines), out


def test_boat_on_road_fails_and_floating_boat_passes(tmp_path, capsys):
    bad = world(tmp_path / "bad.usda")
    labelled_box(bad, "/World/Boat", "boat", (-6, -1, 0.001), (-2, 1, 1.0))
    bad.Save()
    code, out, _ = run_check(capsys, tmp_path / "bad.usda")
    assert code == 1 and any(ln.startswith("/World/Boat: floats_on") and "frame 1" in ln for ln in out), out

    good = world(tmp_path / "good.usda")
    labelled_box(good, "/World/Boat", "boat", (8, -1, WATER_Z - 0.4), (12, 1, WATER_Z + 0.6))  # draft 0.4 m
    good.Save()
    code, out, _ = run_check(capsys, tmp_path / "good.usda")
    assert code == 0, out

    deep = world(tmp_path / "deep.usda")  # sunk 1.6 m: beyond the default draft of 1.5 m (+ 5 cm)
    labelled_box(deep, "/World/Boat", "boat", (8, -1, WATER_Z - 1.6), (12, 1, WATER_Z - 0.6))
    deep.Save()
    code, out, _ = run_check(capsys, tmp_path / "deep.usda")
    assert code == 1 and any("/World/Boat: floats_on" in ln for ln in out), out


def test_car_on_grass_fails_on_road_passes(tmp_path, capsys):
    bad = world(tmp_path / "bad.usda")
    labelled_box(bad, "/World/Car", "car", (1, -1, 0.001), (4, 1, 1.4))
    bad.Save()
    code, out, _ = run_check(capsys, tmp_path / "bad.usda")
    assert code == 1 and any(ln.startswith("/World/Car: on") and "'grass'" in ln and "frame 1" in ln for ln in out), out

    good = world(tmp_path / "good.usda")
    labelled_box(good, "/World/Car", "car", (-6, -1, 0.001), (-2, 1, 1.4))
    good.Save()
    assert run_check(capsys, tmp_path / "good.usda")[0] == 0


def test_floating_car_is_unsupported(tmp_path, capsys):
    s = world(tmp_path / "s.usda")
    labelled_box(s, "/World/Car", "car", (-6, -1, 0.5), (-2, 1, 1.9))
    s.Save()
    code, out, _ = run_check(capsys, tmp_path / "s.usda")
    assert code == 1 and any("/World/Car: on" in ln and "0.50 m above" in ln for ln in out), out


def test_person_walking_into_river_names_first_bad_frame(tmp_path, capsys):
    # Centre x = frame (1..10); the footprint reaches the water (x > 5) when x + 0.2 > 5: frame 5.
    s = world(tmp_path / "walk.usda", frames=10)
    p = person(s, "/World/Walker", 0.0)
    op = p.GetOrderedXformOps()[0]
    for f in range(1, 11):
        op.Set(Gf.Vec3d(float(f), 0.0, 0.901), Usd.TimeCode(f))
    s.Save()
    code, out, _ = run_check(capsys, tmp_path / "walk.usda")
    assert code == 1
    walker = {ln.split(" broken")[0]: ln for ln in out if ln.startswith("/World/Walker:")}
    # not_on breaks when the first contact point is over the water; on when none rests on land
    # (the whole footprint, x - 0.2 > 5, is over the water at frame 6).
    assert "frame 5:" in walker["/World/Walker: not_on"] and "frame 6:" in walker["/World/Walker: on"], out


def test_interpenetration_dynamic_first_frame_and_corrected(tmp_path, capsys):
    # B stands at x = -2; A moves from x = -8 by 1 m per frame: the boxes (0.4 m wide) overlap
    # once |xA - (-2)| < 0.4, i.e. xA = -2 at frame 7 (frame 6 has xA = -3, 0.6 m apart).
    def make(name, speed):
        s = world(tmp_path / name, frames=10)
        person(s, "/World/B", -2.0)
        a = person(s, "/World/A", -8.0)
        op = a.GetOrderedXformOps()[0]
        for f in range(1, 11):
            op.Set(Gf.Vec3d(-8.0 + speed * (f - 1), 0.0, 0.901), Usd.TimeCode(f))
        s.Save()
        return tmp_path / name

    code, out, _ = run_check(capsys, make("hit.usda", 1.0))
    assert code == 1
    hit = [ln for ln in out if "no_interpenetration" in ln]
    assert any(ln.startswith("/World/A: no_interpenetration broken at frame 7") and "/World/B" in ln for ln in hit), out
    # B is static: the default rulebook only forbids dynamic objects from interpenetrating.
    assert not any(ln.startswith("/World/B:") for ln in hit), out
    code, out, _ = run_check(capsys, make("miss.usda", 0.5))  # stops at x = -3.5
    assert code == 0, out


def test_static_interpenetration_needs_a_stage_rule(tmp_path, capsys):
    s = world(tmp_path / "s.usda")
    labelled_box(s, "/World/A", "crate", (-3.2, -0.2, 0.001), (-2.8, 0.2, 1.0))
    labelled_box(s, "/World/B", "crate", (-2.95, -0.2, 0.001), (-2.55, 0.2, 1.0))  # overlaps A by 0.15 m
    s.Save()
    assert run_check(capsys, tmp_path / "s.usda")[0] == 0  # static: not in the default rulebook
    set_class_rule(s, "any", "no_interpenetration", ["any"])
    s.Save()
    code, out, _ = run_check(capsys, tmp_path / "s.usda")
    assert code == 1 and {ln.split(":")[0] for ln in out if "no_interpenetration" in ln} == {"/World/A", "/World/B"}


def test_contained_object_counts_as_interpenetration(tmp_path, capsys):
    s = world(tmp_path / "s.usda")
    labelled_box(s, "/World/Crate", "crate", (-5, -1, 0.001), (-3, 1, 2.0))
    labelled_box(s, "/World/Toy", "toy", (-4.2, -0.2, 0.5), (-3.8, 0.2, 0.9))  # wholly inside the crate
    set_class_rule(s, "toy", "no_interpenetration", ["crate"])
    s.Save()
    code, out, _ = run_check(capsys, tmp_path / "s.usda")
    assert code == 1 and any(ln.startswith("/World/Toy: no_interpenetration") for ln in out), out


def test_overrides_file_stage_and_prim(tmp_path, capsys):
    s = world(tmp_path / "s.usda")
    car = labelled_box(s, "/World/Car", "car", (1, -1, 0.001), (4, 1, 1.4))  # on grass
    s.Save()
    rules = tmp_path / "rules.json"
    rules.write_text(json.dumps({"rules": {"car": {"on": ["road", "grass"]}}}))
    assert run_check(capsys, tmp_path / "s.usda", "--rules", str(rules))[0] == 0
    toml = tmp_path / "rules.toml"
    toml.write_text('[rules."/World/Car"]\non = ["grass"]\n')
    assert run_check(capsys, tmp_path / "s.usda", "--rules", str(toml))[0] == 0
    # A stage class rule overrides the file; a prim rule overrides the stage class rule.
    set_class_rule(s, "car", "on", ["road"])
    s.Save()
    assert run_check(capsys, tmp_path / "s.usda", "--rules", str(rules))[0] == 1
    set_constraint(car.GetPrim(), "on", [])  # switched off for this car
    s.Save()
    assert run_check(capsys, tmp_path / "s.usda")[0] == 0


def test_inside_region_and_bounds(tmp_path, capsys):
    s = world(tmp_path / "s.usda", frames=6)
    zone = labelled_box(s, "/World/Zone", "", (-10, -5, -1), (-4, 5, 3))
    UsdGeom.Imageable(zone.GetPrim()).CreatePurposeAttr(UsdGeom.Tokens.guide)
    p = person(s, "/World/Walker", -8.0)
    set_constraint(p.GetPrim(), "inside", "/World/Zone")
    op = p.GetOrderedXformOps()[0]
    for f in range(1, 7):  # right edge x = -7.8 + (f - 1): leaves the zone (x > -4) at frame 5
        op.Set(Gf.Vec3d(-8.0 + (f - 1), 0.0, 0.901), Usd.TimeCode(f))
    s.Save()
    code, out, _ = run_check(capsys, tmp_path / "s.usda")
    assert code == 1 and any(ln.startswith("/World/Walker: inside broken at frame 5") for ln in out), out

    b = world(tmp_path / "b.usda", frames=4)
    w = person(b, "/World/Walker", 13.0, z=0.0)  # over the water near its far end (x = 15)
    set_constraint(w.GetPrim(), "not_on", [])
    set_constraint(w.GetPrim(), "on", [])
    op = w.GetOrderedXformOps()[0]
    for f in range(1, 5):  # right edge 13.2 + (f-1): beyond x = 15 at frame 3
        op.Set(Gf.Vec3d(13.0 + (f - 1), 0.0, 0.9), Usd.TimeCode(f))
    b.Save()
    code, out, _ = run_check(capsys, tmp_path / "b.usda")
    assert code == 1 and any(ln.startswith("/World/Walker: in_bounds broken at frame 3") for ln in out), out


def test_usd_validation_errors_are_reported(tmp_path, capsys):
    stage = Usd.Stage.CreateNew(str(tmp_path / "v.usda"))  # no metersPerUnit, no upAxis, no default prim
    UsdGeom.Xform.Define(stage, "/World")
    stage.Save()
    code, out, err = run_check(capsys, tmp_path / "v.usda")
    assert code == 1
    assert any("MissingMetersPerUnitMetadata" in ln for ln in out) and any("MissingUpAxisMetadata" in ln for ln in out)
    assert any("no class labels" in ln for ln in err)  # label-less: warned, the rest checked


def test_missing_texture_is_a_usd_validation_error(tmp_path, capfd):
    from lfusd.author.scenes import generate

    generate("room", tmp_path / "r.usda", 0, frames=1, rigs=0)
    (tmp_path / "textures" / "ceramic.png").unlink()
    assert cli.main(["check", str(tmp_path / "r.usda")]) == 1
    out, err = capfd.readouterr()
    assert out.strip().splitlines() == [f"/: usd:usdUtilsValidators:MissingReferenceValidator (UnresolvableDependency): "
                                        f"Found unresolvable external dependency '{tmp_path / 'textures' / 'ceramic.png'}'."]
    assert len(err.strip().splitlines()) == 1 and "1 violation" in err


def test_label_less_stage_warns_and_checks_the_rest(tmp_path, capsys):
    s = world(tmp_path / "s.usda")
    for prim in list(s.Traverse()):
        UsdSemantics.LabelsAPI(prim, "class").GetLabelsAttr() and prim.RemoveAPI(UsdSemantics.LabelsAPI, "class")
        prim.RemoveProperty("semantics:labels:class")
    s.Save()
    code, out, err = run_check(capsys, tmp_path / "s.usda")
    assert code == 0 and len(err) == 1 and "warning" in err[0] and "no class labels" in err[0]


@pytest.mark.parametrize(
    "setup, expect",
    [
        ("garbage", "not a readable USD file"),
        ("missing", "does not exist"),
        ("bad_target", "names prim /World/Nowhere, which does not exist"),
        ("unknown_rule", "unknown rule 'hovers_over'"),
        ("bad_rules_file", "unknown rule 'flies'"),
        ("file_names_missing_prim", "rules for prim /World/Ghost, which is not an object"),
        ("constraint_on_mesh", "prim /World/Walker/geo has lfusd:constraint rules but is not an object"),
    ],
)
def test_bad_input_gives_one_line_errors(tmp_path, capsys, setup, expect):
    path = tmp_path / "s.usda"
    extra = []
    if setup == "garbage":
        path.write_text("this is not USD\n")
    elif setup != "missing":
        s = world(path)
        p = person(s, "/World/Walker", -3.0)
        if setup == "bad_target":
            p.GetPrim().CreateRelationship("lfusd:constraint:inside", custom=True).SetTargets([Sdf.Path("/World/Nowhere")])
        elif setup == "unknown_rule":
            p.GetPrim().CreateAttribute("lfusd:constraint:hovers_over", Sdf.ValueTypeNames.TokenArray, custom=True).Set(["road"])
        elif setup == "bad_rules_file":
            (tmp_path / "r.json").write_text('{"person": {"flies": true}}')
            extra = ["--rules", str(tmp_path / "r.json")]
        elif setup == "file_names_missing_prim":
            (tmp_path / "r.toml").write_text('[rules."/World/Ghost"]\non = ["road"]\n')
            extra = ["--rules", str(tmp_path / "r.toml")]
        elif setup == "constraint_on_mesh":
            set_constraint(s.GetPrimAtPath("/World/Walker/geo"), "on", ["road"])
        s.Save()
    code, out, err = run_check(capsys, path, *extra)
    assert code == 2 and out == [] and len(err) == 1
    assert err[0].startswith("lfusd: error:") and expect in err[0], err


def test_label_less_stage_still_checks_prim_rules(tmp_path, capsys):
    stage = Usd.Stage.CreateNew(str(tmp_path / "s.usda"))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    zone = labelled_box(stage, "/World/Zone", "", (0, 0, 0), (1, 1, 1))
    UsdGeom.Imageable(zone.GetPrim()).CreatePurposeAttr(UsdGeom.Tokens.guide)
    box = labelled_box(stage, "/World/Box", "", (0.5, 0.5, 0.5), (1.5, 1.5, 1.5))  # sticks out of the zone
    # unlabelled geometry is an object of its own (lfusd.author.labels.object_table): the Cube prim
    set_constraint(box.GetPrim().GetChild("geo"), "inside", "/World/Zone")
    stage.Save()
    code, out, err = run_check(capsys, tmp_path / "s.usda")
    assert code == 1 and len(err) == 2 and "no class labels" in err[0]
    assert out == ["/World/Box/geo: inside broken at frame 1: outside '/World/Zone'"]


def test_implicit_shape_is_reported_and_the_rest_checked(tmp_path, capsys):
    s = world(tmp_path / "s.usda")
    ball = UsdGeom.Sphere.Define(s, "/World/Ball")
    UsdSemantics.LabelsAPI.Apply(ball.GetPrim(), "class").CreateLabelsAttr(["person"])
    labelled_box(s, "/World/Car", "car", (1, -1, 0.001), (4, 1, 1.4))  # on grass: still found
    s.Save()
    code, out, _ = run_check(capsys, tmp_path / "s.usda")
    assert code == 1
    assert any(ln.startswith("/World/Ball: geometry broken at frame 1") and "convert it to a Mesh" in ln for ln in out), out
    assert any(ln.startswith("/World/Car: on broken at frame 1") for ln in out), out


def test_static_stage_is_evaluated_once(tmp_path):
    s = world(tmp_path / "s.usda", frames=500)
    person(s, "/World/Walker", -3.0)
    s.Save()
    seen = []
    checker = Checker(Usd.Stage.Open(str(tmp_path / "s.usda")))
    assert checker.check(progress=seen.append) == [] and seen == [1]
