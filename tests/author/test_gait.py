"""Gait cycles: feet planted without sliding, seamless loops, speed-dependent strides, bad input.

Joint positions are measured with pxr's UsdSkel (SkeletonQuery) on the written USD, not taken
from the code that computed them.
"""

from pathlib import Path

import numpy as np
import pytest
from pxr import Usd, UsdSkel

from lfusd.author import gait as G
from lfusd.errors import LfusdError
from lfusd.author.human import HumanSpec, define_human
from lfusd.author.stage import new_stage
from support.skel_measure import joint_world, planted_steps

ANIMATIONS = Path(__file__).resolve().parents[2] / "animations"


def _straight(gait, speed, seconds=5.0, spec=HumanSpec()):
    """A stage with the human moving along +Y on flat ground for ``seconds``."""
    frames = np.arange(1, int(seconds * 24) + 2)
    stage = new_stage(None, 1, int(frames[-1]))
    root = define_human(stage, "/World/Person", spec)
    params = G.gait_params(gait, speed, spec.height)
    rig = G.human_rig(spec)
    motion = G.bake(rig, params, G.straight_trajectory(frames, speed))
    G.write_motion(stage, "/World/Person/Skeleton", rig, motion, root.GetPrim())
    names, pos = joint_world(stage, "/World/Person/Skeleton", frames)
    return stage, params, names, pos


@pytest.mark.parametrize("gait,speed", [("walk", 0.8), ("walk", 1.4), ("walk", 2.2), ("run", 3.0), ("run", 5.0)])
def test_planted_feet_slide_less_than_3cm_per_step(gait, speed):
    _, params, names, pos = _straight(gait, speed)
    for side in "lr":
        ankle = pos[:, names.index(f"{side}_ankle")]
        steps = planted_steps(ankle, np.zeros(len(ankle)))
        full = [s for s in steps if 0 < s[0] and s[1] < len(ankle) - 1]  # stances wholly inside the clip
        assert len(full) >= 2
        assert max(s[2] for s in steps) < 0.03
        # Consecutive plants of one foot are one stride apart (= speed x cycle time).
        starts = np.array([ankle[s[0], 1] for s in full])
        assert np.allclose(np.diff(starts), params.stride, atol=0.02)


def test_walk_has_double_support_and_run_has_flight():
    for gait, speed, expect_both, expect_none in (("walk", 1.3, True, False), ("run", 4.0, False, True)):
        _, _, names, pos = _straight(gait, speed)
        down = []
        for side in "lr":
            # In contact: the ankle is down (heel strike, flat foot) or the ball of the foot is (push-off).
            z = pos[:, names.index(f"{side}_ankle"), 2]
            ball = pos[:, names.index(f"{side}_toe"), 2]
            down.append((z < z.min() + 0.015) | (ball < ball.min() + 0.003))
        both, none = np.logical_and(*down), ~np.logical_or(*down)
        assert both.any() == expect_both and none.any() == expect_none


def test_stride_and_cadence_grow_with_speed_in_human_ranges():
    walk = [G.gait_params("walk", v) for v in (0.6, 1.0, 1.3, 1.8, 2.4)]
    run = [G.gait_params("run", v) for v in (2.5, 3.5, 5.0, 7.0)]
    for seq in (walk, run):
        assert all(a.stride < b.stride for a, b in zip(seq, seq[1:]))
        cad = [2 * p.speed / p.stride for p in seq]
        assert all(a < b for a, b in zip(cad, cad[1:]))
    # Measured human cadence: about 1.7-1.9 steps/s walking at 1.3 m/s, 2.6-3.4 running at 3.5 m/s.
    assert 1.6 < 2 * 1.3 / G.gait_params("walk", 1.3).stride < 2.0
    assert 2.6 < 2 * 3.5 / G.gait_params("run", 3.5).stride < 3.4
    # A taller person takes longer strides at the same speed.
    assert G.gait_params("walk", 1.3, 1.95).stride > G.gait_params("walk", 1.3, 1.55).stride


def test_pelvis_bobs_and_head_stays_up():
    _, _, names, pos = _straight("walk", 1.3)
    pel = pos[:, names.index("pelvis"), 2]
    rest = 0.555 * 1.75
    assert 0.85 * rest < pel.min() < pel.max() <= rest + 1e-6
    assert pel.max() - pel.min() > 0.01  # the body rises and falls over each step
    assert np.all(pos[:, names.index("head"), 2] > 0.82 * 1.75)  # rest: 0.895 of the stature


def _anim_locals(stage, frame):
    anim = next(UsdSkel.Animation(p) for p in stage.Traverse() if p.IsA(UsdSkel.Animation))
    return np.array([np.array(m) for m in anim.GetTransforms(Usd.TimeCode(frame))])


@pytest.mark.parametrize("name", ["human_idle.usda", "human_walk.usda", "human_run.usda"])
def test_committed_cycles_loop_seamlessly(name):
    path = ANIMATIONS / name
    assert path.stat().st_size < 1_000_000
    stage = Usd.Stage.Open(str(path))
    first, last = int(stage.GetStartTimeCode()), int(stage.GetEndTimeCode())
    data = stage.GetRootLayer().customLayerData
    assert last - first == data["lfusd:cycleFrames"]
    # The skeleton's pose at the cycle's end equals its start ...
    assert np.abs(_anim_locals(stage, last) - _anim_locals(stage, first)).max() < 1e-5
    # ... and, with the root's motion removed, so do the joints' positions; the root advanced one stride.
    names, pos = joint_world(stage, "/World/Person/Skeleton", [first, last])
    shift = pos[1] - pos[0]
    assert np.abs(shift - shift[0]).max() < 1e-5
    stride = data["lfusd:stride"]
    assert np.allclose(shift[0], [0.0, stride, 0.0], atol=1e-5)
    assert abs(stride - data["lfusd:speed"] * data["lfusd:cycleFrames"] / 24.0) < 1e-9
    # Not a frozen pose: the joints do move within the cycle.
    _, mid = joint_world(stage, "/World/Person/Skeleton", [first + (last - first) // 4])
    rel_mid = mid[0] - mid[0][0]
    rel_first = pos[0] - pos[0][0]
    assert np.abs(rel_mid - rel_first).max() > 0.005


def test_regenerated_cycle_matches_the_committed_one(tmp_path):
    """The committed clip is what lfusd writes today (regenerate with `lfusd animate write-cycles`)."""
    stage = G.write_cycle(tmp_path / "walk.usda", "walk", 1.3)
    committed = Usd.Stage.Open(str(ANIMATIONS / "human_walk.usda"))
    for f in (1, 10, 20):
        assert np.abs(_anim_locals(stage, f) - _anim_locals(committed, f)).max() < 1e-5


@pytest.mark.parametrize("gait,speed", [("walk", 0.0), ("run", -1.0), ("walk", 7.0), ("crawl", 1.0)])
def test_bad_gait_input_is_a_one_line_error(gait, speed):
    with pytest.raises(LfusdError) as e:
        G.gait_params(gait, speed)
    assert "\n" not in str(e.value)


def test_character_rig_needs_leg_joints():
    with pytest.raises(LfusdError, match="l_hip"):
        G.CharacterRig(["root", "root/spine"], np.array([-1, 0]), np.tile(np.eye(4), (2, 1, 1)), {"pelvis": 0})


def test_roles_recognised_from_common_naming_schemes():
    mixamo = ["mixamorig:Hips", "mixamorig:Hips/mixamorig:LeftUpLeg", "mixamorig:Hips/mixamorig:LeftUpLeg/mixamorig:LeftLeg",
              "mixamorig:Hips/mixamorig:LeftUpLeg/mixamorig:LeftLeg/mixamorig:LeftFoot",
              "mixamorig:Hips/mixamorig:Spine", "mixamorig:Hips/mixamorig:Spine/mixamorig:Spine1",
              "mixamorig:Hips/mixamorig:Spine/mixamorig:Spine1/mixamorig:Spine2"]
    r = G.recognise_roles(mixamo)
    assert (r["pelvis"], r["l_hip"], r["l_knee"], r["l_ankle"], r["spine"], r["chest"]) == (0, 1, 2, 3, 4, 6)
    unreal = ["root", "root/pelvis", "root/pelvis/thigh_r", "root/pelvis/thigh_r/calf_r", "root/pelvis/thigh_r/calf_r/foot_r"]
    r = G.recognise_roles(unreal)
    assert (r["pelvis"], r["r_hip"], r["r_knee"], r["r_ankle"]) == (1, 2, 3, 4)
