"""Metrics against independent, literal formulas (plain Python loops) on random arrays, and the
PyTorch versions against the NumPy ones."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lfusd import LfusdError
from lfusd.evaluation import metrics
from lfusd.evaluation import metrics_torch as mt

RNG = np.random.default_rng(7)


def _pct(flags):
    flags = list(flags)
    return 100.0 * sum(1 for f in flags if f) / len(flags)


def _quantile_linear(values, q):
    s = sorted(values)
    pos = q * (len(s) - 1)
    lo = math.floor(pos)
    hi = min(lo + 1, len(s) - 1)
    return s[lo] + (pos - lo) * (s[hi] - s[lo])


def test_disparity_matches_literal_hci_formulas():
    gt = RNG.uniform(-2, 2, (13, 17))
    pred = gt + RNG.normal(0, 0.04, gt.shape)
    mask = RNG.random(gt.shape) > 0.3
    gt[0, 0] = np.inf  # no surface: left out even where the mask is true
    mask[0, 0] = True
    res = metrics.disparity(pred, gt, mask)
    errs = [abs(pred[i, j] - gt[i, j]) for i in range(13) for j in range(17) if mask[i, j] and math.isfinite(gt[i, j])]
    assert res["mse_x100"] == pytest.approx(100 * sum(e * e for e in errs) / len(errs), rel=1e-12)
    for t in (0.01, 0.03, 0.07):
        assert res[f"badpix_{t}_pct"] == pytest.approx(_pct(e > t for e in errs), rel=1e-12)
    assert res["q25_x100"] == pytest.approx(100 * _quantile_linear(errs, 0.25), rel=1e-12)
    # badpix rates actually move with the noise (the test can fail)
    assert 0 < res["badpix_0.07_pct"] < res["badpix_0.03_pct"] < res["badpix_0.01_pct"] < 100


def test_disparity_no_mask_uses_every_pixel_no_border():
    gt = np.zeros((20, 20))
    pred = np.zeros((20, 20))
    pred[0, :] = 1.0  # errors only on the border row: an implicit border would hide them
    res = metrics.disparity(pred, gt)
    assert res["badpix_0.07_pct"] == pytest.approx(5.0)
    assert res["mse_x100"] == pytest.approx(100 * 20 / 400)


def test_optical_flow_matches_literal_formulas():
    gt = RNG.normal(0, 20, (11, 9, 2))
    pred = gt + RNG.normal(0, 2.5, gt.shape)
    valid = RNG.random((11, 9)) > 0.2
    res = metrics.optical_flow(pred, gt, valid)
    epe, fl, one = [], [], []
    for i in range(11):
        for j in range(9):
            if not valid[i, j]:
                continue
            e = math.hypot(pred[i, j, 0] - gt[i, j, 0], pred[i, j, 1] - gt[i, j, 1])
            mag = math.hypot(gt[i, j, 0], gt[i, j, 1])
            epe.append(e)
            fl.append(e > 3 and e / mag > 0.05)
            one.append(e > 1)
    assert res["epe_px"] == pytest.approx(sum(epe) / len(epe), rel=1e-12)
    assert res["fl_all_pct"] == pytest.approx(_pct(fl), rel=1e-12)
    assert res["epe_gt_1px_pct"] == pytest.approx(_pct(one), rel=1e-12)
    assert 0 < res["fl_all_pct"] < res["epe_gt_1px_pct"] < 100


def test_scene_flow_matches_literal_formulas():
    gt = RNG.normal(0, 0.5, (300, 3))
    pred = gt + RNG.normal(0, 0.08, gt.shape)
    res = metrics.scene_flow(pred, gt, None)
    e = [math.dist(p, g) for p, g in zip(pred, gt)]
    rel = [ei / (math.sqrt(sum(x * x for x in g)) + 1e-4) for ei, g in zip(e, gt)]
    assert res["epe3d_m"] == pytest.approx(sum(e) / len(e), rel=1e-12)
    assert res["acc3d_strict_pct"] == pytest.approx(_pct(a < 0.05 or r < 0.05 for a, r in zip(e, rel)), rel=1e-12)
    assert res["acc3d_relax_pct"] == pytest.approx(_pct(a < 0.1 or r < 0.1 for a, r in zip(e, rel)), rel=1e-12)
    assert res["outlier3d_pct"] == pytest.approx(_pct(a > 0.3 or r > 0.1 for a, r in zip(e, rel)), rel=1e-12)
    assert 0 < res["acc3d_strict_pct"] < res["acc3d_relax_pct"] < 100


def test_kitti_outliers_match_literal_formulas():
    h, w = 10, 12
    d1g = RNG.uniform(5, 80, (h, w))
    d2g = d1g + RNG.normal(0, 2, (h, w))
    fg = RNG.normal(0, 30, (h, w, 2))
    d1p = d1g + RNG.normal(0, 4, (h, w))
    d2p = d2g + RNG.normal(0, 4, (h, w))
    fp = fg + RNG.normal(0, 3, (h, w, 2))
    valid = RNG.random((h, w)) > 0.25
    res = metrics.kitti_outliers(d1p, d1g, d2p, d2g, fp, fg, valid)
    o1, o2, of, osf = [], [], [], []
    for i in range(h):
        for j in range(w):
            if not valid[i, j]:
                continue
            a = abs(d1p[i, j] - d1g[i, j]) > 3 and abs(d1p[i, j] - d1g[i, j]) > 0.05 * abs(d1g[i, j])
            b = abs(d2p[i, j] - d2g[i, j]) > 3 and abs(d2p[i, j] - d2g[i, j]) > 0.05 * abs(d2g[i, j])
            e = math.hypot(*(fp[i, j] - fg[i, j]))
            c = e > 3 and e > 0.05 * math.hypot(*fg[i, j])
            o1.append(a), o2.append(b), of.append(c), osf.append(a or b or c)
    assert res == pytest.approx({"d1_pct": _pct(o1), "d2_pct": _pct(o2), "fl_pct": _pct(of), "sf_pct": _pct(osf)}, rel=1e-12)
    assert 0 < res["d1_pct"] < res["sf_pct"] < 100


def test_luma_is_matlab_rgb2ycbcr():
    assert metrics.rgb_to_y(np.zeros(3)) == pytest.approx(16 / 255)
    assert metrics.rgb_to_y(np.ones(3)) == pytest.approx(235 / 255, abs=1e-12)
    # MATLAB: rgb2ycbcr(uint8([255 0 0])) gives Y = 81 (16 + 65.481 rounded)
    assert round(255 * metrics.rgb_to_y(np.array([1.0, 0, 0]))) == 81
    assert round(255 * metrics.rgb_to_y(np.array([0, 1.0, 0]))) == 145
    assert round(255 * metrics.rgb_to_y(np.array([0, 0, 1.0]))) == 41


def _ssim_literal(a, b):
    """Wang et al.'s SSIM written window by window with explicit sums."""
    k, sigma = 11, 1.5
    g = [[math.exp(-((x - 5) ** 2 + (y - 5) ** 2) / (2 * sigma**2)) for x in range(k)] for y in range(k)]
    tot = sum(map(sum, g))
    g = [[v / tot for v in row] for row in g]
    c1, c2 = 0.01**2, 0.03**2
    vals = []
    for i in range(a.shape[0] - k + 1):
        for j in range(a.shape[1] - k + 1):
            pa = a[i : i + k, j : j + k]
            pb = b[i : i + k, j : j + k]
            ma = sum(g[y][x] * pa[y, x] for y in range(k) for x in range(k))
            mb = sum(g[y][x] * pb[y, x] for y in range(k) for x in range(k))
            va = sum(g[y][x] * (pa[y, x] - ma) ** 2 for y in range(k) for x in range(k))
            vb = sum(g[y][x] * (pb[y, x] - mb) ** 2 for y in range(k) for x in range(k))
            cab = sum(g[y][x] * (pa[y, x] - ma) * (pb[y, x] - mb) for y in range(k) for x in range(k))
            vals.append((2 * ma * mb + c1) * (2 * cab + c2) / ((ma * ma + mb * mb + c1) * (va + vb + c2)))
    return sum(vals) / len(vals)


def test_ssim_and_psnr_match_literal_formulas():
    rgb_gt = RNG.random((14, 15, 3))
    rgb_pred = np.clip(rgb_gt + RNG.normal(0, 0.1, rgb_gt.shape), 0, 1)
    res = metrics.view_synthesis(rgb_pred, rgb_gt)
    yp = (16 + 65.481 * rgb_pred[..., 0] + 128.553 * rgb_pred[..., 1] + 24.966 * rgb_pred[..., 2]) / 255
    yg = (16 + 65.481 * rgb_gt[..., 0] + 128.553 * rgb_gt[..., 1] + 24.966 * rgb_gt[..., 2]) / 255
    mse = sum((p - g) ** 2 for p, g in zip(yp.ravel(), yg.ravel())) / yp.size
    assert res["psnr_db"] == pytest.approx(10 * math.log10(1 / mse), rel=1e-12)
    assert res["ssim"] == pytest.approx(_ssim_literal(yp, yg), rel=1e-10)
    assert 0.2 < res["ssim"] < 0.99
    same = metrics.view_synthesis(rgb_gt, rgb_gt)
    assert same["ssim"] == pytest.approx(1.0) and same["psnr_db"] == math.inf


def test_uint8_views_are_scaled_to_unit_range():
    a = RNG.integers(0, 256, (16, 16, 3), dtype=np.uint8)
    b = RNG.integers(0, 256, (16, 16, 3), dtype=np.uint8)
    assert metrics.view_synthesis(a, b) == pytest.approx(metrics.view_synthesis(a / 255.0, b / 255.0))


@pytest.mark.parametrize("fn, shape", [(metrics.disparity, (4, 5)), (metrics.optical_flow, (4, 5, 2)), (metrics.scene_flow, (4, 5, 3))])
def test_wrong_prediction_shape_is_one_line_error(fn, shape):
    gt = np.zeros(shape)
    with pytest.raises(LfusdError) as e:
        fn(np.zeros((3,) + shape[1:]), gt, None)
    assert "\n" not in str(e.value) and "shape" in str(e.value)


def test_wrong_mask_shape_is_error():
    with pytest.raises(LfusdError):
        metrics.disparity(np.zeros((4, 5)), np.zeros((4, 5)), np.ones((5, 4), bool))


# ---- PyTorch agrees with NumPy ---------------------------------------------------------------


def _agree(np_dicts, t_dict):
    for b, ref in enumerate(np_dicts):
        for k, v in ref.items():
            got = float(t_dict[k][b])
            if math.isinf(v):
                assert math.isinf(got), k
            else:
                assert abs(got - v) <= 1e-5 * max(1.0, abs(v)), (k, b, got, v)


def test_torch_disparity_agrees_with_numpy():
    gt = RNG.uniform(-2, 2, (3, 12, 10)).astype(np.float32)
    pred = (gt + RNG.normal(0, 0.05, gt.shape)).astype(np.float32)
    mask = RNG.random(gt.shape) > 0.3
    mask[2] = False  # an empty item gives NaN in both
    t = mt.disparity(torch.from_numpy(pred), torch.from_numpy(gt), torch.from_numpy(mask))
    _agree([metrics.disparity(pred[b], gt[b], mask[b]) for b in range(2)], t)
    assert all(math.isnan(float(v[2])) for v in t.values())
    assert math.isnan(metrics.disparity(pred[2], gt[2], mask[2])["q25_x100"])


def test_torch_flows_agree_with_numpy():
    gt = RNG.normal(0, 10, (2, 9, 8, 2))
    pred = gt + RNG.normal(0, 2, gt.shape)
    valid = RNG.random(gt.shape[:-1]) > 0.2
    _agree([metrics.optical_flow(pred[b], gt[b], valid[b]) for b in range(2)], mt.optical_flow(pred, gt, valid))
    gt3 = RNG.normal(0, 0.5, (2, 9, 8, 3))
    pred3 = gt3 + RNG.normal(0, 0.1, gt3.shape)
    _agree([metrics.scene_flow(pred3[b], gt3[b], valid[b]) for b in range(2)], mt.scene_flow(pred3, gt3, valid))
    d1g = RNG.uniform(5, 50, (2, 9, 8))
    d2g = d1g + 1
    args = (d1g + RNG.normal(0, 4, d1g.shape), d1g, d2g + RNG.normal(0, 4, d1g.shape), d2g, pred * 3, gt * 3)
    _agree([metrics.kitti_outliers(*(a[b] for a in args), valid[b]) for b in range(2)], mt.kitti_outliers(*args, valid))
    # scene_flow with kitti= merges both sets of keys, in NumPy and PyTorch alike
    gt3b = gt3 * 1.0
    both = [metrics.scene_flow(pred3[b], gt3b[b], valid[b], kitti=tuple(a[b] for a in args)) for b in range(2)]
    assert set(both[0]) == {"epe3d_m", "acc3d_strict_pct", "acc3d_relax_pct", "outlier3d_pct", "d1_pct", "d2_pct", "fl_pct", "sf_pct"}
    assert both[0]["d1_pct"] == metrics.kitti_outliers(*(a[0] for a in args), valid[0])["d1_pct"]
    _agree(both, mt.scene_flow(pred3, gt3b, valid, kitti=args))


def test_torch_view_synthesis_agrees_with_numpy():
    gt = RNG.random((2, 16, 13, 3))
    pred = np.clip(gt + RNG.normal(0, 0.05, gt.shape), 0, 1)
    _agree([metrics.view_synthesis(pred[b], gt[b]) for b in range(2)], mt.view_synthesis(pred, gt))


def test_torch_wrong_shape_is_error():
    with pytest.raises(LfusdError):
        mt.disparity(torch.zeros(1, 4, 5), torch.zeros(1, 4, 6))


# ---- `lfusd eval` on the analytic fake dataset ------------------------------------------------


@pytest.fixture()
def fake_cli(monkeypatch):
    """Route the CLI's dataset opening to the analytic fake (the reader is tested elsewhere)."""
    from support.fake import FakeDataset

    import lfusd.data.dataset

    ds = FakeDataset(root="/data/fake", rows=3, cols=3, width=24, height=20, frames=(1, 2, 3))
    monkeypatch.setattr(lfusd.data.dataset, "open_dataset", lambda path, rig=None: ds)
    return ds


def test_eval_disparity_cli_writes_table_json_csv(fake_cli, tmp_path, capsys):
    import csv
    import json

    from lfusd.data import formats
    from lfusd.cli import main

    ds = fake_cli
    pred = tmp_path / "pred"
    pred.mkdir()
    gt = ds.read(2, (1, 1), "disparity")
    noisy = gt + 0.05
    formats.write_pfm(pred / "0002_01_01.pfm", noisy)
    np.save(pred / "0001_00_02.npy", ds.read(1, (0, 2), "disparity"))
    assert main(["eval", "--task", "disparity", "--pred", str(pred), "--gt", "/data/fake"]) == 0
    out = capsys.readouterr().out
    assert "mse_x100" in out and "summary" in out
    res = json.loads((pred / "eval_disparity.json").read_text())
    rows = {(r["frame"], r["row"], r["col"]): r for r in res["rows"]}
    assert rows[(2, 1, 1)]["mse_x100"] == pytest.approx(100 * 0.05**2, rel=1e-4)
    assert rows[(2, 1, 1)]["badpix_0.03_pct"] == pytest.approx(100.0) and rows[(2, 1, 1)]["badpix_0.07_pct"] == 0.0
    assert rows[(1, 0, 2)]["mse_x100"] == 0.0
    with open(pred / "eval_disparity.csv") as f:
        lines = list(csv.DictReader(f))
    assert [line["frame"] for line in lines] == ["1", "2", "summary"] and lines[0]["scene"] == "fake"


def test_eval_flow_views_and_sceneflow(fake_cli, tmp_path):
    from lfusd.data import formats
    from lfusd.evaluation.score import evaluate

    ds = fake_cli
    pred = tmp_path / "p"
    pred.mkdir()
    formats.write_flo(pred / "0001_01_01.flo", ds.read(1, (1, 1), "flow_fwd") + np.array([3.0, 4.0], np.float32))
    r = evaluate(ds, pred, "flow")[0]
    assert r["epe_px"] == pytest.approx(5.0, rel=1e-5) and r["epe_gt_1px_pct"] == 100.0
    formats.write_png(pred / "0003_02_02.png", ds.read(3, (2, 2), "rgb"))
    r = evaluate(ds, pred, "views")[0]
    assert r["psnr_db"] == math.inf and r["ssim"] == pytest.approx(1.0)
    sf = ds.read(1, (1, 1), "scene_flow")
    np.save(pred / "0001_01_01.npy", sf + np.array([0.0, 0.0, 0.02], np.float32))
    d = ds.read(1, (1, 1), "disparity")
    formats.write_pfm(pred / "0001_01_01_disp.pfm", d)
    formats.write_pfm(pred / "0001_01_01_disp2.pfm", d + ds.read(1, (1, 1), "disparity_change"))
    formats.write_flo(pred / "0001_01_01_flow.flo", ds.read(1, (1, 1), "flow_fwd"))
    r = evaluate(ds, pred, "sceneflow")[0]
    assert r["epe3d_m"] == pytest.approx(0.02, rel=1e-4) and r["acc3d_strict_pct"] == 100.0
    assert (r["d1_pct"], r["d2_pct"], r["fl_pct"], r["sf_pct"]) == (0.0, 0.0, 0.0, 0.0)


def test_eval_bad_predictions_are_one_line_errors(fake_cli, tmp_path, capsys):
    from lfusd.data import formats
    from lfusd.cli import main

    pred = tmp_path / "p"
    pred.mkdir()

    def err(*args):
        assert main(["eval", *args, "--pred", str(pred), "--gt", "/data/fake"]) == 2
        e = capsys.readouterr().err.strip()
        assert e.startswith("lfusd: error:") and "\n" not in e
        return e

    assert "no disparity predictions" in err("--task", "disparity")  # empty folder
    formats.write_pfm(pred / "0002_01_01.pfm", np.zeros((5, 5), np.float32))
    assert "0002_01_01.pfm" in err("--task", "disparity") and "shape" in err("--task", "disparity")
    (pred / "0002_01_01.pfm").unlink()
    formats.write_pfm(pred / "0009_01_01.pfm", np.zeros((20, 24), np.float32))
    assert "frame 9" in err("--task", "disparity")
    (pred / "0009_01_01.pfm").unlink()
    formats.write_flo(pred / "0003_01_01.flo", np.zeros((20, 24, 2), np.float32))
    assert "last one" in err("--task", "flow")
    assert "no views predictions" in err("--task", "views")
    assert main(["eval", "--task", "flow", "--pred", str(tmp_path / "missing"), "--gt", "/data/fake"]) == 2
    assert "does not exist" in capsys.readouterr().err
