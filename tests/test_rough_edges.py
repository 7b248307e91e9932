"""New-user rough edges (issue 27 item 5): the compile note, `rig add --from-camera`, hints right
for assets, negative frames, an invalid upAxis refused at once, pxr warnings on one line each."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom

from support.cli import assert_one_line_error, run_cli

from lfusd.camera import parse_frames


def rot(axis: str, deg: float) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]), "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def usd_matrix(m: np.ndarray) -> Gf.Matrix4d:
    return Gf.Matrix4d(*np.asarray(m, float).T.ravel().tolist())  # USD: row vectors


# A camera asset as DCCs export it: Y up, centimetres, the camera under a moving parent, rolled
# 10 degrees, lens 35 mm and a 36 x 20.25 mm aperture (USD: tenths of a scene unit = mm here).
FRAMES = (1, 3)


def cam_local() -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = rot("y", 30) @ rot("x", -8) @ rot("z", 10)  # yaw, pitch, roll in the stage's Y-up axes
    m[:3, 3] = (20.0, 160.0, 600.0)
    return m


def parent_at(f: int) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (15.0 * (f - 1), 0.0, -40.0 * (f - 1))  # cm per frame
    return m


def write_camera_asset(path: Path, up: str = "Y") -> None:
    stage = Usd.Stage.CreateNew(str(path))
    stage.SetMetadata("upAxis", up)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    stage.SetStartTimeCode(FRAMES[0])
    stage.SetEndTimeCode(FRAMES[1])
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    dolly = UsdGeom.Xform.Define(stage, "/World/Dolly")
    op = dolly.AddTransformOp()
    for f in range(FRAMES[0], FRAMES[1] + 1):
        op.Set(usd_matrix(parent_at(f)), f)
    cam = UsdGeom.Camera.Define(stage, "/World/Dolly/Cam")
    cam.AddTransformOp().Set(usd_matrix(cam_local()))
    cam.CreateFocalLengthAttr(35.0)
    cam.CreateHorizontalApertureAttr(36.0)
    cam.CreateVerticalApertureAttr(20.25)
    cube = UsdGeom.Cube.Define(stage, "/World/Box")
    cube.CreateSizeAttr(100.0)
    stage.Save()


def expected_pose(f: int) -> np.ndarray:
    """The camera's OpenCV camera-to-world pose in lfusd's world (Z up, metres), by hand:
    stage (Y up, cm) -> world is (x, y, z) -> (x, -z, y) * 0.01; USD cameras look down -Z, +Y up."""
    m = parent_at(f) @ cam_local()
    y_to_z = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float)
    out = np.eye(4)
    out[:3, :3] = y_to_z @ m[:3, :3] @ np.diag([1.0, -1.0, -1.0])
    out[:3, 3] = y_to_z @ m[:3, 3] * 0.01
    return out


@pytest.mark.parametrize("grid", ["3x3", "2x4"])
def test_rig_add_from_camera_centres_the_rig_on_the_stage_camera(tmp_path, capsys, grid):
    from lfusd.author.rigs import rigs
    from lfusd.author.stage import open_stage

    asset = tmp_path / "shot.usda"
    write_camera_asset(asset)
    before = hashlib.sha256(asset.read_bytes()).hexdigest()
    code, out, err = run_cli(capsys, "rig", "add", asset, "-o", tmp_path / "shot_rig.usda", "--from-camera", "/World/Dolly/Cam",
                             "--grid", grid, "--baseline", "0.05")
    assert code == 0, err
    assert "centre view at camera /World/Dolly/Cam (35 mm lens, 36 mm aperture)" in out
    assert hashlib.sha256(asset.read_bytes()).hexdigest() == before  # the asset is untouched
    stage = open_stage(tmp_path / "shot_rig.usda")
    rig = rigs(stage)["main"]
    spec = rig.spec
    assert (spec.focal_length_mm, spec.sensor_mm) == pytest.approx((35.0, 36.0))
    assert (spec.width, spec.height) == (1024, 576)  # the camera's 16:9 aperture
    centre = spec.centre_view
    for f in range(FRAMES[0], FRAMES[1] + 1):
        np.testing.assert_allclose(rig.cam_to_world(stage, centre, f), expected_pose(f), atol=1e-9)
        # a point 4 m straight ahead of the camera lands on the centre view's principal point
        X = expected_pose(f) @ np.array([0, 0, 4.0, 1])
        c2w = rig.cam_to_world(stage, centre, f)
        x = spec.intrinsics() @ (np.linalg.inv(c2w) @ X)[:3]
        np.testing.assert_allclose(x[:2] / x[2], [(spec.width - 1) / 2, (spec.height - 1) / 2], atol=1e-6)
        # the other views keep the rig's geometry: one baseline apart along the camera's own x axis
        if spec.cols > 1:
            right = rig.cam_to_world(stage, (centre[0], centre[1] + 1), f)
            np.testing.assert_allclose(right[:3, 3] - c2w[:3, 3], 0.05 * expected_pose(f)[:3, 0], atol=1e-9)


def test_rig_add_from_camera_refusals(tmp_path, capsys):
    asset = tmp_path / "shot.usda"
    write_camera_asset(asset)
    code, _, err = run_cli(capsys, "rig", "add", asset, "-o", tmp_path / "a.usda", "--from-camera", "/World/Nope")
    assert_one_line_error(code, err, "/World/Nope does not exist", "/World/Dolly/Cam")
    code, _, err = run_cli(capsys, "rig", "add", asset, "-o", tmp_path / "b.usda", "--from-camera", "/World/Box")
    assert_one_line_error(code, err, "is not a UsdGeom.Camera")
    code, _, err = run_cli(capsys, "rig", "add", asset, "-o", tmp_path / "c.usda", "--from-camera", "/World/Dolly/Cam", "--at", "0,0,1")
    assert_one_line_error(code, err, "drop --at")
    assert not any((tmp_path / n).exists() for n in ("a.usda", "b.usda", "c.usda"))


def test_no_rig_hint_writes_a_new_layer_and_works_for_usdz(tmp_path, capsys, monkeypatch):
    asset = tmp_path / "shot.usda"
    write_camera_asset(asset)
    code, _, err = run_cli(capsys, "render", asset, "-o", tmp_path / "out", "--quiet")
    assert_one_line_error(code, err, "has no light-field rig", f"'lfusd rig add {asset} -o shot_rig.usda --from-camera /World/Dolly/Cam'",
                          "then render shot_rig.usda")
    assert not (tmp_path / "out").exists()
    # following it on a .usdz package (read-only: the hint must not edit in place)
    from pxr import UsdUtils

    usdz = tmp_path / "pkg.usdz"
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(asset)), str(usdz))
    code, _, err = run_cli(capsys, "render", usdz, "-o", tmp_path / "out2", "--quiet")
    assert_one_line_error(code, err, f"'lfusd rig add {usdz} -o pkg_rig.usda --from-camera /World/Dolly/Cam'")
    monkeypatch.chdir(tmp_path)
    code, _, err = run_cli(capsys, "rig", "add", usdz, "-o", "pkg_rig.usda", "--from-camera", "/World/Dolly/Cam")
    assert code == 0, err


def test_negative_frames_parse_everywhere(capsys):
    assert parse_frames("-3") == [-3]
    assert parse_frames("-5--2") == [-5, -4, -3, -2]
    assert parse_frames("-2-1,4") == [-2, -1, 0, 1, 4]
    from lfusd.cli import build_parser

    ap = build_parser()
    assert ap.parse_args(["render-video", "s.usda", "-o", "x", "--frames", "-5--2"]).frames == (-5, -2)
    assert ap.parse_args(["verify", "x", "--frames", "-3,0"]).frames == [-3, 0]
    assert ap.parse_args(["view", "x", "--frames", "-3"]).frames == [-3]
    code, _, err = run_cli(capsys, "render-video", "s.usda", "-o", "x", "--frames", "-2--5")
    assert code == 2 and "reversed" in err


def write_bad_axis(path: Path) -> None:
    stage = Usd.Stage.CreateNew(str(path))
    stage.SetMetadata("upAxis", "X")
    UsdGeom.Xform.Define(stage, "/World")
    stage.Save()


def test_invalid_up_axis_is_refused_at_once(tmp_path, capsys):
    stage = tmp_path / "x_up.usda"
    write_bad_axis(stage)
    for argv in (("check", stage, "--no-coverage"), ("rig", "add", stage, "-o", tmp_path / "r.usda"),
                 ("render", stage, "-o", tmp_path / "out", "--quiet")):
        code, _, err = run_cli(capsys, *argv)
        assert code == 2
        assert_one_line_error(code, err, "upAxis 'X'", 'set upAxis to "Z" or "Y"')
    assert not (tmp_path / "out").exists() and not (tmp_path / "r.usda").exists()


@pytest.mark.timeout(600)  # its subprocess may take 300 s
def test_pxr_warnings_fold_into_one_lfusd_line_each(tmp_path):
    stage = tmp_path / "looks.usda"
    stage.write_text('#usda 1.0\n(\n    upAxis = "Z"\n    metersPerUnit = 1\n)\n'
                     'def Xform "World"\n{\n'
                     '    def "LookA" (references = @./looks/a.mtlx@</MaterialX>) {}\n'
                     '    def "LookB" (references = @./looks/b.mtlx@</MaterialX>) {}\n}\n')
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(Path(__file__).resolve().parents[1]), os.environ.get("PYTHONPATH", "")]))
    r = subprocess.run([sys.executable, "-m", "lfusd", "check", str(stage), "--no-coverage", "--no-usd-validation"],
                       capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert all(ln.startswith("lfusd: ") for ln in lines), r.stderr  # nothing of pxr's own "Warning: in ... at line ..."
    usd = [ln for ln in lines if ln.startswith("lfusd: warning: USD: ")]
    assert len(usd) == 2 and "a.mtlx" in usd[0] + usd[1] and "b.mtlx" in usd[0] + usd[1]


@pytest.mark.slow  # compiles the numba kernels afresh (about 2 minutes)
def test_compile_note_when_numba_has_no_cached_kernels(tmp_path):
    code = ("from lfusd.cli import configure_logging; configure_logging(); "
            "from lfusd.truth.motion import announce_compile; announce_compile(); announce_compile()")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"),
               PYTHONPATH=os.pathsep.join([str(Path(__file__).resolve().parents[1]), os.environ.get("PYTHONPATH", "")]))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip() and "numba" in ln.lower()]
    assert len(lines) == 1 and lines[0].startswith("lfusd: warning: compiling the motion kernels"), r.stderr


def test_compile_note_only_when_not_cached(monkeypatch):
    import logging

    from lfusd.truth import _motion_numba, motion

    seen = []
    handler = logging.Handler()
    handler.emit = lambda record: seen.append(record.getMessage())
    logger = logging.getLogger(motion.__name__)
    logger.addHandler(handler)
    monkeypatch.setattr(logger, "level", logging.WARNING)
    try:
        for cached in (True, False):
            monkeypatch.setattr(motion, "_ANNOUNCED", False)
            monkeypatch.setattr(_motion_numba, "kernels_cached", lambda cached=cached: cached)
            motion.announce_compile()
            motion.announce_compile()  # once per process
    finally:
        logger.removeHandler(handler)
    assert len(seen) == 1 and seen[0].startswith("compiling the motion kernels")


@pytest.mark.render
def test_render_video_of_negative_time_codes(tmp_path, capsys):
    """A stage whose animation runs over time codes -2..0, rendered with --frames -2--1: frames
    keep their (negative) numbers and the motion is the box's analytic 0.2 m per frame along x."""
    from lfusd import Dataset
    from lfusd.author.labels import set_class_label
    from lfusd.author.rigs import add_rig
    from lfusd.author.stage import new_stage
    from lfusd.camera import RigSpec

    stage = new_stage(tmp_path / "neg.usda", -2, 0)
    g = UsdGeom.Mesh.Define(stage, "/World/Ground")
    g.CreatePointsAttr([(-20, -20, 0), (20, -20, 0), (20, 20, 0), (-20, 20, 0)])
    g.CreateFaceVertexCountsAttr([4])
    g.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    set_class_label(g.GetPrim(), "ground")
    box = UsdGeom.Cube.Define(stage, "/World/Box")
    box.CreateSizeAttr(0.8)
    set_class_label(box.GetPrim(), "crate")
    op = box.AddTranslateOp()
    for f in (-2, -1, 0):
        op.Set(Gf.Vec3d(0.2 * f, 0, 0.5), f)
    add_rig(stage, RigSpec(name="main", rows=1, cols=2, width=24, height=20, baseline=0.1, at=(0, -5, 1.5), look_at=(0, 0, 0.5)))
    stage.Save()
    code, out, err = run_cli(capsys, "render-video", tmp_path / "neg.usda", "-o", tmp_path / "out", "--frames", "-2--1",
                             "--samples", "1", "--quiet", "--device", "cpu")
    assert code == 0, err
    ds = Dataset(tmp_path / "out")
    assert ds.frames == [-2, -1]
    box_id = next(i for i, o in ds.objects.items() if o.prim_path == "/World/Box")
    inst = ds.read(-2, (0, 0), "instance")
    sf = ds.read(-2, (0, 0), "scene_flow")
    valid = ds.read(-2, (0, 0), "valid_fwd")
    on_box = (inst == box_id) & valid
    assert on_box.sum() > 10
    np.testing.assert_allclose(sf[on_box], np.broadcast_to([0.2, 0.0, 0.0], sf[on_box].shape), atol=1e-4)
    np.testing.assert_allclose(sf[(inst != box_id) & (inst > 0) & valid], 0.0, atol=1e-4)
    assert not ds.read(-1, (0, 0), "valid_fwd").any()  # frame 0 was not rendered: no t+1 for -1
