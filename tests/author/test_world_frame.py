"""One world frame (issue 12): stages of any up axis and unit map into lfusd's Z-up metre world.

No Blender: the map itself, rigs authored on Y-up / centimetre stages, and pxr-side geometry,
each checked against the convention written out by hand (tests/support/world_stages.py).
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from pxr import Gf, Usd, UsdGeom, UsdSemantics

from lfusd import cli
from lfusd.author.rules import set_constraint

from lfusd.author.geometry import StageGeometry, local_to_world
from lfusd.author.rigs import rigs
from lfusd.author.stage import WorldFrame, open_stage, world_frame
from lfusd.camera import RigSpec
from tests.support.cli import run_cli
from tests.support.world_stages import BOX_EDGE, RIG_AT, RIG_LOOK_AT, box_centre, to_stage, to_world, world_rig, write_world_stage

CASES = [("Y", 0.01), ("Y", 1.0), ("Z", 0.0254), ("Z", 1.0)]


def test_world_frame_maps_stage_up_to_world_z_and_scales():
    f = WorldFrame("Y", 0.01)
    assert f.points([[0, 1, 0]])[0] == pytest.approx([0, 0, 0.01])
    assert f.points([[1, 0, 0]])[0] == pytest.approx([0.01, 0, 0])
    assert f.points([[0, 0, 1]])[0] == pytest.approx([0, -0.01, 0])  # stage +Z (towards the viewer) is world -Y
    assert np.linalg.det(f.rotation) == pytest.approx(1.0)  # a rotation, not a mirror
    assert WorldFrame("Z", 0.0254).points([[10, 20, 30]])[0] == pytest.approx([0.254, 0.508, 0.762])
    assert np.allclose(WorldFrame("Z", 1.0).matrix(), np.eye(4))
    d = f.to_dict()
    assert d["up_axis"] == "Y" and d["meters_per_unit"] == 0.01
    assert np.array(d["stage_to_world"]) @ [0, 100, 0, 1] == pytest.approx([0, 0, 1, 1])


def test_world_frame_reads_the_stage_and_usds_defaults():
    stage = Usd.Stage.CreateInMemory()
    assert world_frame(stage) == WorldFrame("Y", 0.01)  # USD's fallbacks: Y up, centimetres
    UsdGeom.SetStageUpAxis(stage, "Z")
    UsdGeom.SetStageMetersPerUnit(stage, 0.0254)
    assert world_frame(stage) == WorldFrame("Z", 0.0254)


def test_pose_is_rigid_with_translation_in_metres():
    f = WorldFrame("Y", 0.01)
    m = Gf.Matrix4d().SetRotate(Gf.Rotation(Gf.Vec3d(0.3, 1, -0.2), 35.0)) * Gf.Matrix4d().SetTranslate(Gf.Vec3d(100, 250, -40))
    pose = f.pose(m)
    R = pose[:3, :3]
    assert R.T @ R == pytest.approx(np.eye(3), abs=1e-12) and np.linalg.det(R) == pytest.approx(1.0)
    assert pose[:3, 3] == pytest.approx(to_world([100, 250, -40], "Y", 0.01))  # (1, 0.4, 2.5) m
    # The pose maps metre-scaled local points like the stage does: world(p_local @ M) = pose @ (mpu * p_local).
    p = np.array([7.0, -3.0, 12.0])
    stage_p = np.array(m.Transform(Gf.Vec3d(*p)))
    assert (pose[:3, :3] @ (p * 0.01) + pose[:3, 3]) == pytest.approx(to_world(stage_p, "Y", 0.01))


@pytest.mark.parametrize("up,mpu", CASES)
def test_rig_on_any_stage_sits_at_the_stage_point_looks_at_its_target_and_keeps_stage_up_as_image_up(tmp_path, up, mpu):
    write_world_stage(tmp_path / "s.usda", up, mpu, world_rig(up, rows=3, cols=3))
    stage = open_stage(tmp_path / "s.usda")
    rig = rigs(stage)["main"]
    target = RIG_LOOK_AT
    for view in rig.spec.views:
        c2w = rig.cam_to_world(stage, view, 1)
        R, t = c2w[:3, :3], c2w[:3, 3]
        assert R.T @ R == pytest.approx(np.eye(3), abs=1e-9)
        # Parallel rig: every camera looks along the centre's axis, towards RIG_LOOK_AT.
        axis = (target - RIG_AT) / np.linalg.norm(target - RIG_AT)
        assert R[:, 2] == pytest.approx(axis, abs=1e-9)
        # Image "up" (OpenCV -y) is in the vertical plane of the axis with positive world Z: no roll.
        up_dir = -R[:, 1]
        assert up_dir[2] > 0.5 and abs(np.dot(R[:, 0], [0, 0, 1])) < 1e-9
        sx, sy = rig.spec.offsets(view)
        assert t == pytest.approx(RIG_AT + R[:, 0] * sx * 0.1 + R[:, 1] * sy * 0.1, abs=1e-9)
    centre = rig.cam_to_world(stage, (1, 1), 1)
    assert centre[:3, 3] == pytest.approx(RIG_AT, abs=1e-9)
    # The rig prim is authored in scene units: its stage translation is the --at point in scene units.
    xf = UsdGeom.Xformable(stage.GetPrimAtPath(rig.prim_path)).ComputeLocalToWorldTransform(Usd.TimeCode(1))
    assert np.array(xf.ExtractTranslation()) == pytest.approx(to_stage(RIG_AT, up, mpu), rel=1e-9)
    # Lens and clipping in tenths of a scene unit / scene units, as USD (and Blender's importer) read them.
    cam = UsdGeom.Camera(stage.GetPrimAtPath(rig.cameras[(0, 0)]))
    assert cam.GetFocalLengthAttr().Get() * 100 * mpu == pytest.approx(50.0, rel=1e-6)
    assert cam.GetHorizontalApertureAttr().Get() * 100 * mpu == pytest.approx(36.0, rel=1e-6)
    assert np.array(cam.GetClippingRangeAttr().Get()) * mpu == pytest.approx([0.01, 1.0e4], rel=1e-6)


def test_y_up_rig_is_not_rolled_in_the_stage_either(tmp_path):
    """Seen in the stage's own axes (as a Y-up tool shows it), image up is the stage's +Y."""
    write_world_stage(tmp_path / "s.usda", "Y", 0.01, world_rig("Y", rows=1, cols=1))
    stage = open_stage(tmp_path / "s.usda")
    cam = stage.GetPrimAtPath(rigs(stage)["main"].cameras[(0, 0)])
    m = np.array(UsdGeom.Xformable(cam).ComputeLocalToWorldTransform(Usd.TimeCode(1)))
    cam_up_in_stage = m[1, :3] / np.linalg.norm(m[1, :3])  # USD camera +Y, row-vector matrix
    cam_right_in_stage = m[0, :3] / np.linalg.norm(m[0, :3])
    assert cam_up_in_stage[1] > 0.5 and abs(cam_right_in_stage[1]) < 1e-9


def test_rig_add_cli_takes_negative_stage_coordinates_on_a_y_up_cm_stage(capsys, tmp_path):
    path = tmp_path / "s.usda"
    write_world_stage(path, "Y", 0.01)
    code, _, err = run_cli(capsys, "rig", "add", str(path), "--name", "neg", "--grid", "1x1", "--resolution", "16x16",
                           "--at", "-0.05,0.6,3", "--look-at", "-1,-2,0.5")
    assert code == 0, err
    stage = open_stage(path)
    rig = rigs(stage)["neg"]
    assert rig.spec.at == pytest.approx((-0.05, 0.6, 3.0)) and rig.spec.look_at == pytest.approx((-1.0, -2.0, 0.5))
    c2w = rig.cam_to_world(stage, (0, 0), 1)
    # Metres along the stage's axes: Y-up (x, y, z) is world (x, -z, y).
    at, look = np.array([-0.05, -3.0, 0.6]), np.array([-1.0, -0.5, -2.0])
    assert c2w[:3, 3] == pytest.approx(at, abs=1e-9)
    assert c2w[:3, 2] == pytest.approx((look - at) / np.linalg.norm(look - at), abs=1e-9)
    assert abs(c2w[2, 0]) < 1e-9 and -c2w[2, 1] > 0  # image x level, image up towards the stage's up (world +Z)


@pytest.mark.parametrize("up", ["Y", "Z"])
def test_rig_add_default_pose_stands_upright_on_any_up_axis(capsys, tmp_path, up):
    """Without --at/--look-at the rig is 1.5 m up, 10 m back, looking level at a point 1.5 m above
    the origin, on a Y-up centimetre stage as on a Z-up one (not 10 m below its floor)."""
    path = tmp_path / "s.usda"
    write_world_stage(path, up, 0.01)
    code, _, err = run_cli(capsys, "rig", "add", str(path), "--grid", "1x1", "--resolution", "16x16")
    assert code == 0, err
    stage = open_stage(path)
    c2w = rigs(stage)["main"].cam_to_world(stage, (0, 0), 1)
    assert c2w[:3, 3] == pytest.approx((0.0, -10.0, 1.5), abs=1e-9)
    assert c2w[:3, 2] == pytest.approx((0.0, 1.0, 0.0), abs=1e-9)  # looking level along world +Y
    assert -c2w[2, 1] == pytest.approx(1.0)  # image up is world +Z, the stage's up


def test_existing_z_up_metre_rigs_are_unchanged(tmp_path):
    """The map is the identity on lfusd's own stages: the rig is exactly RigSpec's pose."""
    spec = RigSpec(name="r", rows=2, cols=3, width=16, height=16, at=(0.2, -5.0, 1.6), look_at=(0.0, 0.0, 0.6))
    write_world_stage(tmp_path / "s.usda", "Z", 1.0, spec)
    stage = open_stage(tmp_path / "s.usda")
    rig = rigs(stage)["r"]
    for view in spec.views:
        assert rig.cam_to_world(stage, view, 1) == pytest.approx(spec.cam_to_world(view), abs=1e-9)


@pytest.mark.parametrize("up,mpu", CASES)
def test_stage_geometry_and_object_poses_are_the_mapped_stage_points(tmp_path, up, mpu):
    stage = write_world_stage(tmp_path / "s.usda", up, mpu)
    geo = StageGeometry(stage)
    e = BOX_EDGE / 2
    for frame in (1, 3):
        box = geo.mesh(stage.GetPrimAtPath("/World/Box/Geom"), frame)
        # Stage points of the box at this frame (pxr's own transform, in scene units), mapped by hand.
        xf = np.array(UsdGeom.Xformable(stage.GetPrimAtPath("/World/Box")).ComputeLocalToWorldTransform(Usd.TimeCode(frame)))
        pts = np.array(UsdGeom.Mesh(stage.GetPrimAtPath("/World/Box/Geom")).GetPointsAttr().Get(), float)
        stage_pts = pts @ xf[:3, :3] + xf[3, :3]
        assert box.vertices == pytest.approx(to_world(stage_pts, up, mpu), abs=1e-6)
        # ... which are the designed world corners: Z-up, metres, resting on z = 0.
        assert box.vertices.min(0) == pytest.approx(box_centre(frame) - e, abs=1e-6)
        assert box.vertices.max(0) == pytest.approx(box_centre(frame) + e, abs=1e-6)
        # The object pose maps the prim's local points, scaled to metres, to the world; rigid.
        pose = local_to_world(stage, "/World/Box", frame)
        assert pose[:3, 3] == pytest.approx(box_centre(frame), abs=1e-6)
        assert pose[:3, :3] @ (pts.T * mpu) + pose[:3, 3:] == pytest.approx(box.vertices.T, abs=1e-6)
        assert pose[:3, :3].T @ pose[:3, :3] == pytest.approx(np.eye(3), abs=1e-9)


# -- lfusd check and animate on users' stages ----------------------------------------------------
def _stage_box(stage, path, label, lo, hi, up, mpu):
    """A box lo..hi (world metres) authored in the stage's axes and units: a labelled Xform
    translated to its centre with a unit Cube scaled to its extent."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    x = UsdGeom.Xform.Define(stage, path)
    x.AddTranslateOp().Set(Gf.Vec3d(*to_stage((lo + hi) / 2, up, mpu)))
    cube = UsdGeom.Cube.Define(stage, f"{path}/geo")
    cube.CreateSizeAttr(1.0)
    cube.AddScaleOp().Set(Gf.Vec3f(*np.abs(to_stage(hi - lo, up, mpu))))
    if label:
        UsdSemantics.LabelsAPI.Apply(x.GetPrim(), "class").CreateLabelsAttr([label])
    return x


@pytest.mark.parametrize("up,mpu", [("Y", 0.01), ("Z", 0.0254)])
def test_check_rules_hold_in_the_world_on_other_axes_and_units(tmp_path, capsys, up, mpu):
    """Road, grass and a river (surface 0.3 m below the ground); a person walks 2.5 m per frame
    from the grass into the river and out of a guide region ending at x = 4 m: both rules break
    at frame 3 exactly, in metres and Z-up, whatever the stage's axes and units."""
    stage = Usd.Stage.CreateNew(str(tmp_path / "s.usda"))
    UsdGeom.SetStageUpAxis(stage, up)
    UsdGeom.SetStageMetersPerUnit(stage, mpu)
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(3)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    _stage_box(stage, "/World/Road", "road", (-10, -5, -0.2), (0, 5, 0), up, mpu)
    _stage_box(stage, "/World/Grass", "grass", (0, -5, -0.2), (5, 5, 0), up, mpu)
    _stage_box(stage, "/World/River", "water", (5, -5, -2.0), (15, 5, -0.3), up, mpu)
    zone = _stage_box(stage, "/World/Zone", "", (-10, -5, -1), (4, 5, 3), up, mpu)
    UsdGeom.Imageable(zone.GetPrim()).CreatePurposeAttr(UsdGeom.Tokens.guide)
    walker = _stage_box(stage, "/World/Walker", "person", (0.8, -0.2, 0.001), (1.2, 0.2, 1.801), up, mpu)
    set_constraint(walker.GetPrim(), "inside", "/World/Zone")
    op = walker.GetOrderedXformOps()[0]
    for f in (1, 2, 3):  # x = 1, 3.5, 6 m: on grass, on grass, over the river
        op.Set(Gf.Vec3d(*to_stage([1.0 + 2.5 * (f - 1), 0.0, 0.901], up, mpu)), Usd.TimeCode(f))
    stage.Save()
    code = cli.main(["check", str(tmp_path / "s.usda")])
    out = capsys.readouterr().out.splitlines()
    broken = sorted(m.groups() for m in (re.match(r"(\S+): (\w+) broken at frame (\d+)", ln) for ln in out) if m)
    assert code == 1
    assert broken == [("/World/Walker", kind, "3") for kind in ("inside", "not_on", "on")], out


PERSON_LAST = 30  # frames 1-30: 1.1 s, setting off and walking


def _person_on(tmp_path, up, mpu, *extra):
    """The world stage with frames 1..PERSON_LAST and a person added by the CLI walking along a path
    given in metres along the stage's horizontal axes (X, Y on Z-up; X, Z on Y-up) that is world
    (-2, -1) -> (2, -1); returns (stage, the person's skinned world vertices per frame)."""
    path = tmp_path / f"{up}_{mpu}.usda"
    stage = write_world_stage(path, up, mpu)
    stage.SetEndTimeCode(PERSON_LAST)
    stage.Save()
    axes = [to_stage([x, -1.0, 0.0], up, 1.0) for x in (-2.0, 2.0)]
    horizontal = [0, 2] if up == "Y" else [0, 1]
    pts = [f"{a[horizontal[0]]:g},{a[horizontal[1]]:g}" for a in axes]
    assert cli.main(["animate", "add-person", str(path), "--path", *pts, *extra]) == 0
    stage = open_stage(path)
    geo = StageGeometry(stage)
    body = stage.GetPrimAtPath("/World/People/Person_00/Body")
    return stage, np.array([geo.mesh(body, float(f)).vertices for f in range(1, PERSON_LAST + 1)])


@pytest.mark.parametrize("up,mpu", [("Y", 0.01), ("Z", 0.0254), ("Y", 1.0)])
def test_add_person_walks_the_same_world_path_on_any_stage(tmp_path, capsys, up, mpu):
    """A person added to a Y-up or non-metre stage is, in lfusd's world, the person added to the same
    scene on a Z-up metre stage (same path in metres along the stage's axes, vertex for vertex), and
    that one walks along world y = -1 from x = -2, upright, 1.75 m tall, soles on the ground."""
    ref_stage, ref = _person_on(tmp_path, "Z", 1.0)
    stage, got = _person_on(tmp_path, up, mpu)
    assert np.abs(got - ref).max() < 1e-4
    centre = ref.mean(axis=1)
    assert np.abs(centre[:, 1] + 1.0).max() < 0.1 and abs(centre[0, 0] + 2.0) < 0.1
    assert np.all(np.diff(centre[:, 0]) > -1e-3) and centre[-1, 0] > -1.0  # along +x, about 1.2 m in 1.2 s
    height = ref[..., 2].max(axis=1)
    assert np.all((height > 1.6) & (height < 1.8))
    assert np.abs(ref[..., 2].min(axis=1)).max() < 0.01  # the ground is world z = 0
    assert cli.main(["check", str(tmp_path / f"{up}_{mpu}.usda")]) == 0, capsys.readouterr().out


def test_add_person_reports_path_points_in_the_stages_own_axes(tmp_path, capsys):
    """Off the ground, the refusal names the point in the stage's axes (X, Z on a Y-up stage), not lfusd's world."""
    path = tmp_path / "s.usda"
    stage = write_world_stage(path, "Y", 0.01)
    stage.SetEndTimeCode(72)
    stage.Save()
    before = path.read_bytes()
    code, _, err = run_cli(capsys, "animate", "add-person", str(path), "--path", "0,2", "0,9")
    assert code == 2 and "under 0.00,3." in err and "\n" not in err.strip(), err
    assert path.read_bytes() == before
