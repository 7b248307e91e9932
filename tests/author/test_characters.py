"""Characters from the wild: UsdSkel files as glTF/FBX converters and Mixamo/SMPL rigs write them,
placed with `lfusd animate add-person --character`, checked against their closed-form geometry.

The characters (tests/support/characters.py) are boxes rigidly skinned to an A-posed skeleton
1.70 m tall, authored in a converter's frame (Y-up with a -90 degree X rotation and a 0.01 scale
above the SkelRoot; Z-up centimetres turned and moved above the SkelRoot). Whatever the frame,
the placed character must stand upright on the ground at its authored size, face and follow its
path: all checked on pxr-skinned world vertices (lfusd.author.geometry.StageGeometry).
"""

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from lfusd.author.geometry import StageGeometry
from lfusd.author.labels import class_label, set_class_label
from lfusd.author.people import read_character
from lfusd.author.skeletons import ALIASES, normalise, recognise_roles
from support.characters import HEIGHT, KEYS, PARENTS, box_mesh, canon_position, gltf_mixamo, scaled, smpl_cm, write_character
from support.cli import assert_one_line_error
from support.skel_measure import joint_world, planted_steps

from lfusd.cli import main
from lfusd.errors import LfusdError

GROUND = 0.25  # the ground's height: a character whose origin is not on its soles would float or sink
LAST = 48
SPEED, ACCEL_S = 1.3, 0.6  # the default walk, reaching its speed in 0.6 s (lfusd.author.gait.journey)


def ground_stage(path):
    """Z-up metre stage, frames 1..LAST, a 20 m ground quad at z = GROUND, written without lfusd."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(24)
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(LAST)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    set_class_label(UsdGeom.Xform.Define(stage, "/World/Ground").GetPrim(), "ground")
    m = UsdGeom.Mesh.Define(stage, "/World/Ground/Mesh")
    m.CreatePointsAttr([(-10, -10, GROUND), (10, -10, GROUND), (10, 10, GROUND), (-10, 10, GROUND)])
    m.CreateFaceVertexCountsAttr([4])
    m.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    m.CreateSubdivisionSchemeAttr("none")
    stage.Save()
    return stage


def walked_distance(frames):
    """Closed-form distance along the path: constant acceleration to SPEED over ACCEL_S, then SPEED."""
    t = (np.asarray(frames, float) - 1) / 24.0
    a = SPEED / ACCEL_S
    return np.where(t < ACCEL_S, 0.5 * a * t**2, 0.5 * SPEED * ACCEL_S + SPEED * (t - ACCEL_S))


def place(tmp_path, writer, start, end):
    char = tmp_path / "character.usda"
    writer(char)
    path = tmp_path / "stage.usda"
    ground_stage(path)
    assert main(["animate", "add-person", str(path), "--path", f"{start[0]},{start[1]}", f"{end[0]},{end[1]}",
                 "--character", str(char)]) == 0
    return Usd.Stage.Open(str(path)), "/World/People/Person_00"


@pytest.mark.parametrize("writer,start,end", [
    (gltf_mixamo, (-2.0, 1.0), (2.0, 1.0)),  # Y-up, rotateX -90 and scale 0.01 above the SkelRoot, Mixamo names
    (smpl_cm, (0.5, -2.0), (0.5, 2.0)),  # Z-up centimetres, rotateZ and translate above the SkelRoot, SMPL names
], ids=["gltf-mixamo", "smpl-cm"])
def test_wild_character_stands_on_the_ground_at_its_size_and_walks_its_path(tmp_path, writer, start, end):
    stage, person = place(tmp_path, writer, start, end)
    assert class_label(stage.GetPrimAtPath(person)) == "person"
    frames = np.arange(1, LAST + 1)
    geo = StageGeometry(stage)
    verts = np.array([geo.mesh(stage.GetPrimAtPath(f"{person}/Character/Body"), float(f)).vertices for f in frames])
    _, _, _, keys = box_mesh()
    keys = np.array(keys)
    names, joints = joint_world(stage, f"{person}/Character/Skeleton", frames)
    joint = {k: joints[:, i] for i, k in enumerate(KEYS)}  # the writer authors joints in KEYS order
    assert len(names) == len(KEYS)

    # Walks its path: the pelvis is at the closed-form distance along it, swaying a little sideways.
    direction = (np.array(end) - start) / np.linalg.norm(np.subtract(end, start))
    rel = joint["pelvis"][:, :2] - start
    along, across = rel @ direction, rel @ [-direction[1], direction[0]]
    assert np.abs(along - walked_distance(frames)).max() < 0.005
    assert np.abs(across).max() < 0.03 and along[-1] > 1.5

    # Its authored size in metres: every bone (parent to child joint) keeps its canonical length,
    # and the rigid head box its 0.18 x 0.20 x 0.20 m, at every frame.
    for key in KEYS[1:]:
        parent = PARENTS[key]
        length = np.linalg.norm(joint[key] - joint[parent], axis=1)
        assert np.abs(length - np.linalg.norm(canon_position(key) - canon_position(parent))).max() < 1e-4, key
    head = verts[:, keys == "head"]  # corners (x, y, z) in lo/hi order: z varies fastest
    up, side, front = head[:, 1] - head[:, 0], head[:, 4] - head[:, 0], head[:, 2] - head[:, 0]
    for edge, size in ((up, 0.20), (side, 0.18), (front, 0.20)):
        assert np.abs(np.linalg.norm(edge, axis=1) - size).max() < 1e-4

    # Upright: the head box's up edge points up (within the gait's lean), its top about HEIGHT above
    # the ground (less the gait's bob and crouch), the head above the pelvis.
    assert np.all(up[:, 2] / np.linalg.norm(up, axis=1) > np.cos(np.radians(15)))
    head_top = head[..., 2].max(axis=1)
    assert np.all((head_top - GROUND > HEIGHT - 0.10) & (head_top - GROUND < HEIGHT + 0.01))
    assert np.linalg.norm(head.mean(axis=1)[:, :2] - joint["pelvis"][:, :2], axis=1).max() < 0.15

    # Facing its way: its left foot is on the left of the direction of travel.
    lateral = (joint["l_ankle"] - joint["r_ankle"])[:, :2] @ [-direction[1], direction[0]]
    assert np.all(lateral > 0.1)

    # Feet planted: while an ankle is at its lowest (stance, foot flat), that foot's sole is on the ground.
    for side in "lr":
        steps = planted_steps(joint[f"{side}_ankle"], np.full(len(frames), GROUND))
        assert len(steps) >= 2 and max(s for _, _, s in steps) < 0.03  # the ankle moves in the heel-toe roll
        foot = (keys == f"{side}_ankle") | (keys == f"{side}_toe")
        for i, j, _ in steps:
            sole = verts[i : j + 1][:, foot, 2].min(axis=1)
            assert np.abs(sole - GROUND).max() < 0.003, (side, i, j, sole - GROUND)


def test_transforms_above_the_skel_root_set_size_and_posture(tmp_path):
    """The same content with part of the Xform above its SkelRoot: without the -90 degree rotation it
    lies on its back, without the 0.01 scale it is 170 m tall; both are refused."""
    lying = tmp_path / "lying.usda"
    write_character(lying, "mixamo", up="Y", content=scaled(100.0, 180.0), above=[("scale", 0.01)])
    with pytest.raises(LfusdError, match="is not standing: its legs lie 90 degrees off vertical"):
        read_character(lying)
    giant = tmp_path / "giant.usda"
    write_character(giant, "mixamo", up="Y", content=scaled(100.0, 180.0), above=[("rotateX", -90.0)])
    with pytest.raises(LfusdError, match="is 170 m tall"):
        read_character(giant)


@pytest.mark.parametrize("kwargs,needles", [
    # one leg, anonymous joints: no biped, whatever its names
    ({"style": "cesium", "drop": ("r_hip",)}, ("is not a biped", "1 joint chains reach the ground", "two-legged")),
    # every joint at the origin: height 0 (the NaN crash)
    ({"bind_scale": 0.0}, ("has height 0",)),
    # no rotation above the SkelRoot of a Z-up-content, Y-up file: lying down
    ({"above": [("scale", 0.01)]}, ("is not standing",)),
    # centimetre content in a metre file with no scale: 170 m
    ({"above": [("rotateX", -90.0)]}, ("170 m tall", "metersPerUnit")),
    ({"bind_mesh": False}, ("no mesh bound to its skeleton",)),
    ({"blend_shape": True}, ("blend shapes",)),
], ids=["one-leg", "zero-height", "lying", "units", "no-mesh", "blend-shapes"])
def test_unusable_characters_are_one_line_errors(tmp_path, capfd, kwargs, needles):
    char = tmp_path / "character.usda"
    args = {"style": "mixamo", "up": "Y", "content": scaled(100.0, 180.0), "above": [("rotateX", -90.0), ("scale", 0.01)]}
    write_character(char, **{**args, **kwargs})
    path = tmp_path / "stage.usda"
    ground_stage(path)
    before = path.read_bytes()
    code = main(["animate", "add-person", str(path), "--path", "-2,0", "2,0", "--character", str(char)])
    err = capfd.readouterr().err  # file descriptor level: USD's own warnings would show here too
    assert code == 2
    assert_one_line_error(code, err, str(char), *needles)
    assert path.read_bytes() == before


def test_files_that_are_no_character_are_one_line_errors(tmp_path, capfd):
    path = tmp_path / "stage.usda"
    ground_stage(path)
    statue = Usd.Stage.CreateNew(str(tmp_path / "statue.usda"))
    UsdGeom.Mesh.Define(statue, "/Statue").CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    statue.Save()
    (tmp_path / "broken.usda").write_text("#usda 1.0\n( this is not usd\n")
    colon = tmp_path / "colon.usda"
    write_character(colon, "mixamo", up="Y", content=scaled(100.0, 180.0), above=[("rotateX", -90.0), ("scale", 0.01)])
    colon.write_text(colon.read_text().replace("mixamorig_", "mixamorig:"))
    for name, needle in (("statue.usda", "has no UsdSkel Skeleton"), ("broken.usda", "not a readable USD file"),
                         ("missing.usda", "does not exist"), ("colon.usda", "not a valid UsdSkel joint path")):
        code = main(["animate", "add-person", str(path), "--path", "-2,0", "2,0", "--character", str(tmp_path / name)])
        assert_one_line_error(code, capfd.readouterr().err, needle)


def test_alias_table_matches_common_rigs():
    def roles(joints, *wanted):
        r = recognise_roles(joints)
        return [joints[r[w]].split("/")[-1] if w in r else None for w in wanted]

    legs = ("pelvis", "l_hip", "l_knee", "l_ankle", "l_toe", "r_hip", "l_shoulder", "l_wrist", "spine", "chest")
    mixamo = ["Hips", "Hips/Spine", "Hips/Spine/Spine1", "Hips/Spine/Spine1/Spine2", "Hips/Spine/Spine1/Spine2/LeftShoulder",
              "Hips/Spine/Spine1/Spine2/LeftShoulder/LeftArm", "Hips/Spine/Spine1/Spine2/LeftShoulder/LeftArm/LeftForeArm",
              "Hips/Spine/Spine1/Spine2/LeftShoulder/LeftArm/LeftForeArm/LeftHand",
              "Hips/LeftUpLeg", "Hips/LeftUpLeg/LeftLeg", "Hips/LeftUpLeg/LeftLeg/LeftFoot",
              "Hips/LeftUpLeg/LeftLeg/LeftFoot/LeftToeBase", "Hips/RightUpLeg"]
    expect = ["Hips", "LeftUpLeg", "LeftLeg", "LeftFoot", "LeftToeBase", "RightUpLeg", "LeftArm", "LeftHand", "Spine", "Spine2"]
    assert roles(mixamo, *legs) == expect
    for prefix in ("mixamorig:", "mixamorig_", "mixamorig1:", "Armature_mixamorig_"):
        named = ["/".join(prefix + p for p in j.split("/")) for j in mixamo]
        assert roles(named, *legs) == [prefix + e for e in expect], prefix
    # SMPL: 'left_foot' is the toe (its ankle is 'left_ankle'), 'left_collar' the clavicle.
    smpl = ["pelvis", "pelvis/left_hip", "pelvis/left_hip/left_knee", "pelvis/left_hip/left_knee/left_ankle",
            "pelvis/left_hip/left_knee/left_ankle/left_foot", "pelvis/right_hip", "pelvis/spine1", "pelvis/spine1/spine2",
            "pelvis/spine1/spine2/spine3", "pelvis/spine1/spine2/spine3/left_collar",
            "pelvis/spine1/spine2/spine3/left_collar/left_shoulder", "pelvis/spine1/spine2/spine3/left_collar/left_shoulder/left_elbow",
            "pelvis/spine1/spine2/spine3/left_collar/left_shoulder/left_elbow/left_wrist",
            "pelvis/spine1/spine2/spine3/left_collar/left_shoulder/left_elbow/left_wrist/left_hand"]
    assert roles(smpl, *legs) == ["pelvis", "left_hip", "left_knee", "left_ankle", "left_foot", "right_hip", "left_shoulder",
                                  "left_wrist", "spine1", "spine2"]
    unreal = ["root", "root/pelvis", "root/pelvis/thigh_l", "root/pelvis/thigh_l/calf_l", "root/pelvis/thigh_l/calf_l/foot_l",
              "root/pelvis/thigh_l/calf_l/foot_l/ball_l", "root/pelvis/thigh_r", "root/pelvis/spine_01",
              "root/pelvis/spine_01/spine_02", "root/pelvis/spine_01/spine_02/clavicle_l",
              "root/pelvis/spine_01/spine_02/clavicle_l/upperarm_l", "root/pelvis/spine_01/spine_02/clavicle_l/upperarm_l/lowerarm_l",
              "root/pelvis/spine_01/spine_02/clavicle_l/upperarm_l/lowerarm_l/hand_l"]
    assert roles(unreal, *legs) == ["pelvis", "thigh_l", "calf_l", "foot_l", "ball_l", "thigh_r", "upperarm_l", "hand_l",
                                    "spine_01", "spine_02"]
    # Blender (rigify deform bones, '.L' sides) and 3ds Max Biped ('Bip01 L Thigh').
    assert normalise("DEF-thigh.L") == ("l", "thigh") and normalise("DEF-upper_arm.R") == ("r", "upperarm")
    assert normalise("Bip01 L Thigh") == ("l", "thigh") and normalise("Bip01 Pelvis") == ("", "pelvis")
    assert normalise("L_Hip") == ("l", "hip") and normalise("lHip") == ("l", "hip") and normalise("leftupleg") == ("l", "upleg")
    assert normalise("Hips/Spine/mixamorig:LeftForeArm") == ("l", "forearm")
    # Names that are no role stay unmatched (CesiumMan's numbered joints, fingers, twist bones).
    assert recognise_roles(["Skeleton_torso_joint_1", "leg_joint_L_1", "LeftHandIndex1", "LeftUpLegTwist"]) == {}
    assert set(ALIASES) == {"pelvis", "spine", "chest", "neck", "head", "shoulder", "elbow", "wrist", "hip", "knee", "ankle", "toe"}


def test_anonymous_joints_unreal_root_and_geom_bind_walk_with_soles_on_the_ground(tmp_path):
    """Names carry nothing here (joint_0, joint_1, ...), an Unreal-style root joint sits on the ground
    under the pelvis, and the mesh is authored in another space (geomBindTransform: turned, scaled
    by 100 and moved, as Blender's exporter writes it): recognised by its shape, the character walks
    with its soles on the ground (within 1 cm at every frame, sliding under 1 cm per step) at its size."""
    from support.skel_measure import sole_heights, sole_slides

    a = np.radians(30.0)
    geom_bind = np.eye(4)
    geom_bind[:3, :3] = 100.0 * np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    geom_bind[:3, 3] = (5.0, -3.0, 2.0)

    def writer(path):
        write_character(path, "cesium", up="Y", content=scaled(100.0, 180.0), above=[("rotateX", -90.0), ("scale", 0.01)],
                        root_joint=True, geom_bind=geom_bind, seed=5)

    stage, person = place(tmp_path, writer, (-2.0, 1.0), (2.0, 1.0))
    geo = StageGeometry(stage)
    verts = np.array([geo.mesh(stage.GetPrimAtPath(f"{person}/Character/Body"), float(f)).vertices for f in range(1, LAST + 1)])
    keys = np.array(box_mesh()[3])
    feet = [(keys == f"{s}_ankle") | (keys == f"{s}_toe") for s in "lr"]
    ground = lambda xy: np.full(len(xy), GROUND)  # noqa: E731
    h = sole_heights(verts, feet, ground)
    assert h.min() > -0.01 and np.all(h.min(axis=1) < 0.01)
    assert sole_slides(verts, feet, ground).max() < 0.01
    top = verts[..., 2].max(axis=1) - GROUND
    assert np.all((top > HEIGHT - 0.1) & (top < HEIGHT + 0.01))
    along = verts.mean(axis=1)[:, 0]
    assert along[-1] - along[0] > 1.5


def test_placed_character_is_one_person_object_with_its_materials_and_nothing_else(tmp_path):
    """A character file that labels itself (its SkelRoot 'pedestrian'), keeps its material beside its
    SkelRoot and holds a camera and a light: the placed person is one object labelled person (the
    file's label blanked in the stage's layer, the file untouched), bound to its own material, and
    the camera and light stay out."""
    from pxr import UsdShade

    from lfusd.author.labels import object_table

    char = tmp_path / "character.usda"
    write_character(char, "numbered", up="Y", meters_per_unit=0.01, content=scaled(100.0, 180.0), above=[("rotateX", -90.0)],
                    textured=True)
    cstage = Usd.Stage.Open(str(char))
    set_class_label(cstage.GetPrimAtPath("/Root/Character"), "pedestrian")
    cstage.Save()
    before = char.read_bytes()
    path = tmp_path / "stage.usda"
    ground_stage(path)
    assert main(["animate", "add-person", str(path), "--path", "-2,1", "2,1", "--character", str(char)]) == 0
    assert char.read_bytes() == before
    stage = Usd.Stage.Open(str(path))
    objects, _ = object_table(stage)
    people = [o for o in objects if o.label != "ground"]
    assert [(o.prim_path, o.label) for o in people] == [("/World/People/Person_00", "person")]
    mat, _ = UsdShade.MaterialBindingAPI(stage.GetPrimAtPath("/World/People/Person_00/Character/Body")).ComputeBoundMaterial()
    assert mat.GetPath() == "/World/People/Person_00/Materials/Skin"
    for name in ("Camera", "Light"):
        assert not stage.GetPrimAtPath(f"/World/People/Person_00/{name}").IsActive()


def _skeleton(spec):
    """(joint paths, parent indices, positions) of {name: (parent, (x, y, z))} given parents first;
    names are replaced by numbers (joint_0, ...) so that only the shape can tell the roles."""
    names = list(spec)
    parents = np.array([names.index(p) if p else -1 for p, _ in spec.values()])
    paths = []
    for i in range(len(names)):
        paths.append(f"{paths[parents[i]]}/joint_{i}" if parents[i] >= 0 else f"joint_{i}")
    return names, paths, parents, np.array([xyz for _, xyz in spec.values()], float)


def _rechain(paths, parents):
    """Joint paths rebuilt from their leaf names (after renaming some leaves)."""
    leaves = [p.split("/")[-1] for p in paths]
    out = []
    for i, leaf in enumerate(leaves):
        out.append(f"{out[parents[i]]}/{leaf}" if parents[i] >= 0 else leaf)
    return out


def _legs(spec, side, x, hip_parent, split=False, hip_offset=False, heel=False):
    """A leg (facing +y, left at -x) under ``hip_parent``: optional hip offset joint (CMU's
    LHipJoint), thigh and shin split in two bones each (rigify's deform chains), a heel joint."""
    top = hip_parent
    if hip_offset:
        spec[f"{side}_offset"] = (top, (x * 0.2, 0.0, 0.95))
        top = f"{side}_offset"
    spec[f"{side}_hip"] = (top, (x, 0.0, 0.9))
    knee_parent = f"{side}_hip"
    if split:
        spec[f"{side}_thigh2"] = (f"{side}_hip", (x, 0.0, 0.7))
        knee_parent = f"{side}_thigh2"
    spec[f"{side}_knee"] = (knee_parent, (x, 0.0, 0.5))
    ankle_parent = f"{side}_knee"
    if split:
        spec[f"{side}_shin2"] = (f"{side}_knee", (x, 0.0, 0.3))
        ankle_parent = f"{side}_shin2"
    spec[f"{side}_ankle"] = (ankle_parent, (x, 0.0, 0.09))
    spec[f"{side}_toe"] = (f"{side}_ankle", (x, 0.13, 0.02))
    spec[f"{side}_toe_end"] = (f"{side}_toe", (x, 0.2, 0.0))
    if heel:
        spec[f"{side}_heel"] = (f"{side}_ankle", (x, -0.05, 0.0))


@pytest.mark.parametrize("layout", ["cmu", "rigify", "hips-pelvis", "unreal-root"])
def test_biped_shapes_are_recognised_without_names(layout):
    """Rig layouts seen in the wild, with numbered names: CMU mocap (hip offset joints, heel joints
    lower than the toes), rigify deform chains (thigh and shin split in two), legs under a 'Pelvis'
    child of 'Hips' beside the spine, and an Unreal root on the ground: each leg's hip, knee, ankle
    and toe, the pelvis and the sides are found from the shape alone."""
    from lfusd.author.skeletons import recognise_biped

    spec = {}
    if layout == "unreal-root":
        spec["root"] = (None, (0.0, 0.0, 0.0))
    spec["hips"] = ("root" if layout == "unreal-root" else None, (0.0, 0.0, 0.95))
    leg_parent = "hips"
    if layout == "hips-pelvis":
        spec["pelvis2"] = ("hips", (0.0, 0.0, 0.93))
        leg_parent = "pelvis2"
    for side, x in (("l", -0.1), ("r", 0.1)):
        _legs(spec, side, x, leg_parent, split=layout == "rigify", hip_offset=layout == "cmu", heel=layout == "cmu")
    spec["spine"] = ("hips", (0.0, 0.0, 1.1))
    spec["chest"] = ("spine", (0.0, 0.0, 1.3))
    for side, x in (("l", -1.0), ("r", 1.0)):
        spec[f"{side}_clav"] = ("chest", (0.05 * x, 0.0, 1.4))
        spec[f"{side}_shoulder"] = (f"{side}_clav", (0.17 * x, 0.0, 1.4))
        elbow_parent = f"{side}_shoulder"
        if layout == "rigify":  # the upper arm and forearm split in two as well
            spec[f"{side}_upper2"] = (f"{side}_shoulder", (0.18 * x, 0.0, 1.26))
            elbow_parent = f"{side}_upper2"
        spec[f"{side}_elbow"] = (elbow_parent, (0.19 * x, 0.0, 1.12))
        wrist_parent = f"{side}_elbow"
        if layout == "rigify":
            spec[f"{side}_fore2"] = (f"{side}_elbow", (0.195 * x, 0.0, 1.0))
            wrist_parent = f"{side}_fore2"
        spec[f"{side}_wrist"] = (wrist_parent, (0.2 * x, 0.0, 0.88))
        spec[f"{side}_finger"] = (f"{side}_wrist", (0.205 * x, 0.0, 0.78))
    spec["neck"] = ("chest", (0.0, 0.0, 1.45))
    spec["head"] = ("neck", (0.0, 0.0, 1.55))
    spec["head_end"] = ("head", (0.0, 0.0, 1.72))
    names, paths, parents, pos = _skeleton(spec)
    if layout == "rigify":  # rigify's deform names ('.' written '_' by converters) tell the split arms apart: a hint
        rigify = {"shoulder": "DEF_upper_arm_{S}", "upper2": "DEF_upper_arm_{S}_001", "elbow": "DEF_forearm_{S}",
                  "fore2": "DEF_forearm_{S}_001", "wrist": "DEF_hand_{S}"}
        leaves = [p.split("/")[-1] for p in paths]
        for i, n in enumerate(names):
            side, _, part = n.partition("_")
            if part in rigify:
                leaves[i] = rigify[part].format(S=side.upper())
        paths = _rechain(leaves, parents)
    turn = np.radians(70.0)  # any facing: the shape, not the axes, tells front and left
    rot = np.array([[np.cos(turn), -np.sin(turn), 0], [np.sin(turn), np.cos(turn), 0], [0, 0, 1]])
    roles = recognise_biped(paths, parents, pos @ rot.T * 100.0)  # and any units
    got = {role: names[i] for role, i in roles.items()}
    want = {"pelvis": "hips", "chest": "chest", "neck": "neck", "head": "head"}
    for side in "lr":
        want.update({f"{side}_{j}": f"{side}_{j}" for j in ("hip", "knee", "ankle", "toe", "shoulder", "elbow", "wrist")})
    assert {r: got.get(r) for r in want} == want


def test_brainstem_arms_are_recognised_from_its_shape():
    """Issue 39.16: glTF's BrainStem (anonymous joints) has a 0.19 m upper arm and a 0.41 m forearm
    with hand, its right forearm joint a leaf (no hand joint): its arms are not two long bones of
    similar length, yet each is a shoulder and an elbow (and the left a hand's joint) off the chest."""
    from lfusd.author.skeletons import recognise_biped
    from support.characters import brainstem_joints

    joints, world = brainstem_joints()
    nodes = [int(j.split("_")[-1]) for j in joints]
    parents = [nodes.index(int(j.split("/")[-2].split("_")[-1])) if "/" in j else -1 for j in joints]
    yup_to_zup = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # the skeleton is Y-up, facing +Z
    pos = np.array([world[n][:3, 3] for n in nodes]) @ yup_to_zup.T
    roles = recognise_biped(joints, np.array(parents), pos)
    got = {role: nodes[i] for role, i in roles.items()}
    want = {"pelvis": 3, "chest": 12, "head": 20, "l_hip": 4, "l_knee": 5, "l_ankle": 6, "l_toe": 7, "r_hip": 8,
            "r_knee": 9, "r_ankle": 10, "r_toe": 11, "l_shoulder": 13, "l_elbow": 14, "r_shoulder": 18, "r_elbow": 19}
    assert {r: got.get(r) for r in want} == want
    assert got.get("l_wrist") in (15, 16, 17) and "r_wrist" not in got  # the left hand ends in finger joints


def test_a_t_posed_arm_without_hand_joints_starts_at_the_shoulder_not_the_clavicle():
    """Issue 39.16: an arm of fewer than two long bones (T-posed clavicle, upper arm, and a forearm
    joint with no hand below it) is its own joints from the first one out at the side of the
    torso: the clavicle (0.05 m from the spine) is no shoulder, or the gait would turn it down."""
    from lfusd.author.skeletons import recognise_biped

    spec = {"hips": (None, (0.0, 0.0, 0.95))}
    for side, x in (("l", -0.1), ("r", 0.1)):
        _legs(spec, side, x, "hips")
    spec["spine"] = ("hips", (0.0, 0.0, 1.1))
    spec["chest"] = ("spine", (0.0, 0.0, 1.3))
    for side, x in (("l", -1.0), ("r", 1.0)):
        spec[f"{side}_clav"] = ("chest", (0.05 * x, 0.0, 1.4))
        spec[f"{side}_shoulder"] = (f"{side}_clav", (0.17 * x, 0.0, 1.4))
        spec[f"{side}_elbow"] = (f"{side}_shoulder", (0.45 * x, 0.0, 1.4))  # a leaf: no forearm end, no hand
    spec["neck"] = ("chest", (0.0, 0.0, 1.45))
    spec["head"] = ("neck", (0.0, 0.0, 1.55))
    names, paths, parents, pos = _skeleton(spec)
    got = {role: names[i] for role, i in recognise_biped(paths, parents, pos).items()}
    for side in "lr":
        assert (got.get(f"{side}_shoulder"), got.get(f"{side}_elbow")) == (f"{side}_shoulder", f"{side}_elbow")
        assert f"{side}_wrist" not in got
