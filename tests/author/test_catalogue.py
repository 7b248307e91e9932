"""The asset catalogue (issue 25 item 3): `lfusd assets add|list|check` on assets shaped like real
ones (tests/support/catalogue_assets.py: a Y-up centimetre .usdc car with instanced wheels and a
foreign textured material, a .usdz tree whose leaves are point instances), refusals, and
generated scenes that draw them (placed in the one world frame, one object each, rules kept).
Expected numbers are closed-form: the assets' authored dimensions in metres."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from support.catalogue_assets import (
    CAR_HEIGHT,
    CAR_LENGTH,
    CAR_WIDTH,
    TREE_HEIGHT,
    TREE_WIDTH,
    write_bad,
    write_bench,
    write_car,
    write_tree,
)
from support.cli import assert_one_line_error, run_cli

from lfusd.author.catalogue import load_catalogue

CM = 0.01


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    """A folder with the car (.usdc + textures/) and the tree (.usdz), catalogued beside them."""
    folder = tmp_path_factory.mktemp("library")
    write_car(folder)
    write_tree(folder)
    from lfusd.author.catalogue import add_assets

    path, added = add_assets(folder)
    return folder, path, {a.name: a for a in added}


def test_add_records_class_bounds_units_up_ground_licence_and_hash(tmp_path, capsys):
    write_car(tmp_path / "lib")
    write_tree(tmp_path / "lib")
    code, out, err = run_cli(capsys, "assets", "add", tmp_path / "lib")
    assert code == 0, err
    cat = tmp_path / "lib" / "catalogue.json"  # beside the assets: the default place
    assert f"added 2 assets to {cat}" in out
    entries = {a.name: a for a in load_catalogue(cat)}
    car, tree = entries["sedan"], entries["oak"]
    assert (car.file, tree.file) == ("sedan.usdc", "oak.usdz")  # relative: the folder can move
    assert (car.cls, tree.cls) == ("car", "tree")  # from the assets' UsdSemantics labels
    assert car.meters_per_unit == tree.meters_per_unit == pytest.approx(CM)
    assert car.up_axis == tree.up_axis == "Y"
    # bounds in lfusd's world (Z up, metres): the root's rotateY 90 and Y-up turn the car's length onto y
    size = np.subtract(car.bounds[1], car.bounds[0])
    assert size == pytest.approx([CAR_WIDTH * CM, CAR_LENGTH * CM, CAR_HEIGHT * CM], abs=1e-5)
    assert car.ground == pytest.approx(0.0, abs=1e-6) and tree.ground == pytest.approx(0.0, abs=1e-6)
    assert np.subtract(tree.bounds[1], tree.bounds[0])[2] == pytest.approx(TREE_HEIGHT * CM, abs=1e-5)
    assert np.subtract(tree.bounds[1], tree.bounds[0])[0] == pytest.approx(TREE_WIDTH * CM, abs=1e-5)
    assert (car.licence, tree.licence) == ("CC-BY-4.0", "CC0-1.0")  # from customLayerData
    # triangles: the body's 12 and four instanced 8-sided wheels (8 quads + two octagons: 28 each);
    # the trunk's 12 and six point-instanced leaf boxes
    assert (car.triangles, tree.triangles) == (12 + 4 * 28, 12 + 6 * 12)
    assert car.textured_materials == 1 and tree.textured_materials == 1
    # the content hash covers the texture beside the car (a changed texture changes the asset)
    before = car.sha256
    (tmp_path / "lib" / "textures" / "sedan_paint.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"0" * 64)
    code, out, _ = run_cli(capsys, "assets", "check", cat)
    assert code == 1 and "sedan" in out and "changed since it was added" in out and "oak" not in out
    run_cli(capsys, "assets", "add", tmp_path / "lib" / "sedan.usdc")  # re-added: replaced, not duplicated
    entries = load_catalogue(cat)
    assert sorted(a.name for a in entries) == ["oak", "sedan"]
    assert next(a for a in entries if a.name == "sedan").sha256 != before
    assert run_cli(capsys, "assets", "check", cat)[0] == 0


def test_list_shows_assets_and_the_procedural_generators(library, capsys):
    _, cat, _ = library
    code, out, _ = run_cli(capsys, "assets", "list", cat)
    assert code == 0
    lines = out.splitlines()
    assert any(ln.startswith("sedan: car, 1.92 x 4.20 x 1.40 m, metersPerUnit 0.01, Y-up") for ln in lines), out
    assert any(ln.startswith("oak: tree,") and "CC0-1.0" in ln for ln in lines), out
    assert "procedural:car: car, procedural (lfusd.author.scenes.objects.car)" in lines


def test_check_reports_a_missing_asset(tmp_path, capsys):
    write_car(tmp_path)
    run_cli(capsys, "assets", "add", tmp_path)
    (tmp_path / "sedan.usdc").unlink()
    code, out, err = run_cli(capsys, "assets", "check", tmp_path)
    assert code == 1 and "sedan: file" in out and "is missing" in out and "1 of 1 assets" in err


def test_class_option_labels_an_unlabelled_asset(tmp_path, capsys):
    bench = write_bench(tmp_path / "b")
    code, _, err = run_cli(capsys, "assets", "add", bench)
    assert_one_line_error(code, err, "has no class", "--class")
    assert not (tmp_path / "b" / "catalogue.json").exists()
    code, _, err = run_cli(capsys, "assets", "add", bench, "--class", "spaceship")
    assert_one_line_error(code, err, "'spaceship' is not an object class")
    (tmp_path / "cats").mkdir()
    code, _, err = run_cli(capsys, "assets", "add", bench, "--class", "bench", "--licence", "MIT",
                           "--catalogue", tmp_path / "cats" / "mine.json")
    assert code == 0, err
    (a,) = load_catalogue(tmp_path / "cats" / "mine.json")
    assert (a.cls, a.licence, a.up_axis, a.meters_per_unit) == ("bench", "MIT", "Z", 1.0)
    assert a.file == str(bench.resolve())  # outside the catalogue's folder: absolute
    assert run_cli(capsys, "assets", "add", bench, "--class", "bench", "--catalogue", tmp_path / "c.json")[0] == 0
    assert load_catalogue(tmp_path / "c.json")[0].file == "b/park_bench.usda"  # inside it: relative
    assert np.subtract(a.bounds[1], a.bounds[0]) == pytest.approx([1.6, 0.5, 0.47], abs=1e-6)


@pytest.mark.parametrize("kind, needle", [
    ("unlabelled", "has no class"), ("sphere", "is a Sphere"), ("index", "face index 42 outside its 8 points"),
    ("nan", "non-finite points"), ("flat", "empty bounds"), ("nomesh", "is not a mesh asset"),
])
def test_bad_assets_are_refused_in_one_line_and_nothing_is_written(tmp_path, capsys, kind, needle):
    write_car(tmp_path / "lib")
    bad = write_bad(tmp_path / "lib", kind)
    code, _, err = run_cli(capsys, "assets", "add", tmp_path / "lib")  # a good asset and a bad one
    assert code == 2
    assert_one_line_error(code, err, str(bad), needle)
    assert not (tmp_path / "lib" / "catalogue.json").exists()  # a refused run leaves nothing


def test_an_unreadable_file_is_refused_in_one_line(tmp_path, capsys):
    (tmp_path / "broken.usda").write_text("not USD at all\n")
    code, _, err = run_cli(capsys, "assets", "add", tmp_path / "broken.usda")
    assert_one_line_error(code, err, "cannot open asset", "USD cannot read it")
    (tmp_path / "notes.txt").write_text("x")
    code, _, err = run_cli(capsys, "assets", "add", tmp_path / "notes.txt")
    assert_one_line_error(code, err, "is not a USD file")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["broken.usda", "notes.txt"]


def test_catalogue_is_written_only_where_named_and_never_through_links(tmp_path, capsys):
    write_car(tmp_path / "lib")
    theirs = tmp_path / "theirs.json"
    theirs.write_text('{"a user\'s": "file"}')
    code, _, err = run_cli(capsys, "assets", "add", tmp_path / "lib", "--catalogue", theirs)
    assert_one_line_error(code, err, "is not an lfusd catalogue")
    assert theirs.read_text() == '{"a user\'s": "file"}'
    target = tmp_path / "elsewhere.json"
    os.symlink(target, tmp_path / "lib" / "catalogue.json")
    code, _, err = run_cli(capsys, "assets", "add", tmp_path / "lib")
    assert_one_line_error(code, err, "is a symbolic link")
    assert not target.exists()
    code, _, err = run_cli(capsys, "assets", "add", tmp_path / "lib", "--catalogue", tmp_path / "no" / "cat.json")
    assert_one_line_error(code, err, "does not exist")
    assert not (tmp_path / "no").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lib", "theirs.json"]


def _asset_objects(stage):
    from lfusd.author.labels import object_table
    from lfusd.author.vocabulary import ASSET

    objs = object_table(stage)[0]
    return [o for o in objs if stage.GetPrimAtPath(o.prim_path).HasAttribute(ASSET)], objs


def test_generated_street_draws_catalogue_assets_in_the_world_frame(library, tmp_path, capsys):
    """Catalogue cars and trees appear in a generated street: each one object of its class (its
    instanced wheels and point-instanced leaves are parts of it), grounded 1 mm above the road or
    grass top (z = 0), its size the authored centimetres in metres, its longer side along x
    (cars parked along the road); `lfusd check` passes. The same seed and catalogue give the same bytes."""
    from lfusd.author.geometry import StageGeometry
    from lfusd.author.scenes import GAP, generate

    _, cat, _ = library
    stage = generate("street", tmp_path / "s.usda", 1, frames=1, rigs=1, grid=(2, 2), resolution=(32, 32), catalogues=[cat])
    placed, objs = _asset_objects(stage)
    labels = {o.label for o in placed}
    assert labels == {"car", "tree"}, labels
    # no procedural cars or trees are left: the catalogue's assets replace their class's generator
    assert all(o.prim_path in {p.prim_path for p in placed} for o in objs if o.label in ("car", "tree"))
    # one object per placed asset, not one per wheel instance or leaf
    assert not any("Wheel" in o.prim_path or "[" in o.prim_path for o in objs)
    geo = StageGeometry(stage)
    for o in placed:
        pts = np.concatenate([geo.mesh(p, 1).vertices for p in geo.parts_of(o.prim_path)])
        lo, hi = pts.min(0), pts.max(0)
        assert lo[2] == pytest.approx(GAP, abs=1e-6), o.prim_path
        if o.label == "car":
            assert hi - lo == pytest.approx([CAR_LENGTH * CM, CAR_WIDTH * CM, CAR_HEIGHT * CM], abs=1e-5), o.prim_path
        else:
            assert hi[2] - lo[2] == pytest.approx(TREE_HEIGHT * CM, abs=1e-5)
        n = len(geo.parts_of(o.prim_path))
        assert n == (5 if o.label == "car" else 7)  # body + 4 wheels; trunk + 6 leaves
    code, out, err = run_cli(capsys, "check", tmp_path / "s.usda", "--no-coverage")
    assert code == 0, out + err
    assert "all constraints hold, USD validation clean" in out
    assert f"from {len(objs) - len(placed) + 2} distinct assets (2 from catalogues)" in out  # the car and the tree, once each
    again = generate("street", tmp_path / "t.usda", 1, frames=1, rigs=1, grid=(2, 2), resolution=(32, 32), catalogues=[cat])
    assert again.GetRootLayer().ExportToString() == stage.GetRootLayer().ExportToString()


def test_room_draws_a_catalogue_bench_chair_and_table(tmp_path, capsys):
    """Assets of other classes: an unlabelled stool added as a chair and a bench added as a table
    land in the room template on the floor, and the room passes `lfusd check`."""
    from lfusd.author.scenes import generate

    bench = write_bench(tmp_path / "b")
    stool = write_bench(tmp_path / "s", "stool", length=0.5)
    assert run_cli(capsys, "assets", "add", stool, "--class", "chair", "--catalogue", tmp_path / "c.json")[0] == 0
    assert run_cli(capsys, "assets", "add", bench, "--class", "table", "--catalogue", tmp_path / "t.json")[0] == 0
    stage = generate("room", tmp_path / "r.usda", 0, frames=1, rigs=1, grid=(2, 2), resolution=(32, 32),
                     catalogues=[tmp_path / "c.json", tmp_path / "t.json"])
    placed, _ = _asset_objects(stage)
    assert {o.label for o in placed} == {"chair", "table"}
    code, out, err = run_cli(capsys, "check", tmp_path / "r.usda", "--no-coverage", "--no-usd-validation")
    assert code == 0, out + err


def test_a_changed_asset_is_refused_when_a_scene_draws_it(tmp_path, capsys):
    copy = tmp_path / "lib"
    copy.mkdir()
    write_car(copy)
    assert run_cli(capsys, "assets", "add", copy)[0] == 0
    (copy / "textures" / "sedan_paint.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"1" * 64)
    code, _, err = run_cli(capsys, "stage", "new", "street", "-o", tmp_path / "s.usda", "--rigs", "1", "--frames", "1",
                           "--catalogue", copy / "catalogue.json")
    assert_one_line_error(code, err, "changed since it was added", "lfusd assets add")
    assert not (tmp_path / "s.usda").exists()


def test_check_prints_triangles_distinct_assets_and_textured_materials(library, tmp_path):
    """On a stage the test authors: a road box and the car asset placed twice: triangles are the
    road's 12 plus twice the car's 124, distinct assets 2 (the road; the car once), materials 2
    (the car's paint, textured, and its wheels' rubber, shared by the instances)."""
    from pxr import Gf, UsdGeom

    from lfusd.author.labels import set_class_label
    from lfusd.author.scenes import reference_asset
    from lfusd.author.stage import new_stage
    from lfusd.author.statistics import stage_statistics

    _, _, assets = library
    path = tmp_path / "two.usda"
    stage = new_stage(path)
    road = UsdGeom.Cube.Define(stage, "/World/Road")
    set_class_label(road.GetPrim(), "road")
    for k in range(2):
        x = UsdGeom.Xform.Define(stage, f"/World/Car_{k}")
        x.AddTranslateOp().Set(Gf.Vec3d(6.0 * k, 0, 1.0))
        set_class_label(x.GetPrim(), "car")
        reference_asset(stage, path, f"/World/Car_{k}", assets["sedan"])
    s = stage_statistics(stage)
    assert (s.triangles, s.objects, s.distinct_assets, s.catalogue_assets) == (12 + 2 * 124, 3, 2, 1)
    assert (s.textured_materials, s.materials) == (1, 2)
    assert s.line() == "260 triangles, 3 objects from 2 distinct assets (1 from catalogues), 1 of 2 materials textured"


def test_recipe_names_catalogues_relative_to_itself(library, tmp_path):
    from lfusd.errors import LfusdError
    from lfusd.recipe import _spec_dict, load_recipe, scene_specs

    _, cat, _ = library
    body = ('[dataset]\nname = "x"\ngrid = [2, 2]\nresolution = [32, 32]\n{extra}\n'
            '[[part]]\nname = "p"\ntemplates = ["street"]\nscenes = 1\n')
    rel = os.path.relpath(cat, tmp_path)
    (tmp_path / "r.toml").write_text(body.format(extra=f'catalogues = ["{rel}"]'))
    recipe = load_recipe(tmp_path / "r.toml")
    assert recipe.catalogues == (str(cat.resolve()),)
    (spec,) = scene_specs(recipe)
    assert spec.catalogues == recipe.catalogues and _spec_dict(spec)["catalogues"] == [str(cat.resolve())]
    (tmp_path / "plain.toml").write_text(body.format(extra=""))
    assert "catalogues" not in _spec_dict(scene_specs(load_recipe(tmp_path / "plain.toml"))[0])  # old records still match
    (tmp_path / "bad.toml").write_text(body.format(extra='catalogues = ["nowhere.json"]'))
    with pytest.raises(LfusdError, match="nowhere.json does not exist"):
        load_recipe(tmp_path / "bad.toml")
    assert json.loads(cat.read_text())["format"] == "lfusd-catalogue"


@pytest.mark.slow
def test_dynamic_street_keeps_catalogue_assets_and_its_rules(library, tmp_path, capsys):
    """A dynamic street drawn from the catalogue: people walk and catalogue cars drive around the
    parked catalogue cars and the trees (whose point-instanced leaves have no prim of their own), and
    `lfusd check` passes at every frame."""
    from lfusd.author.scenes import generate

    _, cat, _ = library
    stage = generate("street", tmp_path / "d.usda", 5, frames=6, rigs=1, grid=(2, 2), resolution=(32, 32), dynamic=True,
                     catalogues=[cat])
    placed, _ = _asset_objects(stage)
    assert {o.label for o in placed} == {"car", "tree"}
    code, out, err = run_cli(capsys, "check", tmp_path / "d.usda", "--no-coverage")
    assert code == 0 and "all constraints hold" in out, out + err


@pytest.fixture(scope="module")
def movers_library(tmp_path_factory):
    """Two catalogues: the car (.usdc, Y-up centimetres, instanced wheels) and a glTF-converted
    character (Y-up centimetres, numbered joints, a rotation above its SkelRoot, textured) as a person."""
    from support.characters import gltf_numbered

    from lfusd.author.catalogue import add_assets

    folder = tmp_path_factory.mktemp("movers")
    write_car(folder / "cars")
    gltf_numbered(folder / "people" / "man.usda")
    return add_assets(folder / "cars")[0], add_assets(folder / "people", cls="person")[0]


def _world_at(stage, path, frame):
    from pxr import Usd, UsdGeom

    return np.array(UsdGeom.Xformable(stage.GetPrimAtPath(path)).ComputeLocalToWorldTransform(Usd.TimeCode(frame)))


def test_dynamic_street_drives_catalogue_cars_and_walks_catalogue_characters(movers_library, tmp_path, capsys):
    """--dynamic with catalogues: every car that drives is the catalogue's car (one object, straight
    along the road at a constant speed), every person who walks is the catalogue's character (the
    person prim references its file), none procedural; their soles stay on the pavement (its top
    0.15 m) within 1 cm at every frame and `lfusd check` passes (rules at every frame)."""
    from lfusd.author.geometry import StageGeometry
    from lfusd.author.labels import object_table
    from lfusd.author.scenes import generate
    from lfusd.author.vocabulary import ASSET

    frames = 6
    stage = generate("street", tmp_path / "d.usda", 2, frames=frames, rigs=1, grid=(2, 2), resolution=(32, 32),
                     dynamic=True, catalogues=list(movers_library))
    objs = object_table(stage)[0]
    moving = [o for o in objs if o.label == "car" and not np.allclose(_world_at(stage, o.prim_path, 1), _world_at(stage, o.prim_path, frames))]
    assert moving and all(stage.GetPrimAtPath(o.prim_path).HasAttribute(ASSET) for o in moving)
    for o in moving:  # along x only, the same step every frame
        xs = np.array([_world_at(stage, o.prim_path, f)[3, :3] for f in range(1, frames + 1)])
        steps = np.diff(xs, axis=0)
        assert np.allclose(steps[:, 1:], 0.0, atol=1e-9) and np.allclose(steps[:, 0], steps[0, 0], atol=1e-6)
        assert abs(steps[0, 0]) > 0.1, o.prim_path  # 4-9 m/s at 24 frames per second
    people = [o for o in objs if o.label == "person"]
    assert people
    geo = StageGeometry(stage)
    for o in people:
        refs = stage.GetPrimAtPath(o.prim_path).GetMetadata("references").GetAddedOrExplicitItems()
        assert [r.assetPath.rsplit("/", 1)[-1] for r in refs] == ["man.usda"], o.prim_path
        soles = [min(geo.mesh(p, f).vertices[:, 2].min() for p in geo.parts_of(o.prim_path)) for f in range(1, frames + 1)]
        assert np.allclose(soles, 0.15, atol=0.01), (o.prim_path, soles)
    code, out, err = run_cli(capsys, "check", tmp_path / "d.usda", "--no-coverage")
    assert code == 0 and "all constraints hold" in out, out + err


def test_a_recipe_scene_is_generated_from_its_catalogues(library, tmp_path, monkeypatch):
    """`dataset make` generates each scene with the recipe's catalogues (the render is stopped
    here: rendering a catalogue scene is the render test's)."""
    import lfusd.render.job
    from lfusd.author.stage import open_stage
    from lfusd.recipe import load_recipe, make_scene, scene_specs

    _, cat, _ = library
    (tmp_path / "r.toml").write_text(f'[dataset]\nname = "x"\ngrid = [2, 2]\nresolution = [32, 32]\ncatalogues = ["{cat}"]\n'
                                     '[[part]]\nname = "p"\ntemplates = ["street"]\nscenes = 1\nfirst_seed = 1\n')
    recipe = load_recipe(tmp_path / "r.toml")

    class Stop(Exception):
        pass

    def stop(req):
        raise Stop

    monkeypatch.setattr(lfusd.render.job, "render", stop)
    (spec,) = scene_specs(recipe)
    with pytest.raises(Stop):
        make_scene(recipe, spec, tmp_path / "out")
    (stage_path,) = (tmp_path / "out").rglob("*.usda")
    placed, _ = _asset_objects(open_stage(stage_path))
    assert {o.label for o in placed} == {"car", "tree"}


def test_an_asset_failing_usd_validation_is_added_with_a_warning(tmp_path, capsys):
    """Converters often author a primvar reader's varname as a token (USD wants a string): the
    asset is usable, so it is added, with one warning that `lfusd check` will report it."""
    from pxr import Sdf, Usd

    car = write_car(tmp_path)
    stage = Usd.Stage.Open(str(car))
    reader = stage.GetPrimAtPath("/Car/Materials/M_CarPaint/TexCoordReader")
    reader.RemoveProperty("inputs:varname")
    reader.CreateAttribute("inputs:varname", Sdf.ValueTypeNames.Token).Set("st")
    stage.GetRootLayer().Save()
    code, out, err = run_cli(capsys, "assets", "add", car)
    assert code == 0 and "added 1 asset" in out
    warnings = [ln for ln in err.splitlines() if ln.startswith("lfusd: warning:")]
    assert len(warnings) == 1 and "fails USD validation" in warnings[0] and "varname" in warnings[0], err


def test_a_usdz_package_is_one_file_of_a_stages_identity(tmp_path):
    """A stage referencing the .usdz tree: its identity (lfusd.author.stage.stage_files) holds the
    package as one file, hashed, and nothing from inside it as missing or as an outside file."""
    import logging

    from pxr import Usd

    from lfusd.author.stage import file_hash, stage_files

    tree = write_tree(tmp_path / "lib")
    stage = Usd.Stage.CreateNew(str(tmp_path / "s.usda"))
    stage.DefinePrim("/T").GetReferences().AddReference("./lib/oak.usdz")
    stage.GetRootLayer().Save()
    seen: list[logging.LogRecord] = []
    handler = logging.Handler(logging.WARNING)
    handler.emit = seen.append
    log = logging.getLogger("lfusd")
    log.addHandler(handler)
    try:
        files = stage_files(tmp_path / "s.usda")
    finally:
        log.removeHandler(handler)
    assert sorted(files) == ["lib/oak.usdz", "s.usda"]
    assert files["lib/oak.usdz"]["sha256"] == file_hash(tree)
    assert not seen, [r.getMessage() for r in seen]


def test_a_glTF_shaped_character_with_a_light_is_a_catalogue_person_whose_light_is_off(tmp_path, capsys):
    """A glTF-converted character (Y-up, centimetres, a rotation above its SkelRoot, skinned,
    textured, and the exporter's light): added as a person with one warning naming the light;
    placed in a street, each copy is one person object standing on the pavement with its light
    switched off, and the street passes `lfusd check`."""
    from pxr import Usd, UsdLux
    from support.characters import gltf_numbered

    from lfusd.author.geometry import StageGeometry
    from lfusd.author.scenes import GAP, generate

    man = tmp_path / "people" / "man.usda"
    man.parent.mkdir()
    gltf_numbered(man)
    code, out, err = run_cli(capsys, "assets", "add", man, "--class", "person")
    assert code == 0, err
    assert "switched off where it is placed" in err and "/Root/Light" in err
    (a,) = load_catalogue(tmp_path / "people" / "catalogue.json")
    assert a.lights == ("Light",) and a.up_axis == "Y" and a.meters_per_unit == pytest.approx(CM)
    stage = generate("street", tmp_path / "s.usda", 1, frames=1, rigs=1, grid=(2, 2), resolution=(32, 32),
                     catalogues=[tmp_path / "people" / "catalogue.json"])
    placed, _ = _asset_objects(stage)
    assert placed and {o.label for o in placed} == {"person"}
    lights = [p for p in Usd.PrimRange(stage.GetPseudoRoot()) if p.HasAPI(UsdLux.LightAPI) or p.IsA(UsdLux.BoundableLightBase)]
    assert not any(str(p.GetPath()).startswith(tuple(o.prim_path + "/" for o in placed)) for p in lights)
    for o in placed:
        assert not stage.GetPrimAtPath(f"{o.prim_path}/Asset/Model/Light").IsActive()
    geo = StageGeometry(stage)
    for o in placed:  # standing on the pavement (its top 0.15 m) or the bridge of the street's people: 1 mm above
        z = np.concatenate([geo.mesh(p, 1).vertices for p in geo.parts_of(o.prim_path)])[:, 2].min()
        assert z == pytest.approx(0.15 + GAP, abs=1e-5), o.prim_path
    code, out, err = run_cli(capsys, "check", tmp_path / "s.usda", "--no-coverage")
    assert code == 0 and "all constraints hold" in out, out + err


def test_a_light_inside_an_instance_is_refused(tmp_path, capsys):
    from pxr import Usd, UsdGeom, UsdLux

    from lfusd.author.labels import set_class_label

    path = tmp_path / "lamp_post.usda"
    stage = Usd.Stage.CreateNew(str(path))
    root = stage.DefinePrim("/Post", "Xform")
    stage.SetDefaultPrim(root)
    set_class_label(root, "bench")
    proto = stage.CreateClassPrim("/_Head")
    UsdLux.SphereLight.Define(stage, "/_Head/Bulb")
    UsdGeom.Cube.Define(stage, "/_Head/Box")
    head = stage.DefinePrim("/Post/Head", "Xform")
    head.GetReferences().AddInternalReference(proto.GetPath())
    head.SetInstanceable(True)
    stage.GetRootLayer().Save()
    code, _, err = run_cli(capsys, "assets", "add", path)
    assert_one_line_error(code, err, "light inside an instance", "/Post/Head/Bulb")


def test_an_implausibly_sized_asset_is_flagged_and_a_class_left_out_is_said(tmp_path, capsys):
    """Issue 39.17: a car in centimetres whose file says metres was a silent 420 m car, and then no
    car at all in the street; now its size is flagged when added (with the metersPerUnit that fits)
    and the street says it has no car."""
    from pxr import Sdf

    car = write_car(tmp_path / "lib", name="giant")
    layer = Sdf.Layer.FindOrOpen(str(car))
    layer.pseudoRoot.SetInfo("metersPerUnit", 1.0)  # the converter's mistake: centimetres declared as metres
    layer.Save()
    cat = tmp_path / "cat.json"
    code, out, err = run_cli(capsys, "assets", "add", car, "--catalogue", cat)
    assert code == 0, err
    warn = [ln for ln in err.splitlines() if "implausible" in ln]
    assert len(warn) == 1 and f"a {CAR_LENGTH:.3g} m car" in warn[0] and "metersPerUnit = 0.01" in warn[0], err
    code, out, err = run_cli(capsys, "stage", "new", "street", "-o", tmp_path / "s.usda", "--frames", "1", "--rigs", "1",
                             "--grid", "2x2", "--resolution", "32x32", "--catalogue", cat)
    assert code == 0, err
    assert "the street scene has no car" in err and "1 car asset found room" in err, err
    # a plausible car: no word about its size, and the street has cars
    good = write_car(tmp_path / "ok", name="sedan")
    code, _, err = run_cli(capsys, "assets", "add", good, "--catalogue", tmp_path / "ok.json")
    assert code == 0 and "implausible" not in err
    code, _, err = run_cli(capsys, "stage", "new", "street", "-o", tmp_path / "t.usda", "--frames", "1", "--rigs", "1",
                           "--grid", "2x2", "--resolution", "32x32", "--catalogue", tmp_path / "ok.json")
    assert code == 0 and "has no car" not in err, err


@pytest.mark.parametrize("craft,needle", [
    (lambda e: e.__setitem__("bounds", [[0, 0], [1, 1]]), "'bounds'"),
    (lambda e: e.__setitem__("prim", "bad prim!!"), "is not an absolute prim path"),
    (lambda e: e.__setitem__("lights", ["../../../../Rigs"]), "is not a prim path below the asset's prim"),
    (lambda e: e.__setitem__("name", "../x\nlfusd: all fine"), "is not an asset name"),
    (lambda e: e.__setitem__("up_axis", "W"), "'up_axis'"),
])
def test_a_crafted_catalogue_entry_is_one_line_in_check_and_stage_new(tmp_path, capsys, craft, needle):
    """Issue 39 item 6: a catalogue entry lfusd would not write (two-component bounds, an invalid
    prim, a light path climbing out of the asset to deactivate the scene's rigs, a name with ../
    and a newline) is refused in one line by `assets check` and `stage new`, not exit 3 or passed."""
    write_car(tmp_path / "lib")
    assert run_cli(capsys, "assets", "add", tmp_path / "lib")[0] == 0
    cat = tmp_path / "lib" / "catalogue.json"
    doc = json.loads(cat.read_text())
    craft(doc["assets"][0])
    cat.write_text(json.dumps(doc))
    code, _, err = run_cli(capsys, "assets", "check", cat)
    assert code == 2
    assert_one_line_error(code, err, "damaged entry", needle)
    code, _, err = run_cli(capsys, "stage", "new", "street", "-o", tmp_path / "s.usda", "--catalogue", cat)
    assert code == 2
    assert_one_line_error(code, err, "damaged entry", needle)
    assert not (tmp_path / "s.usda").exists()
