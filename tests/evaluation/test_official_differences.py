"""The six differences from official benchmark code of issue 27, each against a definition written
here from that code: DistgASR's cal_metrics_RE (22-px crop, population covariance), no Y clipping
in BasicLFSR / DistgASR, Spring's float16 storage, KITTI's obj_map and noc masks (devkit
evaluate_scene_flow.cpp, devkit readme) and DistgDisp's reading of valid_mask.png."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from support.fake import FakeDataset
from support.spec_readers import read_png_spec

from lfusd import LfusdError
from lfusd import exports as export
from lfusd.truth import visibility
from lfusd.evaluation import protocols
from lfusd.evaluation.score import dataset_truth


def y_matlab(rgb01):
    """MATLAB rgb2ycbcr's Y of RGB in [0, 1], as is (no clipping)."""
    return (16 + 65.481 * rgb01[..., 0] + 128.553 * rgb01[..., 1] + 24.966 * rgb01[..., 2]) / 255


def skimage019_ssim(im1, im2, sigma=1.5, use_sample_covariance=True, data_range=2.0):
    """skimage 0.19 structural_similarity(gaussian_weights=True) on float images: scipy's
    gaussian_filter (truncate 3.5), data_range the float dtype's 2 by default, crop (win-1)//2."""
    im1, im2 = im1.astype(np.float64), im2.astype(np.float64)
    win = 2 * int(3.5 * sigma + 0.5) + 1
    cov_norm = win**2 / (win**2 - 1) if use_sample_covariance else 1.0
    f = lambda x: gaussian_filter(x, sigma=sigma, truncate=3.5)  # noqa: E731
    ux, uy = f(im1), f(im2)
    vx, vy, vxy = cov_norm * (f(im1 * im1) - ux * ux), cov_norm * (f(im2 * im2) - uy * uy), cov_norm * (f(im1 * im2) - ux * uy)
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    s = ((2 * ux * uy + c1) * (2 * vxy + c2)) / ((ux**2 + uy**2 + c1) * (vx + vy + c2))
    pad = (win - 1) // 2
    return float(s[pad:-pad, pad:-pad].mean())


def skimage_psnr(true, test):
    """peak_signal_noise_ratio without data_range: 1 for a non-negative float truth, else 2."""
    dr = 1.0 if true.min() >= 0 else 2.0
    return 10 * math.log10(dr**2 / np.mean((true.astype(np.float64) - test.astype(np.float64)) ** 2))


@pytest.fixture(scope="module")
def views():
    rng = np.random.default_rng(27)
    g = rng.random((70, 75, 3))
    p = g + rng.normal(0, 0.08, g.shape)  # a float prediction, partly outside [0, 1]
    p[:8] = 1.3  # the top rows far above 1 (inside DistgASR's crop: they must not count there)
    p[30:34, 30:40] = -0.2
    return p, g


def test_distgasr_crops_22px_and_uses_population_covariance(views):
    p, g = views
    res, _ = protocols.score("distgasr", "views", p, {"rgb": g})
    bd = 22  # cal_metrics_RE: img[u, v, bd:-bd, bd:-bd]
    yg, yp = y_matlab(g)[bd:-bd, bd:-bd], y_matlab(p)[bd:-bd, bd:-bd]
    assert res["psnr_db"] == pytest.approx(skimage_psnr(yg, yp), abs=1e-9)
    assert res["ssim_range2"] == pytest.approx(skimage019_ssim(yg, yp, sigma=1.5, use_sample_covariance=False), abs=1e-12)
    assert res["pixels"] == (70 - 44) * (75 - 44)
    # it is a protocol of its own: BasicLFSR's numbers (whole image, sample covariance) differ
    b, _ = protocols.score("basiclfsr", "views", p, {"rgb": g})
    assert abs(b["psnr_db"] - res["psnr_db"]) > 0.1 and abs(b["ssim_range2"] - res["ssim_range2"]) > 1e-4
    with pytest.raises(LfusdError, match="22-px border"):
        protocols.score("distgasr", "views", p[:50, :50], {"rgb": g[:50, :50]})


def test_basiclfsr_and_distgasr_do_not_clip_y(views):
    p, g = views
    yg, yp = y_matlab(g), y_matlab(p)
    assert yp.max() > 1 and yp.min() < 0  # the case at stake
    res, _ = protocols.score("basiclfsr", "views", p, {"rgb": g})
    # BasicLFSR cal_metrics: peak_signal_noise_ratio(label_y, out_y), structural_similarity(..., gaussian_weights=True)
    assert res["psnr_db"] == pytest.approx(skimage_psnr(yg, yp), abs=1e-9)
    assert res["ssim_range2"] == pytest.approx(skimage019_ssim(yg, yp), abs=1e-12)
    assert abs(res["psnr_db"] - skimage_psnr(yg, np.clip(yp, 0, 1))) > 0.1  # clipping would change it


def test_spring_rounds_ground_truth_and_submission_to_float16():
    # flow 100.3 px, prediction 1.0005 px away: float32 says > 1 px; float16 (spacing 1/16 at 100)
    # stores 100.3125 and 101.3125, exactly 1 px apart, which is not > 1 (evaluation.py: epe > 1)
    gt = np.zeros((2, 3, 2), np.float32)
    gt[..., 0] = 100.3
    pred = gt.copy()
    pred[..., 0] += 1.0005
    truth = {"flow": gt, "valid": np.ones((2, 3), bool)}
    res, _ = protocols.score("spring", "flow", pred, truth)
    g16, p16 = gt.astype(np.float16), pred.astype(np.float16)
    epe = np.linalg.norm((g16 - p16).astype(np.float64), axis=-1)  # get_errors_flow
    assert res["epe_gt_1px_pct"] == pytest.approx(100 * np.mean(epe > 1)) == 0.0
    assert np.all(np.linalg.norm(pred.astype(np.float64) - gt, axis=-1) > 1)  # float32/64 would count every pixel
    assert res["epe_px"] == pytest.approx(float(epe.mean()), abs=1e-12)
    # disparity: float16 storage, differences in float32 (get_errors_stereo)
    d = np.full((2, 3), 60.03, np.float32)
    dp = d + np.float32(1.01)
    res, _ = protocols.score("spring", "disparity", dp, {"disparity": d})
    e = np.abs(d.astype(np.float16).astype(np.float32) - dp.astype(np.float16).astype(np.float32)).astype(np.float64)
    assert res["abs_px"] == pytest.approx(float(e.mean()), abs=1e-12)
    assert res["epe_gt_1px_pct"] == pytest.approx(100 * np.mean(e > 1))


@pytest.fixture(scope="module")
def fake():
    return FakeDataset(root="/data/fakescene", rows=3, cols=3, width=24, height=20, frames=(1, 2, 3))


class StillPosedFake(FakeDataset):
    """The box keeps one pose but its surface moves (as a skinned body under a fixed prim)."""

    def __init__(self, **kw):
        super().__init__(**kw)
        box = self.objects[2]
        box.poses = {t: box.poses[self.frames[0]] for t in self.frames}


def test_kitti_obj_map_marks_moving_objects_foreground(fake, tmp_path):
    tr = export.kitti.export_kitti(fake, tmp_path / "kitti")
    c = fake.rig.centre_view
    for i, t in enumerate((1, 2)):
        om = read_png_spec(tr / "obj_map" / f"{i:06d}_10.png")
        assert om.dtype == np.uint8 and om.ndim == 2  # the devkit's 8-bit IntegerImage
        inst = fake.read(t, c, "instance")
        # devkit: O_map 0 = background, > 0 = foreground; the box (id 2) moves, the wall (id 1) does not
        np.testing.assert_array_equal(om > 0, inst == 2)
        assert (om > 0).any() and (om == 0).any()
    still = StillPosedFake(root="/data/still", rows=3, cols=3, width=24, height=20, frames=(1, 2))
    om = export.kitti.kitti_object_map(still, 1, c)
    np.testing.assert_array_equal(om > 0, still.read(1, c, "instance") == 2)


def readme_noc(d0, d1, flow, occ0, occ1, w, h):
    """KITTI devkit readme: 'noc' = pixels whose matching correspondence is inside the image domain."""
    noc0, noc1 = np.zeros_like(occ0), np.zeros_like(occ1)
    for v in range(h):
        for u in range(w):
            inside = lambda x, y: -0.5 <= x < w - 0.5 and -0.5 <= y < h - 0.5  # noqa: E731
            noc0[v, u] = occ0[v, u] and inside(u - d0[v, u], v)
            if occ1[v, u]:
                x1, y1 = u + flow[v, u, 0], v + flow[v, u, 1]
                noc1[v, u] = inside(x1, y1) and inside(x1 - d1[v, u], y1)
    return noc0, noc1


def test_kitti_noc_is_the_readme_definition_in_export_and_dataset_mode(tmp_path):
    # a wide baseline: disparities of 4-8 px, so correspondences leave the image and the box hides wall in the right view
    ds = FakeDataset(root="/data/wide", rows=1, cols=3, width=32, height=20, frames=(1, 2), baseline=0.3)
    tr = export.kitti.export_kitti(ds, tmp_path / "kitti")
    c = ds.rig.centre_view
    d0 = ds.read(1, c, "disparity").astype(np.float64)
    d1 = d0 + ds.read(1, c, "disparity_change")
    flow = ds.read(1, c, "flow_fwd").astype(np.float64)
    occ0 = np.isfinite(d0) & (d0 > 0)
    occ1 = occ0 & ds.read(1, c, "valid_fwd") & (d1 > 0)
    noc0, noc1 = readme_noc(d0, d1, flow, occ0, occ1, 32, 20)
    got0 = read_png_spec(tr / "disp_noc_0" / "000000_10.png") > 0
    got1 = read_png_spec(tr / "disp_noc_1" / "000000_10.png") > 0
    np.testing.assert_array_equal(got0, noc0)
    np.testing.assert_array_equal(got1, noc1)
    assert 0 < noc0.sum() < occ0.sum()
    # pixels occluded in the right view but landing inside it are noc: more than the visibility test keeps
    visible = visibility.stereo_visible(ds, 1, c, (c[0], c[1] + 1)) & occ0
    assert noc0.sum() > visible.sum()
    # dataset mode (`lfusd eval --gt OUT --protocol kitti`) uses the same masks
    k = protocols.kitti_masks(dataset_truth(ds, 1, c, "sceneflow"))
    np.testing.assert_array_equal(k["disp0_noc"], got0)
    np.testing.assert_array_equal(k["disp1_noc"], got1)


def test_hci_valid_mask_has_three_channels_for_distgdisp(fake, tmp_path):
    sd = export.hci.export_hci(fake, tmp_path / "hci", frame=1)[0]
    mask_rgb = read_png_spec(sd / "valid_mask.png")
    assert mask_rgb.shape == (20, 24, 3)
    # DistgDisp utils.py: dispGT[:, :, 1] = np.float32(mask_rgb[:, :, 1] > 0)
    centre = export.hci.hci_centre_view(fake)
    np.testing.assert_array_equal(mask_rgb[:, :, 1] > 0, np.isfinite(fake.read(1, centre, "depth")))
    assert np.all(mask_rgb[..., 0] == mask_rgb[..., 2])
