"""flow/models.py: the macro-pixel layout, what each disentangled extractor sees, the view shear of
the cost volume and the corner blend, checked against their definitions (CPU, no rendering)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch

from support.fake import texture
from support.flow_scripts import load_script


M = load_script("models")


def test_macpi_puts_view_uv_pixel_hw_at_h_times_u_plus_u():
    u, v, h, w = 3, 2, 4, 5
    x = torch.randn(2, 3, u, v, h, w)
    mac = M.sai_to_macpi(x)
    assert mac.shape == (2, 3, h * u, w * v)
    for a, b, i, j in itertools.product(range(u), range(v), range(h), range(w)):
        assert torch.equal(mac[:, :, i * u + a, j * v + b], x[:, :, a, b, i, j])
    assert torch.equal(M.macpi_to_sai(mac, u, v), x)


def _reach(module, shape, at) -> np.ndarray:
    """Where the output of ``module`` changes when one input position ``at`` (row, col) changes: (H,W) bool."""
    torch.manual_seed(1)
    module = module.double()
    x = torch.randn(shape, dtype=torch.float64)
    y0 = module(x)
    x2 = x.clone()
    x2[:, :, at[0], at[1]] += 1.0
    return (module(x2) - y0).abs().amax(dim=(0, 1)).detach().numpy() > 1e-12


@pytest.mark.parametrize("ang", [2, 3])
def test_each_extractor_sees_its_own_subspace(ang):
    block = M.DistgBlock(ang, 4)
    hs, ws = 5, 6  # spatial size; the MacPI is (hs*ang, ws*ang)
    shape = (1, 4, hs * ang, ws * ang)
    h, w, u, v = 2, 3, ang - 1, 0
    at = (h * ang + u, w * ang + v)
    rows, cols = np.mgrid[0 : hs * ang, 0 : ws * ang]
    same_macro = (rows // ang == h) & (cols // ang == w)
    # angular (kernel = stride = angRes): exactly the one macro-pixel, every view of it
    assert np.array_equal(_reach(block.angular, shape, at), same_macro)
    # spatial (3x3, dilation angRes): only view (u, v), its 3x3 spatial neighbours
    one_conv = block.spatial[0]
    want = (rows % ang == u) & (cols % ang == v) & (np.abs(rows // ang - h) <= 1) & (np.abs(cols // ang - w) <= 1)
    assert np.array_equal(_reach(one_conv, shape, at), want)
    # horizontal EPI (kernel [1, angRes*k]): one MacPI row (view row u at spatial row h), the k macro-pixels around
    k = ang if ang % 2 else ang + 1
    want = (rows == at[0]) & (np.abs(cols // ang - w) <= (k - 1) // 2)
    assert np.array_equal(_reach(block.epi, shape, at), want)


def test_shifting_views_by_the_true_disparity_aligns_a_plane():
    # A fronto-parallel plane at disparity d: the reference pixel (u, v) is seen at (u - d*sx, v - d*sy)
    # in a view at offset (sx, sy) (CONVENTIONS.md, light-field grid); so view (sx, sy) holds T(u + d*sx, v + d*sy).
    d, n, h, w = 1.7, 3, 40, 44
    vv, uu = np.mgrid[0:h, 0:w].astype(float)
    offs = [(c - 1.0, r - 1.0) for r in range(n) for c in range(n)]
    views = np.stack([texture((uu + d * sx) * 0.02, (vv + d * sy) * 0.02, 3) for sx, sy in offs])  # V,H,W,3
    t = torch.from_numpy(views).permute(0, 3, 1, 2)[None].float()
    rel = torch.tensor(offs, dtype=torch.float32)[None]
    ref = torch.from_numpy(texture(uu * 0.02, vv * 0.02, 3)).permute(2, 0, 1).float()
    inner = (slice(None), slice(4, -4), slice(4, -4))
    aligned = M.shift_views(t, rel, d)[0]
    err = (aligned - ref).abs()[:, inner[0], inner[1], inner[2]]
    assert err.max() < 0.01, float(err.max())
    wrong = (M.shift_views(t, rel, d + 1.0)[0] - ref).abs()[:, inner[0], inner[1], inner[2]]
    assert wrong.mean() > 10 * err.mean()


def test_disparity_net_regresses_inside_its_candidates():
    net = M.DisparityNet(3, -0.5, 2.5, n_disp=7, ch=4, n_blocks=1, cost_ch=4)
    views, rel = torch.rand(2, 9, 3, 12, 16), torch.randn(2, 9, 2)
    with torch.no_grad():
        assert net.cost_volume(views, rel).shape == (2, 4, 7, 12, 16)
        d = net(views, rel)
    assert d.shape == (2, 12, 16) and float(d.min()) >= -0.5 and float(d.max()) <= 2.5


def test_corner_blend_is_angular_bilinear_and_asr_output_has_every_view():
    n = 4
    corners = torch.rand(1, 4, 3, 6, 7, dtype=torch.float64)
    out = M.blend_corners(corners, n)
    c00, c01, c10, c11 = (corners[0, i] for i in range(4))
    for r, c in itertools.product(range(n), range(n)):
        y, x = r / (n - 1), c / (n - 1)
        want = (1 - y) * ((1 - x) * c00 + x * c01) + y * ((1 - x) * c10 + x * c11)
        assert torch.allclose(out[0, r * n + c], want, atol=1e-12)
    net = M.ASRNet(n, ch=4, n_blocks=1)
    assert net(torch.rand(2, 4, 3, 8, 10)).shape == (2, n * n, 3, 8, 10)
