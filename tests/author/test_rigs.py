"""Rig geometry and USD authoring (no Blender): every camera where the formula puts it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lfusd.errors import LfusdError
from lfusd.camera import RigSpec, grid_offset, parse_grid, parse_point, parse_resolution
from lfusd.author.stage import new_stage
from lfusd.author.rigs import FLIP_YZ, add_rig, rigs, select_rigs


@pytest.mark.parametrize(
    "spacing,count,expected",
    [
        ("uniform", 5, [-2, -1, 0, 1, 2]),
        ("linear", 5, [-3, -1, 0, 1, 3]),  # gaps 1, 2 outward
        ("inverse", 5, [-1.5, -1, 0, 1, 1.5]),  # gaps 1, 1/2
        ("exponential", 7, [-7, -3, -1, 0, 1, 3, 7]),  # gaps 1, 2, 4
        ("uniform", 4, [-1.5, -0.5, 0.5, 1.5]),
        ("linear", 4, [-2.5, -0.5, 0.5, 2.5]),  # half of gap 1, then gap 2
        ("inverse", 6, [-1 - 1 / 3, -1, -0.5, 0.5, 1, 1 + 1 / 3]),
        ("exponential", 4, [-2.5, -0.5, 0.5, 2.5]),
        ("linear", 1, [0]),
    ],
)
def test_grid_offsets_follow_the_gap_rules(spacing, count, expected):
    assert [grid_offset(i, count, spacing) for i in range(count)] == pytest.approx(expected)


def _positions(spec: RigSpec) -> dict:
    return {v: spec.cam_to_world(v)[:3, 3] for v in spec.views}


def test_default_rig_is_the_reference_configuration():
    s = RigSpec()
    assert (s.rows, s.cols, s.baseline, s.focal_length_mm, s.sensor_mm, s.width, s.height) == (9, 9, 0.125, 39.0, 36.0, 1024, 1024)
    assert (s.spacing, s.layout, s.axes) == ("uniform", "plane", "parallel")
    assert s.centre_view == (4, 4)
    K = s.intrinsics()
    assert K[0, 0] == pytest.approx(39 / 36 * 1024) and K[0, 2] == 511.5 and K[1, 2] == 511.5


def test_planar_parallel_rig_positions_and_axes():
    spec = RigSpec(rows=3, cols=5, baseline=0.2, spacing="linear", at=(1, 2, 3), look_at=(1, 12, 3))
    pos = _positions(spec)
    # Looking along +Y with Z up: image x is world +X, image y (down) is world -Z.
    for (r, c), p in pos.items():
        sx = [-3, -1, 0, 1, 3][c]
        sy = [-1, 0, 1][r]
        np.testing.assert_allclose(p, [1 + 0.2 * sx, 2, 3 - 0.2 * sy], atol=1e-12)
        R = spec.cam_to_world((r, c))[:3, :3]
        np.testing.assert_allclose(R, [[1, 0, 0], [0, 0, 1], [0, -1, 0]], atol=1e-12)


def test_view_zero_zero_is_top_left_seen_from_behind():
    spec = RigSpec(rows=3, cols=3, at=(0, 0, 0), look_at=(0, 5, 0))
    tl, br = spec.cam_to_world((0, 0))[:3, 3], spec.cam_to_world((2, 2))[:3, 3]
    assert tl[0] < br[0] and tl[2] > br[2]  # left of and above the last view


def test_spherical_rig_cameras_lie_on_the_sphere_and_look_at_its_centre():
    spec = RigSpec(rows=5, cols=5, baseline=0.5, layout="sphere", axes="converge", radius=4.0, at=(0, -4, 1), look_at=(0, 0, 1))
    centre = np.array([0.0, 0.0, 1.0])
    for v in spec.views:
        T = spec.cam_to_world(v)
        assert np.linalg.norm(T[:3, 3] - centre) == pytest.approx(4.0)
        axis = T[:3, 2]
        np.testing.assert_allclose(axis, (centre - T[:3, 3]) / 4.0, atol=1e-12)
        np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
    # Neighbours along the middle row are one baseline apart along the sphere (arc length).
    a, b = spec.cam_to_world((2, 2))[:3, 3], spec.cam_to_world((2, 3))[:3, 3]
    assert np.linalg.norm(a - b) == pytest.approx(2 * 4.0 * math.sin(0.5 / (2 * 4.0)))
    assert spec.cam_to_world((2, 3))[0, 3] > 0  # the view right of centre is at +x


def test_converging_planar_rig_points_every_axis_at_the_target():
    spec = RigSpec(rows=3, cols=3, baseline=0.3, axes="converge", at=(0, -6, 2), look_at=(1, 0, 1))
    target = np.array([1.0, 0, 1])
    rest = RigSpec(rows=3, cols=3, baseline=0.3, at=(0, -6, 2), look_at=(1, 0, 1))
    for v in spec.views:
        T = spec.cam_to_world(v)
        np.testing.assert_allclose(T[:3, 3], rest.cam_to_world(v)[:3, 3], atol=1e-12)  # same plane positions
        d = target - T[:3, 3]
        np.testing.assert_allclose(T[:3, 2], d / np.linalg.norm(d), atol=1e-12)


@pytest.mark.parametrize("layout,axes,spacing", [("plane", "parallel", "exponential"), ("plane", "converge", "inverse"), ("sphere", "converge", "linear")])
def test_usd_round_trip_keeps_spec_and_poses(layout, axes, spacing):
    stage = new_stage(None)
    spec = RigSpec(name="r", rows=3, cols=4, width=64, height=48, layout=layout, axes=axes, spacing=spacing, at=(1, -5, 2), look_at=(0, 0, 1))
    add_rig(stage, spec)
    rig = rigs(stage)["r"]
    assert rig.spec == spec
    for v in spec.views:
        np.testing.assert_allclose(rig.cam_to_world(stage, v, 1), spec.cam_to_world(v), atol=1e-12)


def test_usd_camera_lens_is_in_tenths_of_a_scene_unit():
    from pxr import UsdGeom

    stage = new_stage(None)
    add_rig(stage, RigSpec(name="r", rows=1, cols=1, width=200, height=100))
    cam = UsdGeom.Camera(stage.GetPrimAtPath("/Rigs/r/cam_00_00"))
    assert cam.GetFocalLengthAttr().Get() == pytest.approx(0.39)  # 39 mm with metersPerUnit = 1
    assert cam.GetHorizontalApertureAttr().Get() == pytest.approx(0.36)
    assert cam.GetVerticalApertureAttr().Get() == pytest.approx(0.18)
    # A centimetre stage gets the same lens in its own units.
    cm = new_stage(None)
    UsdGeom.SetStageMetersPerUnit(cm, 0.01)
    add_rig(cm, RigSpec(name="r", rows=1, cols=1))
    assert UsdGeom.Camera(cm.GetPrimAtPath("/Rigs/r/cam_00_00")).GetFocalLengthAttr().Get() == pytest.approx(39.0)


def test_usd_camera_looks_down_minus_z():
    stage = new_stage(None)
    spec = RigSpec(name="r", rows=1, cols=1, at=(0, 0, 0), look_at=(0, 5, 0))
    add_rig(stage, spec)
    from pxr import Usd, UsdGeom

    m = np.array(UsdGeom.Xformable(stage.GetPrimAtPath("/Rigs/r/cam_00_00")).ComputeLocalToWorldTransform(Usd.TimeCode(1))).T
    np.testing.assert_allclose(m[:3, :3] @ [0, 0, -1], [0, 1, 0], atol=1e-12)  # forward
    np.testing.assert_allclose(m[:3, :3] @ [0, 1, 0], [0, 0, 1], atol=1e-12)  # up
    np.testing.assert_allclose(FLIP_YZ @ FLIP_YZ, np.eye(4))


def test_several_rigs_and_selection():
    stage = new_stage(None)
    for i in range(3):
        add_rig(stage, RigSpec(name=f"rig_{i:02d}", rows=1, cols=2, at=(i, -5, 1)))
    assert [r.spec.name for r in select_rigs(stage, "all", "s.usda")] == ["rig_00", "rig_01", "rig_02"]
    assert select_rigs(stage, "rig_01", "s.usda")[0].spec.at == (1.0, -5.0, 1.0)
    with pytest.raises(LfusdError, match="has 3 rigs"):
        select_rigs(stage, None, "s.usda")
    with pytest.raises(LfusdError, match="no rig named 'nope'"):
        select_rigs(stage, "nope", "s.usda")
    with pytest.raises(LfusdError, match="already has a rig named"):
        add_rig(stage, RigSpec(name="rig_00"))
    with pytest.raises(LfusdError, match="has no light-field rig"):
        select_rigs(new_stage(None), None, "s.usda")


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"baseline": 0.0}, "baseline must be a positive"),
        ({"baseline": -1.0}, "baseline must be a positive"),
        ({"rows": 0}, "grid rows must be a positive"),
        ({"width": -4}, "resolution width"),
        ({"focal_length_mm": 0}, "focal length"),
        ({"spacing": "random"}, "unknown spacing"),
        ({"layout": "cube"}, "unknown layout"),
        ({"axes": "crossed"}, "unknown axes"),
        ({"look_at": (0.0, -10.0, 1.5)}, "same point"),
        ({"name": "9lives"}, "not a valid USD prim name"),
        ({"layout": "sphere", "radius": 0.2, "baseline": 1.0}, "more than a hemisphere"),
    ],
)
def test_impossible_rigs_are_refused(kwargs, match):
    with pytest.raises(LfusdError, match=match):
        RigSpec(**kwargs)


def test_parsers():
    assert parse_grid("7x7") == (7, 7) and parse_resolution("640X480") == (640, 480)
    assert parse_point("1,2.5,-3", "--at") == (1.0, 2.5, -3.0)
    for bad in ("9", "9x", "0x9", "-1x3", "axb", "3x3x3"):
        with pytest.raises(LfusdError):
            parse_grid(bad)
    with pytest.raises(LfusdError, match="X,Y,Z"):
        parse_point("1,2", "--at")


def test_add_rig_to_file_writes_what_it_returns_and_refuses_before_writing(tmp_path):
    """The library function behind `lfusd rig add`: the rig read back from the saved file is the
    spec returned, centred where asked; a pose given with --from-camera is refused, file untouched."""
    from pxr import Usd

    from lfusd.author.rigs import add_rig_to_file

    path = tmp_path / "s.usda"
    new_stage(path, 1, 1).Save()
    spec, target = add_rig_to_file(path, name="r", grid=(2, 3), resolution=(8, 6), at=(1.0, -4.0, 2.0), look_at=(1.0, 0.0, 2.0))
    assert target == str(path) and (spec.rows, spec.cols, spec.width, spec.height) == (2, 3, 8, 6)
    back = rigs(Usd.Stage.Open(str(path)))["r"]
    assert back.spec == spec
    stage = Usd.Stage.Open(str(path))
    centre = np.mean([back.cam_to_world(stage, v, 1)[:3, 3] for v in spec.views], axis=0)
    np.testing.assert_allclose(centre, (1.0, -4.0, 2.0), atol=1e-9)  # the rig centre is --at
    before = path.read_bytes()
    with pytest.raises(LfusdError, match="--from-camera takes the pose and lens from the camera; drop --at"):
        add_rig_to_file(path, name="c", at=(0.0, 0.0, 1.0), from_camera="/Cam")
    with pytest.raises(LfusdError, match="--grid 100x100 is 10000 views"):
        add_rig_to_file(path, name="big", grid=(100, 100))
    assert path.read_bytes() == before
