"""Classical baselines on closed-form scenes (tiny, CPU)."""

from __future__ import annotations

import numpy as np
import pytest

from support.fake import FakeDataset, texture
from lfusd import LfusdError
from lfusd.evaluation import baselines, metrics


def _plane_views(d: float, n: int = 5, h: int = 40, w: int = 48):
    """A textured fronto-parallel plane at disparity d: view (r, c) samples the texture at
    (u + d*sx, v + d*sy) so that the centre pixel (u, v) appears at (u - d*sx, v - d*sy)."""
    v, u = np.mgrid[0:h, 0:w].astype(float)
    imgs, offs = {}, {}
    for r in range(n):
        for c in range(n):
            sx, sy = c - n // 2, r - n // 2
            imgs[(r, c)] = np.round(255 * texture((u + d * sx) * 0.03, (v + d * sy) * 0.03, 5)).astype(np.uint8)
            offs[(r, c)] = (float(sx), float(sy))
    return imgs, offs


def test_plane_sweep_recovers_a_plane():
    imgs, offs = _plane_views(1.3)
    d = baselines.plane_sweep_disparity(imgs, offs, (0.0, 0.0), d_range=(-2, 3), n_planes=51, device="cpu")
    inner = d[8:-8, 8:-8]
    assert np.median(np.abs(inner - 1.3)) < 0.01
    assert np.mean(np.abs(inner - 1.3) < 0.05) > 0.95
    # the sign matters: the mirrored scene gives the mirrored answer
    imgs2, _ = _plane_views(-0.7)
    d2 = baselines.plane_sweep_disparity(imgs2, offs, (0.0, 0.0), d_range=(-2, 3), n_planes=51, device="cpu")
    assert np.median(np.abs(d2[8:-8, 8:-8] + 0.7)) < 0.01


def test_plane_sweep_on_two_depths():
    ds = FakeDataset(rows=5, cols=5, width=64, height=48, frames=(1,))
    c = ds.rig.centre_view
    imgs = {v: ds.read(1, v, "rgb") for v in ds.views}
    offs = {v: ds.rig.offsets(v) for v in ds.views}
    d = baselines.plane_sweep_disparity(imgs, offs, offs[c], d_range=(0.5, 2.5), n_planes=81, device="cpu")
    gt = ds.read(1, c, "disparity")
    inst = ds.read(1, c, "instance")
    # away from the box's outline and the image border
    from numpy.lib.stride_tricks import sliding_window_view

    same = np.zeros_like(inst, bool)
    win = sliding_window_view(np.pad(inst, 4, mode="edge"), (9, 9))
    same[:] = (win.min(axis=(-1, -2)) == win.max(axis=(-1, -2)))
    same[:6], same[-6:], same[:, :6], same[:, -6:] = False, False, False, False
    err = np.abs(d - gt)[same]
    assert same.sum() > 500 and np.median(err) < 0.02 and np.mean(err < 0.07) > 0.9
    f_b = ds.rig.focal_px * ds.baseline  # 64 px * 0.05 m
    assert np.median(d[(inst == 2) & same]) == pytest.approx(f_b / 1.6, abs=0.03)  # the box at z = 1.6
    assert np.median(d[(inst == 1) & same]) == pytest.approx(f_b / 3.0, abs=0.03)  # the wall at z = 3


def test_dis_flow_measures_a_shift():
    v, u = np.mgrid[0:64, 0:80].astype(float)
    a = np.round(255 * texture(u * 0.05, v * 0.05, 9)).astype(np.uint8)
    b = np.round(255 * texture((u - 2.5) * 0.05, (v + 1.25) * 0.05, 9)).astype(np.uint8)  # content moves by (+2.5, -1.25)
    f = baselines.dis_flow(a, b)
    assert f.shape == (64, 80, 2)
    inner = f[10:-10, 10:-10]
    assert np.median(inner[..., 0]) == pytest.approx(2.5, abs=0.15)
    assert np.median(inner[..., 1]) == pytest.approx(-1.25, abs=0.15)


def test_scene_flow_from_exact_inputs_is_exact():
    ds = FakeDataset(rows=3, cols=3, width=48, height=40, frames=(1, 2))
    c = ds.rig.centre_view
    d0, d1 = ds.read(1, c, "disparity"), ds.read(2, c, "disparity")
    flow = ds.read(1, c, "flow_fwd")
    sf, dchange, ok = baselines.scene_flow_from(d0, d1, flow, ds.intrinsics(c), ds.cam_to_world(1, c), ds.cam_to_world(2, c), ds.baseline)
    gt = ds.read(1, c, "scene_flow")
    gt_dc = ds.read(1, c, "disparity_change")
    # where the point stays on one surface between the four pixels it lands on at t+1
    inst1 = ds.read(2, c, "instance")
    u1 = np.arange(48)[None] + flow[..., 0]
    v1 = np.arange(40)[:, None] + flow[..., 1]
    inside = (u1 >= 0) & (u1 <= 46) & (v1 >= 0) & (v1 <= 38)
    i0 = np.clip(np.floor(v1).astype(int), 0, 38)
    j0 = np.clip(np.floor(u1).astype(int), 0, 46)
    same = inside & (inst1[i0, j0] == ds.read(1, c, "instance")) & (inst1[i0 + 1, j0 + 1] == inst1[i0, j0]) & (inst1[i0, j0 + 1] == inst1[i0, j0]) & (inst1[i0 + 1, j0] == inst1[i0, j0])
    assert same.sum() > 1000 and np.all(ok[same])
    np.testing.assert_allclose(sf[same], gt[same], atol=2e-5)
    np.testing.assert_allclose(dchange[same], gt_dc[same], atol=1e-5)
    assert np.abs(gt[same]).max() > 0.01  # the box does move


def test_view_interpolation_beats_blending():
    ds = FakeDataset(rows=5, cols=5, width=48, height=40, frames=(1,))
    offs = {v: ds.rig.offsets(v) for v in ds.views}
    corners = [(0, 0), (0, 4), (4, 0), (4, 4)]
    inp = {v: ds.read(1, v, "rgb") for v in corners}
    targets = {(2, 2): offs[(2, 2)], (1, 3): offs[(1, 3)]}
    synth = baselines.interpolate_views(inp, offs, targets, d_range=(0.5, 2.0), n_planes=31, device="cpu")
    blend = baselines.blend_views(inp, offs, targets)
    for v in targets:
        gt = ds.read(1, v, "rgb")
        s, b = metrics.view_synthesis(synth[v], gt), metrics.view_synthesis(blend[v], gt)
        assert s["psnr_db"] > 27 and s["psnr_db"] > b["psnr_db"] + 3 and s["ssim"] > b["ssim"]


def test_run_baselines_table():
    ds = FakeDataset(rows=3, cols=3, width=32, height=24, frames=(1, 2))
    res = baselines.run_baselines(ds, n_planes=16, asr=3, device="cpu")
    assert set(res) == {"disparity", "flow", "sceneflow", "views", "views_blend"}
    assert res["flow"]["n"] == 1 and res["views"]["n"] == 2 * 5
    assert res["disparity"]["mse_x100"] < 10 and res["flow"]["epe_px"] < 1.0
    table = baselines.format_table(res, "fake")
    assert "MSEx100" in table and "EPE3D" in table and "PSNR" in table


def test_bad_inputs():
    imgs, offs = _plane_views(1.0, n=3)
    with pytest.raises(LfusdError):
        baselines.plane_sweep_disparity({(0, 0): imgs[(0, 0)]}, offs)
    with pytest.raises(LfusdError):
        baselines.plane_sweep_disparity(imgs, offs, d_range=(2, 1))
    for window in (8, 0):  # an even window cannot centre on its pixel (PyTorch's avg_pool2d failed on it)
        with pytest.raises(LfusdError, match="odd"):
            baselines.plane_sweep_disparity(imgs, offs, window=window, device="cpu")
    with pytest.raises(LfusdError):
        baselines.dis_flow(imgs[(0, 0)], imgs[(0, 0)][:10])
    with pytest.raises(LfusdError):
        baselines.scene_flow_from(np.ones((4, 4)), np.ones((4, 5)), np.zeros((4, 4, 2)), np.eye(3), np.eye(4), np.eye(4), 0.1)
