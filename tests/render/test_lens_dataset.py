"""render-video --lens (issue 40 item 4): a dataset rendered through a Brown-Conrady lens has its image and
every ground-truth key in distorted pixel coordinates, checked against OpenCV's projectPoints on the pixel
grid, the disparity against the neighbouring view's own projection, and lfusd verify (traced through the
model) passes, yet fails on one planted wrong pixel."""

from __future__ import annotations

import shutil

import cv2
import numpy as np
import pytest
from support.distortion_stage import LENS, RIG, write_distortion_stage

from lfusd import Dataset
from lfusd.camera import pixel_grid

pytestmark = pytest.mark.render

LENS_ARG = ",".join(repr(float(c)) for c in LENS.coeffs)


@pytest.fixture(scope="module")
def lens_video(tmp_path_factory):
    from lfusd.cli import main

    root = tmp_path_factory.mktemp("distortion")
    write_distortion_stage(root / "d.usda")
    # --verify: exit 0 only when lfusd verify, tracing through the lens, passes at its usual limits
    assert main(["render-video", str(root / "d.usda"), "-o", str(root / "out"), "--quiet", "--device", "cpu", "--light", "none",
                 "--samples", "1", "--keep-raw", "--lens", LENS_ARG, "--verify"]) == 0
    return root / "out"


def _opencv(points: np.ndarray, cam) -> np.ndarray:
    """cv2.projectPoints of world points (H, W, 3) in ``cam`` (its K, pose and lens): (H, W, 2)."""
    R, C = cam.world_to_cam()
    rvec, _ = cv2.Rodrigues(R)
    uv, _ = cv2.projectPoints(np.nan_to_num(points).reshape(-1, 1, 3).astype(np.float64), rvec, -R @ C,
                              np.asarray(cam.K, np.float64), cam.dist.coeffs)
    return uv.reshape(*points.shape[:-1], 2)


def test_the_manifest_records_each_views_lens_and_the_cameras_carry_it(lens_video):
    ds = Dataset(lens_video)
    assert ds.distorted and ds.record.settings.get("lens")["model"] == LENS.to_dict()
    for view in ds.views:
        assert ds.distortion(view) == LENS and ds.camera(1, view).dist == LENS


def test_positions_depths_and_flow_match_opencv_projectpoints_on_the_grid(lens_video):
    ds = Dataset(lens_video)
    u, v = pixel_grid(RIG.height, RIG.width, np.float64)
    grid = np.stack([u, v], -1)
    for view in ds.views:
        for frame in (1, 2):
            cam, cam1 = ds.camera(frame, view), ds.camera(frame + 1, view)
            position = ds.read(frame, view, "position").astype(np.float64)
            surface = np.isfinite(position).all(-1)
            assert surface.all()  # the stage fills every pixel of the distorted image
            assert np.abs(_opencv(position, cam) - grid).max() < 0.01  # each pixel's point is imaged at the pixel
            R, C = cam.world_to_cam()
            np.testing.assert_allclose(ds.read(frame, view, "depth"), (position - C) @ R[2], rtol=1e-5)  # planar, not the ray length
            np.testing.assert_allclose(ds.read(frame, view, "depth_euclidean"), np.linalg.norm(position - C, axis=-1), rtol=1e-5)
            raw = ds._raw(str(ds.view_dir(frame, view)))  # the very point sampled and where it is at t+1 (Blender's AOVs)
            want = _opencv(raw["next_position"].astype(np.float64), cam1) - _opencv(raw["position"].astype(np.float64), cam)
            valid = ds.read(frame, view, "valid_fwd")
            assert valid.sum() > 0.9 * valid.size
            err = np.linalg.norm(ds.read(frame, view, "flow_fwd") - want, axis=-1)[valid]
            assert err.max() < 0.01, err.max()
            moving = np.linalg.norm(want, axis=-1)[valid] > 0.5
            assert moving.sum() > 20  # the box moves: the check is not all zeros


def test_disparity_is_the_horizontal_correspondence_to_the_neighbouring_view(lens_video):
    ds = Dataset(lens_video)
    left, right = (0, 0), (0, 1)  # the right view sits one baseline along the left one's x axis, with the same lens
    u, _ = pixel_grid(RIG.height, RIG.width, np.float64)
    position = ds.read(1, left, "position").astype(np.float64)
    u_right = _opencv(position, ds.camera(1, right))[..., 0]
    d = ds.read(1, left, "disparity")
    ok = np.isfinite(d)
    assert ok.mean() > 0.9
    np.testing.assert_allclose(d[ok], (u - u_right)[ok], atol=0.01)
    # not the pinhole's f b / z: the lens changes it by far more than the tolerance across the image
    pinhole = RIG.focal_px * RIG.baseline / ds.read(1, left, "depth")
    assert np.abs(d[ok] - pinhole[ok]).max() > 0.1


def test_one_planted_wrong_pixel_fails_verify_through_the_lens(lens_video, tmp_path, capsys):
    from lfusd.cli import main
    from lfusd.data import integrity, store

    out = tmp_path / "out"
    shutil.copytree(lens_video, out)
    ds = Dataset(out)
    view, frame = (0, 1), 2
    valid = ds.read(frame, view, "valid_fwd")
    vy, vx = np.argwhere(valid)[len(np.argwhere(valid)) // 2]
    d = ds.view_dir(frame, view)
    arrays = store.read(d / "motion.exr")
    arrays["flow_fwd"][vy, vx] += np.float32(0.2)
    store.write(d / "motion.exr", arrays)
    rec = integrity.read_record(d)
    integrity.record_files(d, add={"motion.exr": {k: v for k, v in rec["files"]["motion.exr"].items() if k not in ("size", "sha256")}})
    assert main(["verify", str(out)]) == 1
    fails = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("FAIL")]
    assert any(ln.startswith("FAIL flow_fwd") and f"frame {frame} view 0,1 pixel (u={vx}, v={vy})" in ln for ln in fails), fails


def test_exports_carry_each_views_lens_or_refuse_in_one_line(lens_video, tmp_path, capsys):
    import h5py

    from lfusd.cli import main
    from lfusd.data.shards import ShardDataset
    from lfusd.exports import export

    ds = Dataset(lens_video)
    export(ds, "webdataset", tmp_path / "wds")
    shards = ShardDataset(tmp_path / "wds")
    assert shards.distorted
    for view in ds.views:
        assert shards.distortion(view) == LENS and shards.camera(1, view).dist == LENS
        # keys computed on read from the exported depth go through the lens as the dataset's do
        for key in ("disparity", "depth_euclidean"):
            np.testing.assert_array_equal(shards.read(1, view, key), ds.read(1, view, key))
    (h5,) = export(ds, "lfmat", tmp_path / "lf", frame=1)
    with h5py.File(h5) as f:
        np.testing.assert_array_equal(f.attrs["distortion"], np.broadcast_to(LENS.coeffs, (1, 2, 5)))
    for fmt in ("hci", "kitti", "spring"):  # pinhole formats: no lens model to carry
        assert main(["export", fmt, str(lens_video), str(tmp_path / fmt)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "lens distortion" in err[0] and "webdataset" in err[0], err
        assert not (tmp_path / fmt).exists()


def test_the_certificate_names_the_lens(lens_video):
    from lfusd.data.certificate import certified

    cert = certified(lens_video, "main")["main"]
    assert cert["ok"] and cert["camera_effects"] == {"lens_distortion": {"model": LENS.to_dict(), "seed": None, "spread": 0.0}}


def test_preview_and_view_show_the_lens(lens_video, tmp_path):
    from evaluation.test_view import read_rrd

    from lfusd.cli import main
    from lfusd.data.formats import read_png
    from lfusd.evaluation.preview import lens_shift
    from lfusd.evaluation.view import entity

    ds = Dataset(lens_video)
    shift = lens_shift(ds, (0, 0))
    K = np.asarray(ds.intrinsics((0, 0)), np.float64)
    u, v = pixel_grid(RIG.height, RIG.width, np.float64)
    pts = np.stack([u, v], -1).reshape(-1, 1, 2)
    # OpenCV's undistortion, to convergence: the pinhole pixel of each distorted pixel's ray
    und = cv2.undistortPointsIter(pts, K, LENS.coeffs, None, K, (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12))
    np.testing.assert_allclose(shift, np.linalg.norm(und.reshape(RIG.height, RIG.width, 2) - np.stack([u, v], -1), axis=-1), atol=1e-6)
    assert shift[0, 0] > 1.0  # barrel: the corner's ray lies pixels out
    assert main(["preview", str(lens_video), "-o", str(tmp_path / "p"), "--no-video"]) == 0
    assert read_png(tmp_path / "p" / "lens_0001.png").shape == (RIG.height, RIG.width, 3)
    assert main(["view", str(lens_video), "--save", str(tmp_path / "v.rrd")]) == 0
    rec = read_rrd(tmp_path / "v.rrd")
    assert any(e == entity("main", tuple(ds.rig.centre_view), "lens") for e, _ in rec)


def test_torch_items_carry_each_views_lens(lens_video):
    from lfusd.torch import LightFieldVideoDataset

    item = LightFieldVideoDataset(lens_video, keys=("rgb", "disparity"), crop=(20, 30))[0]
    np.testing.assert_array_equal(item["distortion"].numpy(), np.stack([LENS.coeffs] * 2))
    # the cropped K with the same coefficients images each pixel's point where the crop shows it
    ds = Dataset(lens_video)
    K = item["intrinsics"][0].numpy()
    top, left = (int(x) for x in item["crop"])
    position = ds.read(1, (0, 0), "position")[top:top + 20, left:left + 30].astype(np.float64)
    from lfusd.camera import Camera

    uv = _opencv(position, Camera(K, ds.cam_to_world(1, (0, 0)), LENS))
    u, v = pixel_grid(20, 30, np.float64)
    assert np.abs(uv - np.stack([u, v], -1)).max() < 0.01


def _one_line_refusal(err: str, root) -> None:
    lines = str(err).strip().splitlines()
    assert len(lines) == 1 and str(root) in lines[0] and "lens distortion" in lines[0] and "needs a pinhole dataset" in lines[0], lines


def test_pinhole_only_consumers_refuse_the_distorted_dataset_in_one_line(lens_video, tmp_path, capsys):
    """The baselines, the rig study, the bench, eval's kitti protocol and the flow/ scripts compute with K
    alone or match along image rows: each refuses
    a dataset rendered through a lens (lfusd.data.folder.require_pinhole) before computing anything."""
    from support.flow_scripts import load_script

    from lfusd import layout
    from lfusd.bench.make import cameras
    from lfusd.bench.score import _test_scenes
    from lfusd.errors import LfusdError
    from lfusd.evaluation.baselines import run_baselines
    from lfusd.evaluation.score import evaluate
    from lfusd.study.run import load_views

    ds = Dataset(lens_video)
    (tmp_path / "pred").mkdir()
    for call in (lambda: run_baselines(ds), lambda: load_views(lens_video, "main", 1, {"0_0": 0, "0_1": 1}),
                 lambda: cameras(ds), lambda: evaluate(lens_video, tmp_path / "pred", "disparity", protocol="kitti")):
        with pytest.raises(LfusdError) as e:
            call()
        _one_line_refusal(e.value, lens_video)
    (tmp_path / "bench" / layout.BENCH_GT).mkdir(parents=True)  # a bench whose test scene is the distorted dataset
    (tmp_path / "bench" / layout.BENCH_GT / "s").symlink_to(lens_video)
    with pytest.raises(LfusdError) as e:
        next(_test_scenes(tmp_path / "bench", {"splits": {"test": ["s"]}}))
    assert "needs a pinhole dataset" in str(e.value)
    # flow/: the predictions (through their one-line error wrapper) and the training scripts
    for name, args in (("predict_disparity", [lens_video, "-o", tmp_path / "d.pfm"]),
                       ("train_sceneflow", ["--data", lens_video, "--out", tmp_path / "run"])):
        script = load_script(name)
        assert script.training.main_wrapper(script.NAME, script.main, [str(a) for a in args]) == 2
        _one_line_refusal(capsys.readouterr().err, lens_video)
    assert not (tmp_path / "d.pfm").exists() and not (tmp_path / "run").exists()
    for call in (lambda: load_script("predict_views").read_dataset_corners(lens_video, 3, None, None),
                 lambda: load_script("predict_sceneflow").predict_dataset(None, {}, lens_video, tmp_path / "sf")):
        with pytest.raises(LfusdError) as e:
            call()
        _one_line_refusal(e.value, lens_video)
    assert not (tmp_path / "sf").exists()
