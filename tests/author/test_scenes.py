"""The scene library (lfusd.author.scenes) and `lfusd stage new`: determinism, content, constraints."""

from __future__ import annotations

import hashlib
import zlib
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade

from lfusd import cli
from lfusd.author.rules import Checker, usd_validation
from lfusd.data.formats import read_png
from lfusd.author.geometry import triangulate
from lfusd.author.labels import class_label, object_table
from lfusd.author.scenes import TEMPLATES, generate
from lfusd.author.scenes import objects as kit
from lfusd.author.scenes.build import box, crease_normals, cylinder, prism
from lfusd.author.scenes.textures import DETAIL_SIZE, TEXTURES, normal_map, texture_pixels
from lfusd.author.rigs import rigs

SMALL = dict(frames=3, rigs=2, grid=(1, 1), resolution=(32, 32))


def small(tmp_path, template, seed=0, **kw):
    args = {**SMALL, **kw}
    return generate(template, tmp_path / f"{template}_{seed}.usda", seed, **args)


def signed_volume(points, counts, indices):
    t = triangulate(np.asarray(counts), np.asarray(indices))
    v = np.asarray(points, float)[t]
    return float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0)


def test_mesh_primitives_are_closed_and_outward():
    # The divergence theorem gives the enclosed volume only for a closed, consistently wound mesh;
    # a positive sign means outward normals (USD rightHanded), which Blender shades and shadows right.
    b = box((1.0, 2.0, 3.0), (5.0, -1.0, 2.0))
    assert signed_volume(b.points, b.counts, b.indices) == pytest.approx(6.0)
    n = 24
    polygon_area = 0.5 * n * np.sin(2 * np.pi / n)  # regular n-gon of radius 1
    for axis in ("z", "x", "y"):
        c = cylinder(1.0, 0.0, 2.0, n, axis=axis)
        assert signed_volume(c.points, c.counts, c.indices) == pytest.approx(2.0 * polygon_area)
    p = prism([(0, 0), (2, 0), (2, 1), (0, 1)], 0.0, 3.0)
    assert signed_volume(p.points, p.counts, p.indices) == pytest.approx(6.0)


def test_every_kit_part_is_closed_and_rests_on_z0():
    rng = np.random.default_rng(0)
    kits = [kit.car(rng), kit.person(rng), kit.tree(rng), kit.street_light(rng)[0], kit.bench(rng),
            kit.building(rng, 8, 6)[0], kit.boat(rng)[0], kit.table(rng)[0], kit.chair(rng), kit.bowl_kit(rng),
            kit.floor_lamp(rng)[0], kit.cabinet(rng)]
    for parts in kits:
        assert min(float(np.min(d.points[:, 2])) for _, d, _ in parts) == pytest.approx(0.0, abs=1e-9)
        for name, d, tex in parts:
            assert tex in TEXTURES
            assert signed_volume(d.points, d.counts, d.indices) > 0, name
            assert len(d.uvs) == len(d.indices)


def test_textures_are_deterministic_png_files(tmp_path):
    a, b = texture_pixels("bricks"), texture_pixels("bricks")
    assert a.shape == (256, 256, 3) and a.dtype == np.uint8 and np.array_equal(a, b)
    assert not np.array_equal(a, texture_pixels("grass"))
    assert a.std() > 10  # real texture, something to match
    small(tmp_path, "street")
    png = (tmp_path / "textures" / "asphalt.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    # decode the single IDAT chunk by hand and compare with the pixels
    idat = png.index(b"IDAT")
    size = int.from_bytes(png[idat - 4:idat], "big")
    raw = np.frombuffer(zlib.decompress(png[idat + 4: idat + 4 + size]), np.uint8).reshape(256, 1 + 256 * 3)
    assert np.all(raw[:, 0] == 0)
    assert np.array_equal(raw[:, 1:].reshape(256, 256, 3), texture_pixels("asphalt"))



def test_crease_normals_keep_box_edges_sharp_and_cylinders_round():
    d = box((1.0, 2.0, 3.0), (0.5, 0.0, 1.0))
    n = crease_normals(d.points, d.counts, d.indices)
    idx = np.asarray(d.indices)
    for f in range(6):  # every corner of a face carries the face's own outward normal
        corners = d.points[idx[4 * f:4 * f + 4]]
        face_n = np.cross(corners[1] - corners[0], corners[3] - corners[0])
        assert np.allclose(n[4 * f:4 * f + 4], face_n / np.linalg.norm(face_n), atol=1e-12)
    c = cylinder(0.5, 0.0, 1.0, 16)
    n, p = crease_normals(c.points, c.counts, c.indices), c.points[np.asarray(c.indices)]
    side = np.abs(n[:, 2]) < 0.5
    radial = p[side, :2] / np.linalg.norm(p[side, :2], axis=1, keepdims=True)  # the analytic surface normal
    assert side.sum() == 16 * 4 and np.allclose(n[side, :2], radial, atol=1e-12) and np.allclose(n[side, 2], 0.0)
    assert np.allclose(np.abs(n[~side, 2]), 1.0)  # flat caps


def test_normal_map_is_the_analytic_normal_of_its_height_field():
    # z = A sin(2 pi u / W) along the columns (u), and along v (up the image: row 0 is the top)
    w, a = 64, 3.0
    t = np.arange(w)
    along_u = np.tile(a * np.sin(2 * np.pi * t / w), (w, 1))
    n = normal_map(along_u)
    # central differences of a sine: slope A (2 pi / W) cos(.) times sin(2 pi / W) / (2 pi / W)
    slope = a * np.cos(2 * np.pi * t / w) * np.sin(2 * np.pi / w)
    expect = np.stack([-slope, np.zeros(w), np.ones(w)], -1) / np.sqrt(1 + slope**2)[:, None]
    assert np.allclose(n, expect[None], atol=1e-12)
    # the same wave up the image (row r is at v = W - 1 - r): the y component is the u case's x, flipped rows
    nv = normal_map(along_u.T[::-1])
    assert np.allclose(nv[..., 1], expect[:, 0][::-1, None], atol=1e-12) and np.allclose(nv[..., 0], 0.0, atol=1e-12)


@pytest.mark.parametrize("name", sorted(TEXTURES))
def test_every_texture_has_tileable_detail_maps(name):
    rough, normal = texture_pixels(f"{name}_roughness"), texture_pixels(f"{name}_normal")
    assert rough.shape == normal.shape == (DETAIL_SIZE, DETAIL_SIZE, 3) and rough.dtype == normal.dtype == np.uint8
    assert np.array_equal(rough[..., 0], rough[..., 1]) and rough[..., 0].std() > 1  # grey, and varying
    n = normal.astype(float) / 255 * 2 - 1
    assert np.allclose(np.linalg.norm(n, axis=-1), 1.0, atol=0.02) and (n[..., 2] > 0.5).all()  # unit, facing out
    # tileable: the wrap-around step is no larger than the steps inside
    for img in (rough.astype(float), normal.astype(float)):
        inside = np.abs(np.diff(img, axis=0)).max()
        assert np.abs(img[0] - img[-1]).max() <= inside and np.abs(img[:, 0] - img[:, -1]).max() <= np.abs(np.diff(img, axis=1)).max()


@pytest.mark.parametrize("template", TEMPLATES)
def test_same_seed_same_bytes_other_seed_other_scene(tmp_path, template):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    generate(template, tmp_path / "a" / "s.usda", 7, **SMALL)
    generate(template, tmp_path / "b" / "s.usda", 7, **SMALL)
    generate(template, tmp_path / "c.usda", 8, **SMALL)
    digest = lambda p: hashlib.sha256(p.read_bytes()).hexdigest()  # noqa: E731
    assert digest(tmp_path / "a" / "s.usda") == digest(tmp_path / "b" / "s.usda")
    assert digest(tmp_path / "a" / "s.usda") != digest(tmp_path / "c.usda")
    for png in (tmp_path / "a" / "textures").iterdir():
        assert digest(png) == digest(tmp_path / "b" / "textures" / png.name)


@pytest.mark.parametrize("template", TEMPLATES)
def test_template_content(tmp_path, template):
    stage = small(tmp_path, template, seed=3, rigs=3)
    assert UsdGeom.GetStageUpAxis(stage) == "Z" and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode(), stage.GetTimeCodesPerSecond()) == (1, 3, 24)
    objects, classes = object_table(stage)
    labels = {o.label for o in objects}
    required = TEMPLATES[template].labels
    assert required and required <= labels, required - labels
    assert all(o.label for o in objects)  # every piece of geometry belongs to a labelled object
    # Geometry is polygon meshes only (no implicit shapes that Blender would tessellate its own way).
    for prim in stage.Traverse():
        if prim.IsA(UsdGeom.Gprim):
            assert prim.IsA(UsdGeom.Mesh), prim.GetPath()
            mesh = UsdGeom.Mesh(prim)
            assert mesh.GetSubdivisionSchemeAttr().Get() == "none"
            pts = np.array(mesh.GetPointsAttr().Get())
            assert signed_volume(pts, mesh.GetFaceVertexCountsAttr().Get(), mesh.GetFaceVertexIndicesAttr().Get()) > 0
            # bound to a UsdPreviewSurface whose diffuse colour reads an existing PNG by a relative path
            mat, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
            surface = mat.ComputeSurfaceSource()[0]
            assert surface.GetIdAttr().Get() == "UsdPreviewSurface"
            tex = surface.GetInput("diffuseColor").GetConnectedSources()[0][0].source
            asset = UsdShade.Shader(tex.GetPrim()).GetInput("file").Get()
            assert asset.path.startswith("./textures/") and (tmp_path / asset.path).is_file()
    lights = {p.GetTypeName() for p in stage.Traverse() if p.HasAPI(UsdLux.LightAPI)}
    # a sky dome always; a sun only when the drawn lighting setup is "sun" (tests/author/test_choreography.py)
    setup = stage.GetDefaultPrim().GetCustomDataByKey("lfusd:lighting")["setup"]
    assert "DomeLight" in lights and ("DistantLight" in lights) == (setup == "sun") and len(lights) >= 2, lights
    for p in stage.Traverse():
        if p.HasAPI(UsdLux.LightAPI):
            assert UsdLux.LightAPI(p).GetNormalizeAttr().Get() is True
    found = rigs(stage)
    assert sorted(found) == ["rig_00", "rig_01", "rig_02"]
    for r in found.values():
        assert (r.spec.rows, r.spec.cols, r.spec.width) == (1, 1, 32)
        assert np.linalg.norm(np.subtract(r.spec.look_at, r.spec.at)) >= 2.0


def test_default_rig_spec_and_count(tmp_path):
    stage = generate("street", tmp_path / "r.usda", 1, frames=2)  # (rooms take a 0.05 m baseline)
    found = rigs(stage)
    assert sorted(found) == [f"rig_{i:02d}" for i in range(10)]
    s = found["rig_05"].spec
    assert (s.rows, s.cols, s.baseline, s.focal_length_mm, s.sensor_mm, s.width, s.height) == (9, 9, 0.125, 39.0, 36.0, 1024, 1024)


def test_generated_scenes_pass_check(tmp_path):
    # 12 scenes here (seeds 0..11 across the four templates); benchmarks/bench_stage_new.py runs 50.
    for k in range(12):
        template = list(TEMPLATES)[k % len(TEMPLATES)]
        stage = generate(template, tmp_path / f"{template}_{k}.usda", k, **SMALL)
        problems = [v.line() for v in Checker(stage).check()] + usd_validation(stage)
        assert problems == [], (template, k, problems)


def _move(stage, path, xyz):
    op = UsdGeom.Xformable(stage.GetPrimAtPath(path)).GetOrderedXformOps()[0]
    op.Set(Gf.Vec3d(*xyz))


def test_breaking_a_generated_street_is_caught(tmp_path):
    stage = small(tmp_path, "street", seed=5)
    cars = [o.prim_path for o in object_table(stage)[0] if o.label == "car"]
    verge = stage.GetPrimAtPath("/World/Verge_N")
    lo = np.array(UsdGeom.Imageable(verge).ComputeWorldBound(1, "default").ComputeAlignedRange().GetMin())
    hi = np.array(UsdGeom.Imageable(verge).ComputeWorldBound(1, "default").ComputeAlignedRange().GetMax())
    _move(stage, cars[0], ((lo[0] + hi[0]) / 2 + 0.37, hi[1] - 2.5, hi[2] + 0.001))  # onto the grass
    lines = [v.line() for v in Checker(stage).check()]
    assert any(ln.startswith(f"{cars[0]}: on broken at frame 1") and "'grass'" in ln for ln in lines), lines


def test_breaking_a_generated_river_is_caught(tmp_path):
    stage = small(tmp_path, "river", seed=2)
    boats = [o.prim_path for o in object_table(stage)[0] if o.label == "boat"]
    people = [o.prim_path for o in object_table(stage)[0] if o.label == "person"]
    bank = UsdGeom.Imageable(stage.GetPrimAtPath("/World/Bank_S")).ComputeWorldBound(1, "default").ComputeAlignedRange()
    _move(stage, boats[0], (25.0, bank.GetMin()[1] + 2.5, 0.001))  # a boat on the grass bank
    water = UsdGeom.Imageable(stage.GetPrimAtPath("/World/River")).ComputeWorldBound(1, "default").ComputeAlignedRange()
    _move(stage, people[0], (-27.0, 0.0, water.GetMax()[2] + 0.001))  # a person standing on the river
    lines = [v.line() for v in Checker(stage).check()]
    assert any(ln.startswith(f"{boats[0]}: floats_on broken at frame 1") for ln in lines), lines
    assert any(ln.startswith(f"{people[0]}: not_on broken at frame 1") and "'water'" in ln for ln in lines), lines


def test_breaking_a_generated_room_is_caught(tmp_path):
    stage = small(tmp_path, "room", seed=4)
    bowls = [o.prim_path for o in object_table(stage)[0] if o.label == "bowl"]
    chairs = [o.prim_path for o in object_table(stage)[0] if o.label == "chair"]
    table = UsdGeom.Imageable(stage.GetPrimAtPath("/World/Table")).ComputeWorldBound(1, "default").ComputeAlignedRange()
    c = (np.array(table.GetMin()) + np.array(table.GetMax())) / 2
    _move(stage, bowls[0], (c[0], c[1], 2.2))  # a bowl in mid-air above the table
    _move(stage, chairs[0], (c[0], c[1], 0.001))  # a chair inside the table
    lines = [v.line() for v in Checker(stage).check()]
    assert any(ln.startswith(f"{bowls[0]}: on broken at frame 1") and "above" in ln for ln in lines), lines
    # one line per (object, rule): the first intersecting partner found is named
    assert any(ln.startswith(f"{chairs[0]}: no_interpenetration broken at frame 1") for ln in lines), lines
    assert any(ln.startswith("/World/Table: no_interpenetration broken at frame 1") and chairs[0] in ln for ln in lines), lines


def test_stage_new_cli_and_errors(tmp_path, capsys):
    out = tmp_path / "stages" / "m.usda"
    code = cli.main(["stage", "new", "mixed", "-o", str(out), "--seed", "4", "--frames", "12", "--rigs", "1",
                     "--grid", "3x2", "--resolution", "40x30"])
    assert code == 0 and out.is_file() and (out.parent / "textures" / "grass.png").is_file()
    stage = Usd.Stage.Open(str(out))
    r = rigs(stage)["rig_00"].spec
    assert (r.rows, r.cols, r.width, r.height) == (3, 2, 40, 30) and stage.GetEndTimeCode() == 12
    assert class_label(stage.GetPrimAtPath("/World/Road")) == "road"
    capsys.readouterr()
    for argv, expect in (
        (["stage", "new", "castle", "-o", str(tmp_path / "x.usda")], "unknown template 'castle'"),
        (["stage", "new", "room", "-o", str(tmp_path / "x.usda"), "--grid", "9by9"], "--grid"),
        (["stage", "new", "room", "-o", str(tmp_path / "x.usda"), "--rigs", "11"], "--rigs"),
        (["stage", "new", "room", "-o", str(tmp_path / "x.txt")], "must end in .usda"),
    ):
        assert cli.main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("lfusd: error:") and expect in err[0], err


STAGES = Path(__file__).resolve().parents[2] / "stages"
COMMITTED = sorted(p for p in STAGES.glob("*.usda") if p.name != "static_boxes.usda")


def _regenerate(stage: Usd.Stage, out: Path) -> None:
    """Regenerate a committed stage from the template, seed and sizes it records."""
    world = stage.GetDefaultPrim()
    template, seed = world.GetCustomDataByKey("lfusd:template"), world.GetCustomDataByKey("lfusd:seed")
    found = rigs(stage)
    spec = found["rig_00"].spec
    generate(template, out, seed, frames=int(stage.GetEndTimeCode()), rigs=len(found),
             grid=(spec.rows, spec.cols), resolution=(spec.width, spec.height),
             dynamic=bool(world.GetCustomDataByKey("lfusd:dynamic")))


@pytest.mark.slow
@pytest.mark.parametrize("path", COMMITTED, ids=lambda p: p.name)
def test_committed_stage_passes_check_and_regenerates_byte_for_byte(tmp_path, path):
    stage = Usd.Stage.Open(str(path))
    assert [v.line() for v in Checker(stage).check()] + usd_validation(stage) == []
    # The stage records its template and seed; regenerating them here must give the same bytes
    # on any CPU: every double is written rounded (stageio.round_layer).
    _regenerate(stage, tmp_path / path.name)
    assert (tmp_path / path.name).read_bytes() == path.read_bytes()
    # Textures are uint8 pixels (rounded by the code); their PNG bytes depend on the zlib build.
    pngs = sorted((tmp_path / "textures").iterdir())
    assert pngs
    for png in pngs:
        assert np.array_equal(read_png(png), read_png(STAGES / "textures" / png.name)), png.name


def _nudged(x, direction):
    """``x`` moved by one ulp towards ``direction``: what another CPU's SIMD path may return."""
    return np.nextafter(np.asarray(x, np.float64), direction)


def _double_values(layer):
    """[(spec, time code or None)] for every double-precision value authored in ``layer`` (a
    float's value already is float32: a float64 ulp does not move it)."""
    from lfusd.author.stage import float_attribute_specs

    out = []
    for spec in float_attribute_specs(layer):
        name = spec.typeName.scalarType.cppTypeName
        if (name == "double" or name.endswith("d")) and "Quat" not in name:
            out += [(spec, None)] if spec.HasDefaultValue() else []
            out += [(spec, t) for t in layer.ListTimeSamplesForPath(spec.path)]
    return out


@pytest.mark.parametrize("direction", [np.inf, -np.inf], ids=["up", "down"])
def test_last_bit_of_the_inputs_to_rounding_does_not_change_the_stage(tmp_path, monkeypatch, direction):
    import lfusd.author.scenes as scenes
    from lfusd.author.stage import round_layer, typed_value

    args = dict(frames=6, rigs=3, grid=(3, 3), resolution=(64, 64), dynamic=True)
    generate("street", tmp_path / "plain.usda", 5, **args)
    nudged = 0

    def nudge_then_round(layer):
        # every double the generator authored moves by one ulp, then is rounded as usual
        nonlocal nudged
        for spec, t in _double_values(layer):
            value = np.array(spec.default if t is None else layer.QueryTimeSample(spec.path, t), np.float64)
            nudged += value.size
            new = typed_value(_nudged(value, direction), spec.typeName)
            if t is None:
                spec.default = new
            else:
                layer.SetTimeSample(spec.path, t, new)
        return round_layer(layer)

    monkeypatch.setattr(scenes, "round_layer", nudge_then_round)
    generate("street", tmp_path / "nudged.usda", 5, **args)
    assert nudged > 1000  # rig cameras, object transforms, skeletons and animation samples
    assert (tmp_path / "nudged.usda").read_bytes() == (tmp_path / "plain.usda").read_bytes()


def test_round_layer_rounds_every_floating_point_value(tmp_path):
    from lfusd.author.stage import round_layer

    stage = Usd.Stage.CreateInMemory()
    prim = stage.DefinePrim("/P")
    third = 1.0 / 3.0
    prim.CreateAttribute("d", Sdf.ValueTypeNames.Double).Set(third)
    prim.CreateAttribute("m", Sdf.ValueTypeNames.Matrix4d).Set(Gf.Matrix4d(1.0).SetTranslate(Gf.Vec3d(third, -0.0, 1.0)))
    prim.CreateAttribute("v", Sdf.ValueTypeNames.Double3Array).Set([Gf.Vec3d(third, -1e-17, 2.0)])
    prim.CreateAttribute("q", Sdf.ValueTypeNames.Quatd).Set(Gf.Quatd(third, Gf.Vec3d(0.0, third, 0.0)))
    prim.CreateAttribute("f", Sdf.ValueTypeNames.Float3Array).Set([Gf.Vec3f(third, 5.5e-17, 20.1)])
    prim.CreateAttribute("t", Sdf.ValueTypeNames.Double3).Set(Gf.Vec3d(third, 0, 0), 2.0)
    assert round_layer(stage.GetRootLayer()) == 6
    r = 0.333333333
    assert prim.GetAttribute("d").Get() == r
    m = prim.GetAttribute("m").Get()
    assert m[3][0] == r and m[0][0] == 1.0
    v = prim.GetAttribute("v").Get()[0]
    assert (v[0], v[2]) == (r, 2.0)
    assert prim.GetAttribute("q").Get() == Gf.Quatd(r, Gf.Vec3d(0.0, r, 0.0))
    assert prim.GetAttribute("t").Get(2.0)[0] == r
    # float32: a residue of cancellation becomes 0; otherwise the float's own (coarser) step remains
    f = prim.GetAttribute("f").Get()[0]
    assert (f[1], f[2]) == (0.0, np.float32(20.1)) and f[0] == np.float32(r)
    text = stage.GetRootLayer().ExportToString()
    assert "-0" not in text.replace("e-0", "") and "e-17" not in text  # no negative zeros, no residues


@pytest.mark.slow
def test_a_cpu_whose_math_rounds_the_other_way_writes_the_same_stage(tmp_path, monkeypatch):
    # Emulate another CPU: NumPy's transcendental functions and norms return their neighbour
    # in the last bit (SVML against libm, FMA against none), upwards and then downwards. The stage
    # file must not change.
    args = dict(frames=6, rigs=3, grid=(3, 3), resolution=(64, 64), dynamic=True)
    for template in TEMPLATES:
        generate(template, tmp_path / f"{template}_plain.usda", 1, **args)
    plain = {name: getattr(np, name) for name in ("sin", "cos", "exp", "arctan2", "sqrt", "hypot", "radians", "degrees")}
    norm = np.linalg.norm
    for direction, label in ((np.inf, "up"), (-np.inf, "down")):
        calls = 0

        def wrap(fn, direction=direction):
            def nudged(*a, **kw):
                nonlocal calls
                calls += 1
                out = fn(*a, **kw)
                return _nudged(out, direction) if np.issubdtype(np.asarray(out).dtype, np.floating) else out
            return nudged

        for name, fn in plain.items():
            monkeypatch.setattr(np, name, wrap(fn))
        monkeypatch.setattr(np.linalg, "norm", wrap(norm))
        for template in TEMPLATES:
            out = tmp_path / f"{template}_{label}.usda"
            generate(template, out, 1, **args)
            assert out.read_bytes() == (tmp_path / f"{template}_plain.usda").read_bytes(), (template, label)
        assert calls > 1000, label


# -- dynamic variants (issue 6) ----------------------------------------------------------------------
DYN = dict(frames=48, rigs=2, grid=(3, 3), resolution=(64, 64), dynamic=True)


def _moving(stage):
    from lfusd.author.rules import _time_varying

    return [o for o in object_table(stage)[0] if _time_varying(stage.GetPrimAtPath(o.prim_path))]


@pytest.mark.parametrize("template", TEMPLATES)
def test_dynamic_scenes_move_and_pass_check(tmp_path, template):
    from pxr import UsdSkel

    for seed in (0, 1):
        stage = generate(template, tmp_path / f"{template}_{seed}.usda", seed, **DYN)
        assert [v.line() for v in Checker(stage).check()] + usd_validation(stage) == [], (template, seed)
        moving = _moving(stage)
        expected = TEMPLATES[template].movers
        assert expected and expected <= {o.label for o in moving}, (template, seed, [o.prim_path for o in moving])
        for o in moving:
            prim = stage.GetPrimAtPath(o.prim_path)
            if o.label == "person":  # an animated UsdSkel person, not a static blocky one
                assert prim.IsA(UsdSkel.Root)
            else:  # rigid movers: one world pose per frame that changes over the clip
                mats = [np.array(UsdGeom.Xformable(d).ComputeLocalToWorldTransform(f)) for d in Usd.PrimRange(prim)
                        if d.IsA(UsdGeom.Mesh) for f in (1, 48)]
                assert any(not np.allclose(a, b) for a, b in zip(mats[::2], mats[1::2])), o.prim_path
        # the blocky static people are gone: every person is animated
        assert all(stage.GetPrimAtPath(o.prim_path).IsA(UsdSkel.Root) for o in object_table(stage)[0] if o.label == "person")
        assert stage.GetDefaultPrim().GetCustomDataByKey("lfusd:dynamic") is True


def test_dynamic_seed_to_stage_is_byte_stable_and_keeps_the_static_scene(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    generate("river", tmp_path / "a" / "s.usda", 3, **DYN)
    generate("river", tmp_path / "b" / "s.usda", 3, **DYN)
    generate("river", tmp_path / "c.usda", 4, **DYN)
    assert (tmp_path / "a" / "s.usda").read_bytes() == (tmp_path / "b" / "s.usda").read_bytes()
    assert (tmp_path / "a" / "s.usda").read_bytes() != (tmp_path / "c.usda").read_bytes()
    # the dynamic variant is the static scene plus movers: its surfaces are authored identically
    static = generate("river", tmp_path / "static.usda", 3, **{**DYN, "dynamic": False})
    dyn = Usd.Stage.Open(str(tmp_path / "a" / "s.usda"))
    for path in ("/World/River", "/World/Bank_N", "/World/Bridge", "/World/Lights/Sky"):
        a, b = static.GetPrimAtPath(path), dyn.GetPrimAtPath(path)
        assert a and b
        for attr in a.GetAttributes():
            assert b.GetAttribute(attr.GetName()).Get() == attr.Get(), (path, attr.GetName())


def test_stage_new_dynamic_cli(tmp_path, capsys):
    out = tmp_path / "d.usda"
    code = cli.main(["stage", "new", "street", "-o", str(out), "--seed", "2", "--frames", "24", "--rigs", "1",
                     "--grid", "2x2", "--resolution", "32x32", "--dynamic"])
    assert code == 0 and "dynamic" in capsys.readouterr().out
    stage = Usd.Stage.Open(str(out))
    assert {"person", "car"} <= {o.label for o in _moving(stage)}
