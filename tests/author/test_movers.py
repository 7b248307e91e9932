"""Rigid movers (lfusd.author.movers): rulebook at every frame, smooth motion, analytic pose == pxr."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from lfusd.author import movers
from lfusd.author.rules import Checker, set_constraint
from lfusd.author.geometry import StageGeometry
from lfusd.author.scenes import objects as kit
from lfusd.author.scenes.build import Builder, box
from lfusd.author.stage import new_stage

FRAMES = 48


def _stage(tmp_path, name, frames=FRAMES):
    stage = new_stage(tmp_path / f"{name}.usda", 1, frames)
    UsdGeom.Scope.Define(stage, "/World/Looks")
    return stage, Builder(stage, tmp_path / f"{name}.usda")


def _surface(b, path, label, size, centre, tex="grass"):
    b.obj(path, label)
    b.mesh(f"{path}/surface", box(size, centre), tex)


def _parts(b, path, label, parts, pos, yaw=0.0):
    b.obj(path, label, pos, yaw)
    for name, data, tex in parts:
        b.mesh(f"{path}/{name}", data, tex)


def _world_points(stage, prim_path, frames):
    """(F, P, 3) world vertices of every mesh under prim_path, from pxr (lfusd.author.geometry)."""
    geo = StageGeometry(stage)
    mine = [g for g in geo.gprims if g.GetPath().HasPrefix(prim_path)]
    return np.stack([np.concatenate([geo.mesh(g, float(f)).vertices for g in mine]) for f in frames])


def _assert_pxr_equals(stage, prim_path, motion):
    prim = stage.GetPrimAtPath(prim_path)
    for f, m in zip(motion.frames, motion.matrices()):
        got = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode(int(f))), float).T
        np.testing.assert_allclose(got, m, atol=1e-9)


def _assert_smooth(points, max_step, max_accel):
    step = np.linalg.norm(np.diff(points, axis=0), axis=-1).max()
    accel = np.linalg.norm(np.diff(points, 2, axis=0), axis=-1).max()
    assert step <= max_step, step
    assert accel <= max_accel, accel


def test_rot_xyz_is_usd_rotate_xyz():
    rng = np.random.default_rng(1)
    for a in rng.uniform(-180, 180, (5, 3)):
        # Gf composes row-vector rotations X first: M = Rx * Ry * Rz (row) = (Rz Ry Rx)^T (column)
        g = (Gf_rot((1, 0, 0), a[0]) @ Gf_rot((0, 1, 0), a[1]) @ Gf_rot((0, 0, 1), a[2])).T
        np.testing.assert_allclose(movers.rot_xyz(a), g, atol=1e-12)


def Gf_rot(axis, deg):
    from pxr import Gf

    return np.array(Gf.Matrix3d(Gf.Rotation(Gf.Vec3d(*axis), float(deg))), float)


def _river(tmp_path, waves, velocity=(0.6, 0.0), yaw=10.0, frames=FRAMES):
    stage, b = _stage(tmp_path, "river", frames)
    _surface(b, "/World/River", "water", (40.0, 10.0, 2.0), (0, 0, -1.0), "water")
    parts, draft = kit.boat(np.random.default_rng(3))
    _parts(b, "/World/Boat", "boat", parts, (-5.0, 0.0, -draft), yaw)
    motion = movers.drift_boat(stage, "/World/Boat", velocity, level=0.0, waves=waves)
    return stage, parts, draft, motion


def test_boat_drifts_bobs_and_stays_within_its_draft(tmp_path):
    waves = movers.wave_params(np.random.default_rng(7))
    stage, parts, draft, motion = _river(tmp_path, waves)
    assert Checker(stage).check() == []
    _assert_pxr_equals(stage, "/World/Boat", motion)
    frames = np.arange(1, FRAMES + 1)
    pts = _world_points(stage, "/World/Boat", frames)
    # Independent of the motion code: the hull's bottom (local z = 0) is under water by an amount
    # inside the closed-form band the boat's draft constraint holds, and the hull's rim stays dry.
    hull = np.asarray(parts[0][1].points)
    bottom = _world_points(stage, "/World/Boat/hull", frames)[:, np.abs(hull[:, 2]) < 1e-9]
    rim = _world_points(stage, "/World/Boat/hull", frames)[:, hull[:, 2] > 0.85]  # the gunwale (the chine rises to the bow)
    lo, hi = np.array(stage.GetPrimAtPath("/World/Boat").GetAttribute("lfusd:constraint:draft").Get(), float)
    depth = -bottom[..., 2]
    assert lo <= depth.min() and depth.max() <= hi
    assert lo > 0.1 and hi - lo < 0.5 and rim[..., 2].min() > 0.2
    assert abs(depth.mean() - draft) < 0.05  # bobbing about the draft it was placed at
    # It heaves, rolls and drifts: the waterline centre moves 0.6 m/s along x.
    centre = motion.translate + np.einsum("nij,j->ni", motion.rotations(), [0, 0, draft])
    np.testing.assert_allclose(centre[-1, 0] - centre[0, 0], 0.6 * (FRAMES - 1) / 24.0, atol=1e-12)
    assert np.ptp(centre[:, 2]) > 0.01 and np.ptp(motion.rotate[:, 0]) > 1.0
    _assert_smooth(pts, max_step=(0.6 + 0.4) / 24, max_accel=3e-3)


def test_a_boat_rocking_beyond_its_draft_fails_check_at_a_later_frame(tmp_path):
    stage, _, draft, _ = _river(tmp_path, movers.Waves(bob=0.08, roll=3.0, pitch=1.0))
    prim = stage.GetPrimAtPath("/World/Boat")
    set_constraint(prim, "draft", (draft - 0.03, draft + 0.03))  # tighter than its waves allow
    lines = [v.line() for v in Checker(stage).check()]
    assert len(lines) == 1 and lines[0].startswith("/World/Boat: floats_on broken at frame"), lines
    assert int(lines[0].split("frame ")[1].split(":")[0]) > 1


def test_drift_boat_refuses_waves_that_lift_the_hull(tmp_path):
    from lfusd.errors import LfusdError

    with pytest.raises(LfusdError, match="lift out of the water"):
        _river(tmp_path, movers.Waves(bob=0.6))


def _street(tmp_path, road_len=60.0, frames=FRAMES):
    stage, b = _stage(tmp_path, "street", frames)
    _surface(b, "/World/Road", "road", (road_len, 8.0, 0.3), (road_len / 2 - 30.0, 0, -0.15), "asphalt")
    _surface(b, "/World/Verge", "grass", (60.0 - road_len, 8.0, 0.3), (road_len / 2 + 0.0, 0, -0.15), "grass")
    parts, wheels, radius = kit.moving_car(np.random.default_rng(2))
    _parts(b, "/World/Car", "car", parts, (-20.0, -2.0, 0.001), 0.0)
    for name, hub, mesh in wheels:
        movers.make_wheel(b.mesh(f"/World/Car/{name}", mesh, "paint_dark").GetPrim(), hub, radius)
    return stage, wheels, radius


def test_car_drives_on_the_road_with_rolling_wheels(tmp_path):
    stage, wheels, radius = _street(tmp_path, road_len=59.0)
    speed = 8.0
    motion = movers.drive_car(stage, "/World/Car", speed)
    assert Checker(stage).check() == []
    _assert_pxr_equals(stage, "/World/Car", motion)
    # Rendering needs: each wheel is a mesh carrying its own transform (Blender merges an Xform
    # holding a single mesh, hiding the mesh's path), and no tyre face is coplanar with the body.
    body = _world_points(stage, "/World/Car/body", [1])[0]
    for name, _, _ in wheels:
        assert stage.GetPrimAtPath(f"/World/Car/{name}").IsA(UsdGeom.Mesh)
        tyre = _world_points(stage, f"/World/Car/{name}", [1])[0]
        assert np.abs(tyre[:, 1] + 2.0).max() > np.abs(body[:, 1] + 2.0).max() + 0.01
    xf = UsdGeom.XformCache()
    for f in (1, 10, 30, FRAMES):
        xf.SetTime(Usd.TimeCode(f))
        for name, hub, _ in wheels:
            w = stage.GetPrimAtPath(f"/World/Car/{name}")
            m = np.array(xf.GetLocalToWorldTransform(w), float).T
            travelled = speed * (f - 1) / 24.0
            np.testing.assert_allclose(m[:3, 3], [-20.0 + hub[0] + travelled, -2.0 + hub[1], 0.001 + hub[2]], atol=1e-9)
            # rolling without slipping: the wheel turned (about +Y) by distance / radius
            angle = np.arctan2(m[0, 2], m[0, 0])
            expect = (travelled / radius + np.pi) % (2 * np.pi) - np.pi
            assert abs((angle - expect + np.pi) % (2 * np.pi) - np.pi) < 1e-9
    # the lowest point of each 12-gon tyre stays within 1.1 cm of the road: r (1 - cos 15 deg)
    pts = _world_points(stage, "/World/Car/wheel_FL", range(1, FRAMES + 1))
    low = pts[..., 2].min(axis=1)
    assert low.min() >= 0.001 - 1e-9 and low.max() <= 0.001 + radius * (1 - np.cos(np.radians(15))) + 1e-9
    _assert_smooth(_world_points(stage, "/World/Car/body", range(1, FRAMES + 1)), speed / 24 + 1e-9, 1e-9)


def test_a_car_driving_off_the_road_fails_check_at_that_frame(tmp_path):
    stage, wheels, radius = _street(tmp_path, road_len=30.0)  # road x in -30..0, grass beyond
    movers.drive_car(stage, "/World/Car", 12.0)
    lines = [v.line() for v in Checker(stage).check()]
    car = [ln for ln in lines if ln.startswith("/World/Car: on broken")]
    assert car and "'grass'" in car[0], lines
    frame = int(car[0].split("frame ")[1].split(":")[0])
    # the front tyres' contact (under their hubs) crosses x = 0 between these two frames
    hub_x = max(h[0] for _, h, _ in wheels)
    crossing = 1 + (20.0 - hub_x) * 24.0 / 12.0
    assert crossing - 1 <= frame <= crossing + 1, (frame, crossing)


def test_cabinet_doors_swing_and_a_chair_slides_cleanly(tmp_path):
    stage, b = _stage(tmp_path, "room")
    _surface(b, "/World/Floor", "floor", (8.0, 8.0, 0.2), (0, 0, -0.1), "wood")
    rng = np.random.default_rng(5)
    parts = kit.cabinet(rng)
    carcass = np.asarray(parts[0][1].points)
    depth, width, height = np.ptp(carcass, axis=0)
    _parts(b, "/World/Cabinet", "cabinet", parts, (-2.0, 0.5, 0.001), 30.0)
    motions = {}
    for name, hinge, sign, panel in kit.cabinet_doors(width, depth, height):
        b.mesh(f"/World/Cabinet/{name}", panel, "wood").AddTranslateOp().Set(tuple(float(v) for v in hinge))
        motions[name] = movers.swing(stage, f"/World/Cabinet/{name}", sign * 95.0, 0.2, 1.0, duration=0.6)
    chair = kit.chair(rng)
    _parts(b, "/World/Chair", "chair", chair, (1.0, 1.0, 0.001), 180.0)
    slid = movers.slide(stage, "/World/Chair", (0.4, 0.0), 0.1, 0.8, t_back=1.0)
    assert Checker(stage).check() == []
    for name, m in motions.items():
        _assert_pxr_equals(stage, f"/World/Cabinet/{name}", _compose(stage, "/World/Cabinet", m))
        yaw = m.rotate[:, 2]
        assert yaw[0] == pytest.approx(0.0, abs=1e-12) and abs(abs(yaw).max() - 95.0) < 1e-9 and yaw[-1] == pytest.approx(0.0, abs=1e-12)
        # C2 easing: the first and last frames of each swing barely move
        steps = np.abs(np.diff(yaw))
        assert steps[steps > 0][0] < 0.01 and steps.max() < 95.0 * 1.875 / (0.6 * 24) + 1e-9
    _assert_pxr_equals(stage, "/World/Chair", slid)
    assert slid.translate[:, 0].max() == pytest.approx(1.4) and slid.translate[-1, 0] == pytest.approx(1.0)
    # the door panels never enter the carcass: all their points lie in front of its front face
    panels = _world_points(stage, "/World/Cabinet/door_L", range(1, FRAMES + 1))
    front = np.array([np.cos(np.radians(30)), np.sin(np.radians(30))])
    ahead = (panels[..., :2] - [-2.0, 0.5]) @ front
    assert ahead.min() >= depth / 2 - 1e-9


def _compose(stage, parent, motion):
    """The child's world motion: a parent placed by translate + rotateZ, then the child's motion."""
    pos, yaw = movers.start_pose(stage.GetPrimAtPath(parent))
    P = np.eye(4)
    P[:3, :3] = movers.rot_xyz([0.0, 0.0, yaw])
    P[:3, 3] = pos
    return _Matrices(motion.frames, P @ motion.matrices())


class _Matrices:
    def __init__(self, frames, mats):
        self.frames, self._m = frames, mats

    def matrices(self):
        return self._m


def test_same_seed_same_motion():
    a = movers.wave_params(np.random.default_rng(11))
    b = movers.wave_params(np.random.default_rng(11))
    c = movers.wave_params(np.random.default_rng(12))
    assert a == b and a != c
    m1 = movers.boat_motion(np.arange(1, 30), 24.0, (0, 0), 0.0, (0.5, 0), -0.5, 0.3, a)
    m2 = movers.boat_motion(np.arange(1, 30), 24.0, (0, 0), 0.0, (0.5, 0), -0.5, 0.3, b)
    assert np.array_equal(m1.translate, m2.translate) and np.array_equal(m1.rotate, m2.rotate)
