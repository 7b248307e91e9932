"""People on paths: terrain following, smooth turns, water refused, user characters, Blender skinning.

Stages here are written with plain pxr and closed-form ground heights, so every expected height
and frame is computed independently of lfusd.
"""

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt

from lfusd.author.people import FILLET_RADIUS, add_person, parse_points
from lfusd.errors import LfusdError
from lfusd.author.geometry import StageGeometry
from lfusd.author.human import HumanSpec, define_human
from lfusd.author.labels import class_label, set_class_label
from support.skel_measure import joint_world, planted_steps

ROOT = Path(__file__).resolve().parents[2]
PY = sys.executable


def _quad(stage, path, label, x0, x1, y0, y1, z0, z1=None):
    """A labelled quad from x0 to x1 whose height rises linearly from z0 to z1 along x."""
    z1 = z0 if z1 is None else z1
    set_class_label(UsdGeom.Xform.Define(stage, path).GetPrim(), label)
    m = UsdGeom.Mesh.Define(stage, path + "/Mesh")
    m.CreatePointsAttr([(x0, y0, z0), (x1, y0, z1), (x1, y1, z1), (x0, y1, z0)])
    m.CreateFaceVertexCountsAttr([4])
    m.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    m.CreateSubdivisionSchemeAttr("none")


def _plain_stage(path, last):
    """A stage written without lfusd: Z up, metres, 24 fps, frames 1..last."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(24)
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(last)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    return stage


def slope_stage(path, last=96):
    """Flat ground for x < 0, a 10 % slope (z = 0.1 x) for x in 0..10."""
    stage = _plain_stage(path, last)
    _quad(stage, "/World/Flat", "ground", -10, 0, -10, 10, 0.0)
    _quad(stage, "/World/Slope", "grass", 0, 10, -10, 10, 0.0, 1.0)
    stage.Save()
    return stage


def slope_z(xy):
    return np.where(xy[..., 0] < 0, 0.0, 0.1 * xy[..., 0])


def river_stage(path, last=150, bridge=False):
    """Ground (x < 3), a river (3 < x < 6, surface 0.3 m down), grass beyond; optionally a bridge."""
    stage = _plain_stage(path, last)
    _quad(stage, "/World/Ground", "ground", -10, 3, -10, 10, 0.0)
    _quad(stage, "/World/River", "river", 3, 6, -10, 10, -0.3)
    _quad(stage, "/World/Bank", "grass", 6, 12, -10, 10, 0.0)
    if bridge:
        _quad(stage, "/World/Bridge", "bridge", 2.5, 6.5, -1, 1, 0.05)
    stage.Save()
    return stage


def _root_world(stage, prim_path, frames):
    xf = UsdGeom.Xformable(stage.GetPrimAtPath(prim_path))
    return np.array([np.array(xf.ComputeLocalToWorldTransform(Usd.TimeCode(float(f)))) for f in frames])


def test_person_follows_terrain_and_plants_feet(tmp_path):
    stage = slope_stage(tmp_path / "slope.usda")
    frames = np.arange(1, 97)
    prim = add_person(stage, [(-4.0, -1.0), (5.0, -1.0), (5.0, 6.0)], gait="walk", speed=1.4, start=5)
    assert class_label(prim) == "person"
    root = _root_world(stage, prim.GetPath(), frames)
    # The root stands on the (closed-form) ground at every frame.
    assert np.abs(root[:, 3, 2] - slope_z(root[:, 3, :2])).max() < 1e-4
    assert root[-1, 3, 0] > 0.5 and root[-1, 3, 2] > 0.05  # it did climb the slope
    names, pos = joint_world(stage, f"{prim.GetPath()}/Skeleton", frames)
    ankle_h = 0.04 * 1.75
    for side in "lr":
        ankle = pos[:, names.index(f"{side}_ankle")]
        steps = planted_steps(ankle, slope_z(ankle[:, :2]))
        assert len(steps) >= 3
        assert max(s for _, _, s in steps) < 0.03
        # Flat on the ground when planted, also on the slope: the ankle and the ball of the foot
        # are at their standing heights above the surface under them.
        flat = np.concatenate([np.arange(i + (j - i) // 4, j + 1 - (j - i) // 4) for i, j, _ in steps])  # mid-stance
        toe = pos[flat, names.index(f"{side}_toe")]
        assert np.abs(ankle[flat, 2] - slope_z(ankle[flat, :2]) - ankle_h).max() < 0.005
        assert np.abs(toe[:, 2] - slope_z(toe[:, :2]) - 0.012 * 1.75).max() < 0.005


def test_person_turns_smoothly(tmp_path):
    stage = slope_stage(tmp_path / "turn.usda", last=150)
    speed = 1.4
    prim = add_person(stage, [(-9.0, -6.0), (-4.0, -6.0), (-4.0, 4.0)], gait="walk", speed=speed)
    frames = np.arange(1, 151)
    root = _root_world(stage, prim.GetPath(), frames)
    fwd = root[:, 1, :2]  # the character's +Y axis in the world (row-vector matrices)
    heading = np.unwrap(np.arctan2(fwd[:, 1], fwd[:, 0]))
    assert abs(heading[0] - 0.0) < 1e-6 and abs(heading[-1] - np.pi / 2) < 1e-3
    # Turning at walking speed on a fillet of radius R: at most speed / R radians per second.
    assert np.abs(np.diff(heading)).max() <= speed / FILLET_RADIUS / 24 * 1.05
    # The position moves at the walking speed, without jumps.
    step = np.linalg.norm(np.diff(root[:, 3, :2], axis=0), axis=1)
    assert step.max() <= speed / 24 + 1e-6
    names, pos = joint_world(stage, f"{prim.GetPath()}/Skeleton", frames)
    for side in "lr":
        ankle = pos[:, names.index(f"{side}_ankle")]
        assert max(s for _, _, s in planted_steps(ankle, slope_z(ankle[:, :2]))) < 0.03
    # The feet never cross over: the left ankle stays on the left of the body's line of travel.
    left, right = pos[:, names.index("l_ankle"), :2], pos[:, names.index("r_ankle"), :2]
    lateral = np.einsum("fi,fi->f", left - right, root[:, 0, :2])  # along the character's +X (right)
    assert np.all(lateral < 0)


@pytest.mark.parametrize("gait,speed,accel", [("walk", 1.3, 0.6), ("run", 3.5, 1.2)])
def test_person_sets_off_and_stops_at_rest(tmp_path, gait, speed, accel):
    stage = slope_stage(tmp_path / "trip.usda", last=120)
    start, length = 10, 4.0 if gait == "walk" else 7.0
    prim = add_person(stage, [(-8.0, 1.0), (-8.0 + length, 1.0)], gait=gait, speed=speed, start=start)
    frames = np.arange(1, 121)
    root = _root_world(stage, prim.GetPath(), frames)[:, 3, :3]
    v = np.linalg.norm(np.diff(root, axis=0), axis=1) * 24  # m/s between frames
    # Constant acceleration to the speed in ``accel`` seconds, cruising, and the mirror image to a stop.
    t = (frames[1:] - 0.5 - start) / 24
    expected = np.clip(np.minimum(t, (length / speed + accel) - t) * speed / accel, 0.0, speed)
    assert np.abs(v - expected).max() < 0.15 * speed
    assert np.allclose(root[0, :2], [-8.0, 1.0]) and np.allclose(root[-1, :2], [-8.0 + length, 1.0], atol=1e-6)
    # Standing still before and after: both feet down and still, side by side within a step.
    names, pos = joint_world(stage, f"{prim.GetPath()}/Skeleton", frames)
    for sl in (slice(0, start), slice(-10, None)):
        ankles = pos[sl][:, [names.index("l_ankle"), names.index("r_ankle")]]
        assert np.ptp(ankles, axis=0).max() < 1e-6
        assert np.allclose(ankles[0, :, 2], 0.04 * 1.75, atol=1e-3)
        assert np.linalg.norm(ankles[0, 0, :2] - ankles[0, 1, :2]) < 0.6


def test_idle_person_stands_in_place_breathing(tmp_path):
    stage = slope_stage(tmp_path / "idle.usda", last=72)
    prim = add_person(stage, [(-3.0, 2.0), (-3.0, 5.0)], gait="idle")
    frames = np.arange(1, 73)
    root = _root_world(stage, prim.GetPath(), frames)
    assert np.allclose(root[:, 3, :3], [-3.0, 2.0, 0.0], atol=1e-9)
    assert np.allclose(root[:, 1, :2], [0.0, 1.0], atol=1e-6)  # facing the second point (+Y)
    names, pos = joint_world(stage, f"{prim.GetPath()}/Skeleton", frames)
    ankles = pos[:, [names.index("l_ankle"), names.index("r_ankle")]]
    assert np.ptp(ankles, axis=0).max() < 1e-6  # feet still
    assert np.ptp(pos[:, names.index("head")], axis=0).max() > 0.005  # but the body moves


def test_path_across_the_river_is_refused_naming_the_frame(tmp_path):
    path = tmp_path / "river.usda"
    river_stage(path)
    before = path.read_bytes()
    # Walking speeds up at a constant rate over 0.6 s, so from then on the person is 1.25 * 0.3 m
    # behind a constant-speed walker: x(f) = -2.1 + 1.25 ((f - 5) / 24 - 0.3) first exceeds 3 at f = 111.
    r = subprocess.run([PY, "-m", "lfusd", "animate", "add-person", str(path), "--path", "-2.1,0", "10,0",
                        "--speed", "1.25", "--start", "5"], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "frame 111" in r.stderr and "/World/River" in r.stderr
    assert path.read_bytes() == before  # nothing written


def test_path_over_a_bridge_is_accepted(tmp_path):
    stage = river_stage(tmp_path / "bridge.usda", last=120, bridge=True)
    prim = add_person(stage, [(-1.0, 0.0), (8.0, 0.0)], gait="run", speed=3.0)
    root = _root_world(stage, prim.GetPath(), np.arange(1, 121))
    on_bridge = (root[:, 3, 0] > 3) & (root[:, 3, 0] < 6)
    assert on_bridge.any()
    assert np.allclose(root[on_bridge, 3, 2], 0.05, atol=1e-4)


def test_cli_adds_people(tmp_path):
    path = tmp_path / "s.usda"
    slope_stage(path, last=48)
    for y in (-2, 2):
        r = subprocess.run([PY, "-m", "lfusd", "animate", "add-person", str(path), "--path", f"-5,{y}", f"-1,{y}",
                            "--gait", "run", "--speed", "3", "--start", "3"], capture_output=True, text=True, cwd=ROOT)
        assert r.returncode == 0, r.stderr
    stage = Usd.Stage.Open(str(path))
    for i in range(2):
        prim = stage.GetPrimAtPath(f"/World/People/Person_{i:02d}")
        assert prim.IsA(UsdSkel.Root) and class_label(prim) == "person"
    # The rulebook checks the result at every frame: a third person on the first one's path collides.
    before = path.read_bytes()
    r = subprocess.run([PY, "-m", "lfusd", "animate", "add-person", str(path), "--path", "-5,-2", "-1,-2",
                        "--gait", "run", "--speed", "3", "--start", "3"], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 2 and r.stderr.count("\n") == 1
    assert "no_interpenetration" in r.stderr and "Person_02" in r.stderr and "frame 1" in r.stderr
    assert path.read_bytes() == before


def test_animated_stages_pass_the_rulebook(tmp_path):
    """People stay on allowed surfaces at every frame: `lfusd check` passes (running flight included)."""
    path = tmp_path / "bridge.usda"
    stage = river_stage(path, last=96, bridge=True)
    add_person(stage, [(-1.0, 0.0), (8.0, 0.0)], gait="run", speed=3.0, check=False)
    add_person(stage, [(-6.0, -4.0), (1.0, -4.0), (1.0, 4.0)], gait="walk", speed=1.3, start=10, check=False)
    stage.Save()
    r = subprocess.run([PY, "-m", "lfusd", "check", str(path)], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "all constraints hold" in r.stdout


def _mixamo_character(path):
    """lfusd's human re-authored as a user file: Y up, centimetres, Mixamo joint names, mesh 'Skin'."""
    names = {"pelvis": "Hips", "spine": "Spine", "chest": "Spine2", "neck": "Neck", "head": "Head",
             "l_shoulder": "LeftArm", "l_elbow": "LeftForeArm", "l_wrist": "LeftHand",
             "r_shoulder": "RightArm", "r_elbow": "RightForeArm", "r_wrist": "RightHand",
             "l_hip": "LeftUpLeg", "l_knee": "LeftLeg", "l_ankle": "LeftFoot", "l_toe": "LeftToeBase",
             "r_hip": "RightUpLeg", "r_knee": "RightLeg", "r_ankle": "RightFoot", "r_toe": "RightToeBase"}
    src = Usd.Stage.CreateInMemory()
    define_human(src, "/Char", HumanSpec(1.8, 0.3))
    to_yup_cm = lambda v: Gf.Vec3d(100 * v[0], 100 * v[2], -100 * v[1])  # Z up m -> Y up cm
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    root = UsdSkel.Root.Define(stage, "/Character")
    stage.SetDefaultPrim(root.GetPrim())
    s_skel = UsdSkel.Skeleton(src.GetPrimAtPath("/Char/Skeleton"))
    joints = ["/".join(names[p] for p in j.split("/")) for j in s_skel.GetJointsAttr().Get()]
    skel = UsdSkel.Skeleton.Define(stage, "/Character/Rig")
    skel.CreateJointsAttr(joints)
    for get, create in ((s_skel.GetBindTransformsAttr, skel.CreateBindTransformsAttr),
                        (s_skel.GetRestTransformsAttr, skel.CreateRestTransformsAttr)):
        create(Vt.Matrix4dArray([Gf.Matrix4d(1).SetTranslate(to_yup_cm(m.ExtractTranslation())) for m in get().Get()]))
    s_mesh = src.GetPrimAtPath("/Char/Body")
    mesh = UsdGeom.Mesh.Define(stage, "/Character/Skin")
    mesh.CreatePointsAttr([Gf.Vec3f(to_yup_cm(p)) for p in UsdGeom.Mesh(s_mesh).GetPointsAttr().Get()])
    for a in ("faceVertexCounts", "faceVertexIndices", "subdivisionScheme"):
        mesh.GetPrim().CreateAttribute(a, s_mesh.GetAttribute(a).GetTypeName()).Set(s_mesh.GetAttribute(a).Get())
    s_bind, bind = UsdSkel.BindingAPI(s_mesh), UsdSkel.BindingAPI.Apply(mesh.GetPrim())
    bind.CreateSkeletonRel().SetTargets([skel.GetPath()])
    bind.CreateJointIndicesPrimvar(False, 4).Set(s_bind.GetJointIndicesPrimvar().Get())
    bind.CreateJointWeightsPrimvar(False, 4).Set(s_bind.GetJointWeightsPrimvar().Get())
    bind.CreateGeomBindTransformAttr(Gf.Matrix4d(1))
    stage.Save()


def test_user_character_walks_upright_without_sliding(tmp_path):
    char = tmp_path / "hero.usda"
    _mixamo_character(char)
    stage = slope_stage(tmp_path / "hero_stage.usda", last=72)
    prim = add_person(stage, [(-6.0, 0.0), (2.0, 0.0)], gait="walk", speed=1.5, character=char)
    assert class_label(prim) == "person"
    frames = np.arange(1, 73)
    names, pos = joint_world(stage, f"{prim.GetPath()}/Rig", frames)
    for side in ("Left", "Right"):
        ankle = pos[:, names.index(f"{side}Foot")]
        steps = planted_steps(ankle, slope_z(ankle[:, :2]))
        assert len(steps) >= 2 and max(s for _, _, s in steps) < 0.03
    # Upright and life-size in the stage's metres: head well above the feet, soles on the ground.
    geo = StageGeometry(stage)
    skin = stage.GetPrimAtPath(f"{prim.GetPath()}/Skin")
    for f in (1, 30, 60):
        v = geo.mesh(skin, f).vertices
        ground = slope_z(v[np.argmin(v[:, 2]), :2])
        assert 1.6 < v[:, 2].max() - ground < 1.85
        assert -0.03 < v[:, 2].min() - ground < 0.03
    # Facing its direction of travel (+X): its left foot is on the +Y side.
    assert np.all(pos[:, names.index("LeftFoot"), 1] > pos[:, names.index("RightFoot"), 1])


def _rotated_frames_character(path, seed=0, mesh_name="Body"):
    """lfusd's human with every joint's bind frame turned by a random rotation (as exported rigs
    have): same bind-pose geometry, different joint orientations."""
    rng = np.random.default_rng(seed)
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)  # USD's fallback is centimetres
    root = define_human(stage, "/Character", HumanSpec())
    stage.SetDefaultPrim(root.GetPrim())
    skel = UsdSkel.Skeleton(stage.GetPrimAtPath("/Character/Skeleton"))
    joints = [str(j) for j in skel.GetJointsAttr().Get()]
    bind = []
    for m in skel.GetBindTransformsAttr().Get():
        q = rng.normal(size=4)
        rot = Gf.Matrix4d(1).SetRotate(Gf.Quatd(*(q / np.linalg.norm(q)).tolist()))
        bind.append(rot * m)  # row vectors: rotate the frame, keep the joint's position
    parent = {j: "/".join(j.split("/")[:-1]) for j in joints}
    index = {j: i for i, j in enumerate(joints)}
    rest = [bind[i] * bind[index[parent[j]]].GetInverse() if parent[j] else bind[i] for i, j in enumerate(joints)]
    skel.GetBindTransformsAttr().Set(Vt.Matrix4dArray(bind))
    skel.GetRestTransformsAttr().Set(Vt.Matrix4dArray(rest))
    if mesh_name != "Body":
        layer = stage.GetRootLayer()
        assert Sdf.CopySpec(layer, "/Character/Body", layer, f"/Character/{mesh_name}")
        stage.RemovePrim("/Character/Body")
        stage.RemovePrim("/Character/Hair")  # leaves one mesh named Hair on the probed stage: Person_00's
    stage.Save()


def test_character_with_rotated_joint_frames_moves_like_the_builtin_human(tmp_path):
    """Retargeting works on world-space deltas: joint orientations must not change the motion."""
    char = tmp_path / "turned.usda"
    _rotated_frames_character(char)
    stage = slope_stage(tmp_path / "two.usda", last=40)
    route = [(-6.0, -3.0), (-2.0, -3.0), (-2.0, 2.0)]
    mine = add_person(stage, route, gait="walk", speed=1.5, check=False)
    theirs = add_person(stage, route, gait="walk", speed=1.5, character=char, check=False)
    geo = StageGeometry(stage)
    for f in (1, 13, 27, 40):
        a = geo.mesh(stage.GetPrimAtPath(f"{mine.GetPath()}/Body"), f).vertices
        b = geo.mesh(stage.GetPrimAtPath(f"{theirs.GetPath()}/Body"), f).vertices
        assert np.abs(a - b).max() < 1e-4


@pytest.mark.blender
def test_blender_skinning_equals_pxr_skinning(tmp_path):
    """Acceptance: Blender's evaluated skinned vertices = UsdSkel ComputeSkinnedPoints within 1e-4 m."""
    char = tmp_path / "hero.usda"
    _mixamo_character(char)
    turned = tmp_path / "turned.usda"
    _rotated_frames_character(turned, mesh_name="Turned")
    path = tmp_path / "clip.usda"
    stage = slope_stage(path, last=30)
    add_person(stage, [(-3.0, -1.0), (1.0, -1.0), (1.0, 3.0)], gait="walk", speed=1.6, start=2, check=False)
    add_person(stage, [(-3.0, 2.0), (2.0, 2.0)], gait="run", speed=3.5, character=char, check=False)
    add_person(stage, [(-3.0, -5.0), (2.0, -5.0)], gait="walk", speed=1.2, character=turned, check=False)
    stage.Save()
    out = tmp_path / "blender.npz"
    r = subprocess.run([PY, str(ROOT / "tests" / "support" / "blender_skin_probe.py"), str(path), "Body,Hair,Skin,Turned", "1", "30",
                        str(out)], capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    for name in ("Body", "Hair", "Skin", "Turned"):
        assert f"{name} modifiers: ['ARMATURE']" in r.stdout
    blender = np.load(out)
    geo = StageGeometry(stage)
    for name, prim_path in (("Body", "/World/People/Person_00/Body"), ("Hair", "/World/People/Person_00/Hair"), ("Skin", "/World/People/Person_01/Skin"),
                            ("Turned", "/World/People/Person_02/Turned")):
        prim = stage.GetPrimAtPath(prim_path)
        ref = np.array([geo.mesh(prim, f).vertices for f in range(1, 31)])
        assert blender[name].shape == ref.shape
        assert np.abs(blender[name] - ref).max() < 1e-4
        # The clip really moves: vertices travel well beyond the tolerance.
        assert np.abs(ref[-1] - ref[0]).max() > 0.5


# --- bad input: one-line errors


def _cli(*args):
    return subprocess.run([PY, "-m", "lfusd", "animate", "add-person", *map(str, args)], capture_output=True,
                          text=True, cwd=ROOT)


@pytest.mark.parametrize("extra,needle", [
    (["--path", "1,2"], "at least two points"),
    (["--path", "1,2", "3,x"], "not X,Y"),
    (["--path", "-4,0", "0,0", "--speed", "0"], "not positive"),
    (["--path", "-4,0", "0,0", "--speed", "-1.5", "--gait", "run"], "not positive"),
    (["--path", "-4,0", "0,0", "--start", "500"], "outside the stage's range 1-48"),
    (["--path", "-4,0", "0,0", "--start", "0"], "outside the stage's range 1-48"),
    # x = 9 + 2.4 ((f - 1) / 24 - 0.3) > 10 (the slope's end) from f = 19 (0.6 s to reach speed)
    (["--path", "9,0", "14,0", "--speed", "2.4"], "leaves the supporting surfaces at frame 19"),
])
def test_bad_cli_input_is_a_one_line_error(tmp_path, extra, needle):
    path = tmp_path / "s.usda"
    slope_stage(path, last=48)
    r = _cli(path, *extra)
    assert r.returncode == 2
    assert r.stderr.startswith("lfusd: error:") and r.stderr.count("\n") == 1 and needle in r.stderr


def test_character_without_skeleton_is_refused(tmp_path):
    plain = Usd.Stage.CreateNew(str(tmp_path / "statue.usda"))
    _quad(plain, "/Statue", "person", 0, 1, 0, 1, 0)
    plain.Save()
    path = tmp_path / "s.usda"
    slope_stage(path, last=24)
    r = _cli(path, "--path", "-4,0", "0,0", "--character", tmp_path / "statue.usda")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "has no UsdSkel Skeleton" in r.stderr
    with pytest.raises(LfusdError, match="does not exist"):
        add_person(Usd.Stage.Open(str(path)), [(-4, 0), (0, 0)], character=tmp_path / "nope.usda")


def test_stage_in_centimetres_gets_a_person_of_metres(tmp_path):
    """USD's fallback unit is the centimetre: a 1.75 m person is 175 stage units tall there, and a
    path of metres (0,0 -> 1,0) moves it 100 units along the stage's X (tests/author/test_world_frame.py
    covers Y-up and other units against a metre stage)."""
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)  # metersPerUnit left unauthored: 0.01
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(48)
    _quad(stage, "/Ground", "ground", -500, 500, -500, 500, 0)
    person = add_person(stage, [(0, 0), (1, 0)], check=False)
    body = UsdGeom.Mesh(stage.GetPrimAtPath(f"{person.GetPath()}/Body"))
    first = StageGeometry(stage).mesh(body.GetPrim(), 1.0).vertices  # lfusd's world: metres
    assert 1.65 < first[:, 2].max() - first[:, 2].min() < 1.85
    pts = np.array(UsdGeom.Mesh(body).GetPointsAttr().Get())  # the stage's own view of the person, in its units:
    xf = np.array(UsdGeom.Xformable(person).ComputeLocalToWorldTransform(Usd.TimeCode(1)))
    assert 100 * (first[:, 2].max() - first[:, 2].min()) == pytest.approx((pts @ xf[:3, :3])[:, 2].ptp(), rel=0.05)
    start, end = (np.array(UsdGeom.Xformable(person).ComputeLocalToWorldTransform(Usd.TimeCode(t)))[3, :3] for t in (1, 48))
    assert end - start == pytest.approx([100.0, 0.0, 0.0], abs=0.5)


def test_parse_points_api():
    assert parse_points(["-3,2", "4.5, -1"]).tolist() == [[-3.0, 2.0], [4.5, -1.0]]
    with pytest.raises(LfusdError, match="at least two points"):
        parse_points(["1,1"])
    with pytest.raises(LfusdError, match="at least two points"):
        add_person(Usd.Stage.CreateInMemory(), [(0, 0)])


def test_add_person_to_file_refuses_a_taken_or_bad_name_before_writing(tmp_path):
    """The library function behind `lfusd animate add-person`: --name must be an absolute prim path
    and free (or --force); a refusal leaves the file as it was."""
    from lfusd.author.people import add_person_to_file

    path = tmp_path / "s.usda"
    slope_stage(path, last=8)
    before = path.read_bytes()
    with pytest.raises(LfusdError, match="--name 'Alice' is not an absolute prim path"):
        add_person_to_file(path, [(-5, 0), (-1, 0)], name="Alice")
    with pytest.raises(LfusdError, match="stage already has a prim at /World; choose another --name or pass --force"):
        add_person_to_file(path, [(-5, 0), (-1, 0)], name="/World")
    with pytest.raises(LfusdError, match="build"):
        add_person_to_file(path, [(-5, 0), (-1, 0)], build=7.0)
    assert path.read_bytes() == before


def _unlabelled_floor_stage(path, last=None):
    """A floor with no class label (as a downloaded set has), frames 1..last or no time range."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(24)
    if last is not None:
        stage.SetStartTimeCode(1)
        stage.SetEndTimeCode(last)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    m = UsdGeom.Mesh.Define(stage, "/World/Floor")
    m.CreatePointsAttr([(-10, -10, 0.25), (10, -10, 0.25), (10, 10, 0.25), (-10, 10, 0.25)])
    m.CreateFaceVertexCountsAttr([4])
    m.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    m.CreateSubdivisionSchemeAttr("none")
    UsdGeom.Mesh.Define(stage, "/World/Table").CreatePointsAttr([(0, 0, 0)])
    set_class_label(stage.GetPrimAtPath("/World/Table"), "table")
    stage.Save()


def test_ground_option_labels_the_floor_a_person_walks_on(tmp_path):
    """Issue 39.18: a set without ground labels had only a Python fix; --ground PRIM labels it."""
    path = tmp_path / "set.usda"
    _unlabelled_floor_stage(path, last=24)
    r = _cli(path, "--path", "-2,0", "2,0")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "--ground PRIM" in r.stderr
    for bad, needle in (("/World/Nothing", "not a prim"), ("/World/Table", "labelled 'table'")):
        r = _cli(path, "--path", "-2,0", "2,0", "--ground", bad)
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and needle in r.stderr, r.stderr
    r = _cli(path, "--path", "-2,0", "2,0", "--ground", "/World/Floor")
    assert r.returncode == 0, r.stderr
    stage = Usd.Stage.Open(str(path))
    assert class_label(stage.GetPrimAtPath("/World/Floor")) == "ground"
    root = _root_world(stage, "/World/People/Person_00", [1, 12, 24])
    np.testing.assert_allclose(root[:, 3, 2], 0.25, atol=1e-4)  # standing on the floor it was told about


def test_a_walk_on_a_stage_without_time_range_is_refused_or_given_frames(tmp_path):
    """Issue 39.18: a stage with no time range silently got a one-frame walk; now refused, and
    --frames N gives it frames 1..N."""
    path = tmp_path / "still.usda"
    _unlabelled_floor_stage(path)
    before = path.read_bytes()
    r = _cli(path, "--path", "-2,0", "2,0", "--ground", "/World/Floor")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "no time range" in r.stderr and "--frames N" in r.stderr
    assert path.read_bytes() == before
    assert _cli(path, "--path", "-2,0", "2,0", "--gait", "idle", "--ground", "/World/Floor", "-o", tmp_path / "idle.usda").returncode == 0
    r = _cli(path, "--path", "-2,0", "2,0", "--ground", "/World/Floor", "--frames", "36")
    assert r.returncode == 0, r.stderr
    stage = Usd.Stage.Open(str(path))
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (1, 36)
    root = _root_world(stage, "/World/People/Person_00", [1, 36])
    assert np.linalg.norm(root[1, 3, :2] - root[0, 3, :2]) > 1.0  # it walks
    r = _cli(path, "--path", "-2,3", "2,3", "--frames", "10")
    assert r.returncode == 2 and "already has frames 1-36" in r.stderr


def test_add_person_says_each_phase_on_a_terminal(tmp_path, monkeypatch, capsys):
    """Issue 39.19: add-person ran up to a minute without a word; on a terminal it names each phase."""
    from lfusd.cli import main

    path = tmp_path / "s.usda"
    slope_stage(path, last=24)
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    assert main(["animate", "add-person", str(path), "--path", "-5,0", "-2,0"]) == 0
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("lfusd: add-person: ")]
    assert [ln.split(": ", 2)[2].split(" ")[0] for ln in lines] == ["finding", "moving", "checking"], err
    assert all(ln.endswith(" s)") for ln in lines)
    # the rulebook's check (minutes on a large set) says which frame it is at
    import lfusd.author.people

    monkeypatch.setattr(lfusd.author.people, "PROGRESS_EVERY_S", 0.0)
    assert main(["animate", "add-person", str(path), "--path", "-5,3", "-2,3"]) == 0
    err = capsys.readouterr().err
    assert "checking the stage's rules: frame 24 of 1-24" in err, err


def test_a_t_posed_character_walks_with_its_arms_down(tmp_path, monkeypatch):
    """Issue 39.16: a T-posed character (arms straight out, as glTF's BrainStem; written here as a
    glTF converter writes one, Y-up under rotateX -90, anonymous joint names so only its shape
    tells the arms) walks with its arms at its sides: the hands swing near the body at every frame."""
    from support import characters

    for s, x in (("l", -1.0), ("r", 1.0)):  # arms horizontal at shoulder height: wrists 0.70 m out
        monkeypatch.setitem(characters._CANON, f"{s}_shoulder", (f"{s}_clavicle", (0.17 * x, 0.0, 1.40)))
        monkeypatch.setitem(characters._CANON, f"{s}_elbow", (f"{s}_shoulder", (0.45 * x, 0.0, 1.40)))
        monkeypatch.setitem(characters._CANON, f"{s}_wrist", (f"{s}_elbow", (0.70 * x, 0.0, 1.40)))
    char = tmp_path / "tposed.usda"
    characters.write_character(char, "cesium", up="Y", content=characters.scaled(100.0, 180.0), above=[("rotateX", -90.0), ("scale", 0.01)])
    stage = slope_stage(tmp_path / "stage.usda", last=48)
    prim = add_person(stage, [(-6.0, 0.0), (-1.0, 0.0)], gait="walk", speed=1.3, character=char)
    geo = StageGeometry(stage)
    body = [g for g in geo.gprims if g.GetPath().HasPrefix(prim.GetPath())]
    for f in (1, 12, 24, 36, 48):
        v = np.concatenate([geo.mesh(g, f).vertices for g in body])
        across = v[:, 1].max() - v[:, 1].min()  # walking along +X: its width is along Y
        assert across < 0.8, (f, across)  # T-posed it is 1.5 m across the hands; arms down, about 0.5 m
        assert v[:, 2].max() - v[:, 2].min() > 1.6  # still a standing person


def test_a_brainstem_shaped_character_walks_with_its_arms_down(tmp_path):
    """Issue 39.16: BrainStem walked with its arms straight out (2.41 m wide at every frame): its
    T-posed arms (a short upper arm, a long forearm with hand, the right forearm joint a leaf)
    were not recognised, so they kept their rest pose. Authored as its glTF -> USD conversion is
    (anonymous joints, the glTF's transforms above the skeleton), it walks with its hands at its
    sides: the skinned points' width across its path stays far under the T-pose span."""
    from support import characters

    char = tmp_path / "brainstem.usda"
    hands = characters.brainstem_like(char)
    span = float(np.linalg.norm(hands[0] - hands[1]))  # 2.03 m between the hands' joints, T-posed
    stage = slope_stage(tmp_path / "stage.usda", last=48)
    prim = add_person(stage, [(-6.0, 0.0), (-1.0, 0.0)], gait="walk", speed=1.3, character=char)
    geo = StageGeometry(stage)
    body = [g for g in geo.gprims if g.GetPath().HasPrefix(prim.GetPath())]
    for f in (1, 12, 24, 36, 48):
        v = np.concatenate([geo.mesh(g, f).vertices for g in body])
        across = v[:, 1].max() - v[:, 1].min()  # walking along +X: its width is along Y
        # arms down: the shoulders' 0.84 m plus the arms' boxes and A-pose hang, about 1.1 m
        assert across < 0.6 * span, (f, across, span)
        assert v[:, 2].max() - v[:, 2].min() > 1.6  # still a standing robot


def test_a_character_whose_arms_are_not_recognised_is_said_to_keep_them(tmp_path):
    """Issue 39.16: where the skeleton's shape gives no arm (here its upper arms are missing), the
    arms cannot be brought down for the gait: add-person says so instead of walking it silently."""
    from support import characters

    char = tmp_path / "armless.usda"
    characters.write_character(char, "cesium", up="Y", content=characters.scaled(100.0, 180.0),
                               above=[("rotateX", -90.0), ("scale", 0.01)], drop=("l_shoulder", "r_shoulder"))
    path = tmp_path / "s.usda"
    slope_stage(path, last=24)
    r = _cli(path, "--path", "-5,0", "-2,0", "--character", char)
    assert r.returncode == 0, r.stderr
    warn = [ln for ln in r.stderr.splitlines() if "arm recognised" in ln]
    assert len(warn) == 1 and "left or right arm" in warn[0] and warn[0].startswith("lfusd: warning:"), r.stderr
    full = tmp_path / "full.usda"
    characters.write_character(full, "cesium", up="Y", content=characters.scaled(100.0, 180.0), above=[("rotateX", -90.0), ("scale", 0.01)])
    r = _cli(path, "--path", "-5,3", "-2,3", "--character", full)
    assert r.returncode == 0 and "arm recognised" not in r.stderr, r.stderr


def test_a_character_with_a_broken_reference_is_one_warning_line_not_pxr_output(tmp_path):
    """Issue 39.19: pxr's raw multi-line warnings leaked from add-person (a character file whose
    prop references a missing file: four raw lines, from the character and from the placed person)."""
    from support import characters

    char = tmp_path / "c.usda"
    characters.write_character(char, "cesium", up="Y", content=characters.scaled(100.0, 180.0), above=[("rotateX", -90.0), ("scale", 0.01)])
    st = Usd.Stage.Open(str(char))
    st.DefinePrim("/Root/Prop").GetReferences().AddReference("./missing_prop.usda")
    st.Save()
    path = tmp_path / "s.usda"
    slope_stage(path, last=12)
    r = _cli(path, "--path", "-5,0", "-2,0", "--character", char, "-o", tmp_path / "o.usda")
    assert r.returncode == 0, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert all(ln.startswith("lfusd: ") for ln in lines), lines  # nothing of pxr's own output
    assert sum("missing_prop.usda" in ln for ln in lines) == 1, lines


def _refusal_stage(tmp_path, case, name=None):
    """A flat-ground stage of 24 frames where a person's path from (-6, 0) to (-1, 0) is refused:
    over water ('water'), out of the stage's lfusd:bounds ('bounds'), into a still 1 m box
    ('obstacle'), or under that box held 2 m up ('overhead': not refused)."""
    stage = river_stage(tmp_path / f"{name or case}.usda", last=24)
    if case == "bounds":  # the ground spans x -10..3, the bounds stop at x = -5.5
        stage.GetDefaultPrim().CreateAttribute("lfusd:bounds", Sdf.ValueTypeNames.Double3Array, custom=True).Set(
            Vt.Vec3dArray([Gf.Vec3d(-5.5, -10, -1), Gf.Vec3d(12, 10, 5)]))
    if case in ("obstacle", "overhead"):
        box = UsdGeom.Cube.Define(stage, "/World/Crate")
        box.CreateSizeAttr(1.0)
        box.AddTranslateOp().Set(Gf.Vec3d(-5.8, 0.0, 0.5 if case == "obstacle" else 2.5))
        set_class_label(box.GetPrim(), "crate")
    return stage


@pytest.mark.parametrize("case, says", [
    ("water", "crosses water (/World/River"),
    ("bounds", "leaves the stage bounds (lfusd:bounds of /World) at frame 1"),
    ("obstacle", "runs into /World/Crate (class crate) at frame 1"),
])
def test_an_impossible_placement_is_refused_before_the_gait(tmp_path, monkeypatch, case, says):
    """Issue 39.19: a refused placement took 3.5 minutes before its error (the gait, the skinning
    and the rulebook's check of the finished person ran first). What the root's path alone makes
    certain is refused before the gait is computed, and the rulebook agrees: without the early
    check the finished person is refused by the same rule."""
    import lfusd.author.gait as gait
    import lfusd.author.people as people

    path = [(4.0, 0.0), (5.0, 0.0)] if case == "water" else [(-6.0, 0.0), (-1.0, 0.0)]  # the river: x 3..6
    with monkeypatch.context() as m:
        m.setattr(gait, "bake", lambda *a, **k: pytest.fail("the gait was computed for a placement refused anyway"))
        with pytest.raises(LfusdError, match=re.escape(says)):
            add_person(_refusal_stage(tmp_path, case), path, speed=1.3)
    if case == "water":  # refused before the gait already; the rulebook's agreement is shown for the new checks
        return
    monkeypatch.setattr(people, "_refuse_path_early", lambda *a, **k: None)
    with pytest.raises(LfusdError, match="would break the stage's rules") as err:
        add_person(_refusal_stage(tmp_path, case, "unchecked"), path, speed=1.3)
    assert {"bounds": "in_bounds", "obstacle": "no_interpenetration"}[case] in str(err.value), err.value


def test_a_path_under_a_still_object_is_not_refused_early(tmp_path):
    """The early check refuses only what is certain: a path under a box held 2 m up is walked (and
    passes the rulebook's check of the finished person)."""
    stage = _refusal_stage(tmp_path, "overhead")
    prim = add_person(stage, [(-6.0, 0.0), (-1.0, 0.0)], speed=1.3)
    assert prim.IsValid() and class_label(prim) == "person"


def test_the_early_refusal_follows_check(tmp_path, monkeypatch):
    """Generated scenes place people with check=False (no rulebook): no early refusal either."""
    stage = _refusal_stage(tmp_path, "obstacle")
    prim = add_person(stage, [(-6.0, 0.0), (-1.0, 0.0)], speed=1.3, check=False)
    assert prim.IsValid()
