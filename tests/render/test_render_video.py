"""`lfusd render-video` on tiny renders: motion ground truth against analytic projected motion."""

from __future__ import annotations

import errno
import json

import numpy as np
import pytest
from support.analytic import cast, cast_uv, pixel_rays, project
from support.scenes import GROUND_HALF, MOVERS, movers_world, rig_offset, write_motion_stage
from support.cli import assert_one_line_error, run_cli

from lfusd import Dataset
from lfusd.camera import RigSpec

pytestmark = pytest.mark.render

RIG = RigSpec(name="main", rows=3, cols=3, width=48, height=40, baseline=0.1, at=(0.3, -5.0, 1.8), look_at=(0.0, 0.5, 0.6))
RIG_MOTION = (0.05, -0.03, 0.0)  # metres per frame: the whole rig moves too
FRAMES = 3


def assert_same_data(a, b, frames, views, keys):
    """Two datasets rendered separately hold the same data: integer keys and masks exactly, floating
    keys to far below their accuracy (Cycles' threads and SIMD paths may differ between the runs),
    8-bit colour to one level."""
    for f in frames:
        for view in views:
            for key in keys:
                x, y = a.read(f, view, key), b.read(f, view, key)
                assert x.shape == y.shape and x.dtype == y.dtype, (f, view, key)
                if key == "rgb":
                    assert np.abs(x.astype(int) - y).max() <= 1, (f, view, key)
                elif np.issubdtype(x.dtype, np.floating):
                    np.testing.assert_allclose(x, y, rtol=1e-6, atol=1e-6, equal_nan=True, err_msg=f"{f} {view} {key}")
                else:
                    np.testing.assert_array_equal(x, y, err_msg=f"{f} {view} {key}")


def analytic_cam(view, frame):
    T = RIG.cam_to_world(view)
    T[:3, 3] += rig_offset(frame, RIG_MOTION)
    return T


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    root = tmp_path_factory.mktemp("video")
    stage = root / "movers.usda"
    write_motion_stage(stage, RIG, FRAMES, RIG_MOTION)
    out = root / "out"
    from lfusd.cli import main

    # --keep-raw: Blender's raw passes stay readable (the vector pass test below)
    assert main(["render-video", str(stage), "-o", str(out), "--samples", "2", "--quiet", "--device", "cpu", "--workers", "2", "--keep-raw"]) == 0
    return stage, out


def analytic_motion(view, t, t2):
    """Per-pixel analytic hit at frame t and its motion to frame t2 (t +/- 1)."""
    K = RIG.intrinsics()
    T0, T1 = analytic_cam(view, t), analytic_cam(view, t2)
    depth, hit = cast(K, T0, RIG.width, RIG.height, movers_world(t), GROUND_HALF)
    origin, dirs = pixel_rays(K, T0, RIG.width, RIG.height)
    P0 = origin + depth[..., None] * dirs
    P1 = P0.copy()
    for name, (pose, _, _) in MOVERS.items():
        sel = hit == f"/World/{name}"
        M = pose(t2) @ np.linalg.inv(pose(t))
        P1[sel] = P0[sel] @ M[:3, :3].T + M[:3, 3]
    v, u = np.mgrid[0 : RIG.height, 0 : RIG.width]
    fin = np.isfinite(depth)
    flow = np.zeros(depth.shape + (2,))
    flow[fin] = project(K, T1, P1[fin]) - np.stack([u[fin], v[fin]], -1)
    w2c = np.linalg.inv(T1)
    z1 = P1 @ w2c[2, :3] + w2c[2, 3]
    # visibility at t2: the first surface along the ray through the point's pixel there
    vis = np.zeros(depth.shape, bool)
    uv1 = u[fin] + flow[fin][:, 0], v[fin] + flow[fin][:, 1]
    inside = (uv1[0] > -0.5) & (uv1[0] < RIG.width - 0.5) & (uv1[1] > -0.5) & (uv1[1] < RIG.height - 0.5)
    first = cast_uv(K, T1, np.stack(uv1, -1), movers_world(t2), GROUND_HALF)
    vis[fin] = inside & (first >= z1[fin] * (1 - 1e-6))
    return {"depth": depth, "hit": hit, "flow": flow, "scene_flow": P1 - P0, "z1": z1, "visible": vis}


def _interior(ds, frame, view, hit):
    ids = {o.prim_path: i for i, o in ds.objects.items()}
    ref = np.vectorize(lambda h: ids.get(h if h != "ground" else "/World/Ground", 0))(hit)
    same = ref == ds.read(frame, view, "instance")
    m = same.copy()
    m[1:] &= same[:-1]
    m[:-1] &= same[1:]
    m[:, 1:] &= same[:, :-1]
    m[:, :-1] &= same[:, 1:]
    return m & (ref > 0), ref


@pytest.mark.parametrize("direction", ["fwd", "bwd"])
def test_flow_scene_flow_and_disparity_change_equal_analytic_motion(video, direction):
    ds = Dataset(video[1])
    f_px, b = RIG.focal_px, RIG.baseline
    errs, sf_errs, dc_errs, moving = [], [], [], 0
    frames = [1, 2] if direction == "fwd" else [2, 3]
    for t in frames:
        t2 = t + 1 if direction == "fwd" else t - 1
        for view in ds.views:
            ref = analytic_motion(view, t, t2)
            sel, ids = _interior(ds, t, view, ref["hit"])
            valid = ds.read(t, view, f"valid_{direction}")
            assert valid[sel].all(), f"frame {t} view {view}: {direction} motion invalid on interior pixels"
            flow = ds.read(t, view, f"flow_{direction}")
            errs.append(np.linalg.norm(flow[sel] - ref["flow"][sel], axis=-1))
            moving += (np.linalg.norm(ref["flow"][sel], axis=-1) > 1.0).sum()
            if direction == "fwd":
                sf = ds.read(t, view, "scene_flow")
                sf_errs.append(np.linalg.norm(sf[sel] - ref["scene_flow"][sel], axis=-1))
                dc_ref = f_px * b / ref["z1"] - f_px * b / ref["depth"]
                dc_errs.append(np.abs(ds.read(t, view, "disparity_change")[sel] - dc_ref[sel]))
    e = np.concatenate(errs)
    assert moving > 200  # the test sees real motion, not only a still background
    assert np.median(e) < 0.005 and np.percentile(e, 99) < 0.05, (np.median(e), np.percentile(e, 99), e.max())
    if direction == "fwd":
        s = np.concatenate(sf_errs)
        assert np.median(s) < 1e-4 and np.percentile(s, 99) < 1e-3, (np.median(s), np.percentile(s, 99))
        d = np.concatenate(dc_errs)
        assert np.median(d) < 0.005 and np.percentile(d, 99) < 0.05, (np.median(d), np.percentile(d, 99))


def test_raw_vector_pass_signs_match_analytic_flow(video):
    """Blender's vector pass: forward = (-Z, +W), backward = (X, -Y) in (u right, v down)."""
    ds = Dataset(video[1])
    view = RIG.centre_view
    vec = ds.read(2, view, "vector")
    for t2, flow in ((3, np.stack([-vec[..., 2], vec[..., 3]], -1)), (1, np.stack([vec[..., 0], -vec[..., 1]], -1))):
        ref = analytic_motion(view, 2, t2)
        sel, _ = _interior(ds, 2, view, ref["hit"])
        e = np.linalg.norm(flow[sel] - ref["flow"][sel], axis=-1)
        assert np.percentile(e, 99) < 0.05, (t2, np.percentile(e, 99))


def test_occlusion_masks_agree_with_ray_cast_visibility(tmp_path):
    """> 99% agreement, measured on a 160x128 view (at 48x40 silhouettes are a large share of pixels)."""
    global RIG
    rig = RigSpec(name="main", rows=1, cols=1, width=160, height=128, at=(0.3, -5.0, 1.8), look_at=(0.0, 0.5, 0.6))
    stage = tmp_path / "occ.usda"
    write_motion_stage(stage, rig, 2, RIG_MOTION)
    from lfusd.cli import main

    assert main(["render-video", str(stage), "-o", str(tmp_path / "out"), "--samples", "1", "--quiet", "--device", "cpu"]) == 0
    ds = Dataset(tmp_path / "out")
    saved, RIG = RIG, rig
    try:
        ref = analytic_motion((0, 0), 1, 2)
    finally:
        RIG = saved
    fg = np.isfinite(ref["depth"]) & np.isfinite(ds.read(1, (0, 0), "depth"))
    occ = ds.read(1, (0, 0), "occlusion_fwd")
    assert (~ref["visible"][fg]).sum() > 100  # the scene has occlusions to find
    agree = (occ[fg] == ~ref["visible"][fg]).mean()
    assert agree > 0.99, agree


def test_masks_at_the_ends_of_the_range(video):
    ds = Dataset(video[1])
    for view in ds.views:
        assert not ds.read(FRAMES, view, "valid_fwd").any()
        assert not ds.read(1, view, "valid_bwd").any()
        fg = np.isfinite(ds.read(2, view, "depth"))
        assert ds.read(2, view, "valid_bwd")[fg].mean() > 0.95


def test_poses_and_cameras_equal_the_authored_transforms(video):
    ds = Dataset(video[1])
    assert ds.frames == [1, 2, 3]
    paths = {o.prim_path: o for o in ds.objects.values()}
    for f in ds.frames:
        for name, (pose, _, _) in MOVERS.items():
            np.testing.assert_allclose(paths[f"/World/{name}"].poses[f], pose(f), atol=1e-6)
        for view in ds.views:
            np.testing.assert_allclose(ds.cam_to_world(f, view), analytic_cam(view, f), atol=1e-6)


def test_a_views_motion_decodes_only_its_own_raw_passes(video, tmp_path, monkeypatch):
    """Exact occlusion reads a neighbouring frame's camera, not its images: the motion of frame t,
    derived in a fresh process state (a derivation lane whose cache no longer holds the view),
    decodes t's passes.exr alone, not t-1's and t+1's too, and writes the motion keys the render
    wrote."""
    import shutil

    from lfusd.data import passes
    from lfusd.truth.motion import MOTION_KEYS
    from lfusd.truth.derive import write_motion

    _, reference = video
    out = tmp_path / "out"
    shutil.copytree(reference, out)
    decoded = []
    read_raw = passes.read_raw
    monkeypatch.setattr(passes, "read_raw", lambda path: decoded.append(str(path)) or read_raw(path))
    b = Dataset(reference)
    for f in range(1, FRAMES + 1):
        for v in ((0, 0), (1, 2)):
            decoded.clear()
            write_motion(Dataset(out), f, v)
            assert decoded == [str(Dataset(out).view_dir(f, v) / "passes.exr")], (f, v)
            a = Dataset(out)
            for key in MOTION_KEYS:  # every motion key a render without camera effects makes
                x, y = a.read(f, v, key), b.read(f, v, key)
                assert x.dtype == y.dtype and np.array_equal(x.view(np.uint8), y.view(np.uint8)), (f, v, key)


def test_a_lane_decodes_each_raw_pass_once_for_static_keys_and_motion(video, tmp_path, monkeypatch):
    """As render-video's derivation lanes call it (a view's frames in turn, the lane's cache no longer
    holding the view): derive_if_stale of frame t writes t's gt.exr and motion from one decoding of
    t's passes.exr, and decodes no neighbour's; what it writes equals what the render wrote."""
    import shutil

    from lfusd.data import integrity, passes
    from lfusd.truth.motion import MOTION_KEYS
    from lfusd.truth.derive import derive_if_stale

    _, reference = video
    out = tmp_path / "out"
    shutil.copytree(reference, out)
    v = (2, 1)
    for f in range(1, FRAMES + 1):  # as committed, before any derivation: no gt.exr, no motion
        d = Dataset(out).view_dir(f, v)
        integrity.record_files(d, remove=("gt.exr", "motion.exr"))
        (d / "gt.exr").unlink()
        (d / "motion.exr").unlink()
    decoded = []
    read_raw = passes.read_raw
    monkeypatch.setattr(passes, "read_raw", lambda path: decoded.append(str(path)) or read_raw(path))
    b = Dataset(reference)
    for f in range(1, FRAMES + 1):
        decoded.clear()
        assert derive_if_stale(Dataset(out), f, v)
        assert decoded == [str(Dataset(out).view_dir(f, v) / "passes.exr")], f
    a = Dataset(out)
    for f in range(1, FRAMES + 1):
        assert not integrity.render_problems(a.view_dir(f, v))
        for key in MOTION_KEYS + ("depth", "instance", "normal"):
            x, y = a.read(f, v, key), b.read(f, v, key)
            assert x.dtype == y.dtype and np.array_equal(x.view(np.uint8), y.view(np.uint8)), (f, key)


def test_killed_worker_resumes_to_the_same_dataset(video, tmp_path, monkeypatch, capsys):
    stage, reference = video
    out = tmp_path / "out"
    monkeypatch.setenv("LFUSD_TEST_KILL_AFTER_FRAME", "1")
    code, _, err = run_cli(capsys, "render-video", stage, "-o", out, "--samples", "2", "--quiet", "--device", "cpu", "--workers", "2")
    assert_one_line_error(code, err, "failed", "rerun the same command to resume")
    kept = sorted(p.name for p in (out / "main" / "f000001").iterdir() if p.is_dir())
    assert kept  # views of frame 1 were committed before the kill
    assert not (out / "main" / "f000003" / "00_00").exists()
    monkeypatch.delenv("LFUSD_TEST_KILL_AFTER_FRAME")
    code, _, err = run_cli(capsys, "render-video", stage, "-o", out, "--samples", "2", "--quiet", "--device", "cpu", "--workers", "2")
    assert code == 0, err
    assert_same_data(Dataset(out), Dataset(reference), (1, 3), ((0, 0), (2, 1)), ("depth", "instance", "flow_fwd", "scene_flow", "rgb"))


def test_full_disk_is_one_line_and_loses_nothing(video, tmp_path, monkeypatch, capsys):
    import lfusd.render.executors as ex

    stage, _ = video
    out = tmp_path / "out"
    real, calls = ex.commit_view, []

    def filling(*args, **kw):
        calls.append(args)
        if len(calls) > 4:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(*args, **kw)

    monkeypatch.setattr(ex, "commit_view", filling)
    code, _, err = run_cli(capsys, "render-video", stage, "-o", out, "--frames", "1-2", "--samples", "1", "--quiet", "--device", "cpu")
    assert_one_line_error(code, err, "No space left on device", "rerun")
    done = [p for p in (out / "main").glob("f*/??_??") if p.is_dir()]
    assert len(done) == 4
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["complete"] == {"main": []}  # 4 of 9 views of frame 1: no frame complete yet
    assert not list((out / "main").glob("f*/.*.tmp*"))
    monkeypatch.setattr(ex, "commit_view", real)
    code, _, err = run_cli(capsys, "render-video", stage, "-o", out, "--frames", "1-2", "--samples", "1", "--quiet", "--device", "cpu")
    assert code == 0, err
    assert len(Dataset(out).frames) == 2
    assert json.loads((out / "manifest.json").read_text())["complete"] == {"main": [1, 2]}


def test_render_video_bad_input(video, tmp_path, capsys):
    stage, out = video
    new = tmp_path / "new"
    code, _, err = run_cli(capsys, "render-video", stage, "-o", new, "--frames", "2-9")
    assert_one_line_error(code, err, "frame 4", "range 1-3")
    code, _, err = run_cli(capsys, "render-video", stage, "-o", new, "--frames", "3-2")
    assert_one_line_error(code, err, "--frames", "A-B")
    code, _, err = run_cli(capsys, "render-video", stage, "-o", new, "--workers", "0")
    assert_one_line_error(code, err, "--workers")
    code, _, err = run_cli(capsys, "render-video", stage, "-o", new, "--executor", "ray", "--ray-address", "127.0.0.1:1")
    assert_one_line_error(code, err, "cannot reach the Ray cluster at 127.0.0.1:1")
    code, _, err = run_cli(capsys, "render-video", stage, "-o", out, "--samples", "5", "--device", "cpu")
    assert_one_line_error(code, err, "holds a different dataset", "samples")
    assert not new.exists()
    assert json.loads((out / "manifest.json").read_text())["settings"]["samples"] == 2


def test_ray_executor_gives_the_same_arrays_as_local(video, tmp_path, capsys):
    stage, reference = video
    out = tmp_path / "ray"
    code, _, err = run_cli(capsys, "render-video", stage, "-o", out, "--samples", "2", "--quiet", "--device", "cpu", "--executor", "ray", "--workers", "2")
    assert code == 0, err
    a, b = Dataset(out), Dataset(reference)
    assert a.frames == b.frames
    assert_same_data(a, b, a.frames, a.views, ("depth", "instance", "flow_fwd", "flow_bwd", "scene_flow", "valid_fwd", "rgb"))
