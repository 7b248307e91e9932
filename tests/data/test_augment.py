"""Light-field augmentations (lfusd.data.augment) keep the ground truth consistent with the images:
checked analytically on the closed-form light field of tests/support/fake.py (a textured wall and
a moving textured square, every key exact) and on a rendered scene."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from support.fake import FakeDataset
from lfusd import LfusdError
from lfusd.data import augment as aug

KEYS = ("rgb", "disparity", "depth", "position", "normal", "scene_flow", "flow_fwd", "flow_bwd", "instance")


@pytest.fixture(scope="module")
def item():
    from lfusd.torch import LightFieldVideoDataset

    # an off-centre crop (principal point not at the crop's centre), so that the flips' cx' = w-1-cx matters
    ds = FakeDataset(rows=5, cols=5, width=49, height=51, frames=(1, 2, 3, 4))
    return LightFieldVideoDataset(ds, keys=KEYS, views="all", clip=2, frames=[2], crop=(46, 44))[0]


def project(p: np.ndarray, pose: np.ndarray, k: np.ndarray):
    """World points [3, h, w] -> (u, v, z) in the camera with OpenCV pose and K."""
    q = np.einsum("ij,jhw->ihw", np.linalg.inv(pose)[:3, :3], p) + np.linalg.inv(pose)[:3, 3, None, None]
    return k[0, 0] * q[0] / q[2] + k[0, 2], k[1, 1] * q[1] / q[2] + k[1, 2], q[2]


def centre_index(item) -> int:
    return int(np.flatnonzero(np.all(item["offsets"].numpy() == 0, axis=1))[0])


def check_geometry(item, motion: bool = True) -> None:
    """Every key agrees with every other through the cameras (t = 0 and 1 of a clip; ``motion``: the flow too)."""
    pos, disp, depth = (item[k].numpy().astype(np.float64) for k in ("position", "disparity", "depth"))
    poses, ks, offs = item["cam_to_world"].numpy(), item["intrinsics"].numpy(), item["offsets"].numpy()
    h, w = pos.shape[-2:]
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    c = centre_index(item)
    for i in range(len(offs)):
        for t in range(len(pos)):
            u, v, z = project(pos[t, i], poses[t, i], ks[i])  # each view sees its own positions at its pixels
            fg = np.isfinite(depth[t, i])  # a surface (a rendered scene has background)
            assert fg.mean() > 0.5 and np.isnan(u[~fg]).all()
            np.testing.assert_allclose(u[fg], xx[fg], atol=2e-3)
            np.testing.assert_allclose(v[fg], yy[fg], atol=2e-3)
            np.testing.assert_allclose(z[fg], depth[t, i][fg], rtol=1e-5)
        # the centre view's points appear in view i at (u - d sx, v - d sy) (docs/CONVENTIONS.md)
        u, v, _ = project(pos[0, c], poses[0, i], ks[i])
        fg = np.isfinite(depth[0, c])
        np.testing.assert_allclose(u[fg], (xx - disp[0, c] * offs[i, 0])[fg], atol=2e-3)
        np.testing.assert_allclose(v[fg], (yy - disp[0, c] * offs[i, 1])[fg], atol=2e-3)
        if not motion:
            continue
        # forward flow: where the moved point projects at t+1
        sf, flow = item["scene_flow"].numpy().astype(np.float64), item["flow_fwd"].numpy().astype(np.float64)
        u, v, _ = project(pos[0, i] + sf[0, i], poses[1, i], ks[i])
        np.testing.assert_allclose(u, xx + flow[0, i, 0], atol=2e-3)
        np.testing.assert_allclose(v, yy + flow[0, i, 1], atol=2e-3)
        assert np.linalg.det(poses[0, i, :3, :3]) == pytest.approx(1.0)  # still a right-handed camera


def bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    h, w = img.shape[-2:]
    u0, v0 = np.clip(np.floor(u).astype(int), 0, w - 2), np.clip(np.floor(v).astype(int), 0, h - 2)
    a, b = u - u0, v - v0
    return (img[..., v0, u0] * (1 - a) * (1 - b) + img[..., v0, u0 + 1] * a * (1 - b) + img[..., v0 + 1, u0] * (1 - a) * b
            + img[..., v0 + 1, u0 + 1] * a * b)


def warp_error(item, i: int, disparity=None, least: float = 0.2, surface_only: bool = False) -> float:
    """Mean |centre - view i warped to the centre by the centre's disparity| over pixels whose
    sample lies inside view i and away from depth edges (bilinear sampling blurs them)."""
    rgb = item["rgb"].numpy().astype(np.float64)
    rgb = rgb[0] if rgb.ndim == 5 else rgb
    d = (item["disparity"].numpy()[0] if item["disparity"].ndim == 4 else item["disparity"].numpy()) if disparity is None else disparity
    c = centre_index(item)
    d = d[c].astype(np.float64)
    off = item["offsets"].numpy()[i]
    h, w = d.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    u, v = xx - d * off[0], yy - d * off[1]
    ok = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    edge = np.zeros_like(ok)
    gy, gx = np.gradient(d)
    edge |= (np.abs(gx) + np.abs(gy)) > 0.05 * (np.abs(d) + 1e-6)
    from scipy.ndimage import binary_dilation

    ok &= ~binary_dilation(edge, iterations=3)
    if surface_only:  # leave out the empty background, which looks the same whatever the disparity
        depth = item["depth"].numpy()
        ok &= np.isfinite((depth[0] if depth.ndim == 4 else depth)[c])
    assert ok.mean() > least
    return float(np.abs(bilinear(rgb[i], u, v) - rgb[c])[:, ok].mean())


AUGMENTS = {
    "identity": lambda it: it,
    "refocus+1": lambda it: aug.refocus(it, 1),
    "refocus-2": lambda it: aug.refocus(it, -2),
    "flip x": lambda it: aug.flip(it, "x"),
    "flip y": lambda it: aug.flip(it, "y"),
    "transpose": aug.transpose,
    "all": lambda it: aug.transpose(aug.flip(aug.flip(aug.refocus(it, 1), "y"), "x")),
}


@pytest.mark.parametrize("name", AUGMENTS)
def test_every_key_stays_consistent_with_the_cameras_and_the_images(item, name):
    out = AUGMENTS[name](item)
    check_geometry(out)
    for i in (0, 7, 23):  # corner, inner, off-centre views: warped by the augmented disparity onto the centre
        assert warp_error(out, i) < 0.025, (name, i)
    if name != "identity":
        assert any(not torch.equal(out[k], item[k]) for k in ("rgb", "disparity"))


def test_the_warp_check_sees_a_wrong_disparity(item):
    """The image check fails where the disparity does not match: the unshifted disparity after a
    refocus, the views left in place after a flip."""
    out = aug.refocus(item, 1)
    assert warp_error(out, 0, disparity=out["disparity"].numpy()[0] + 1) > 5 * warp_error(out, 0)
    flipped = aug.flip(item, "x")
    wrong = dict(flipped, rgb=torch.flip(item["rgb"], (-1,)))  # image flipped, grid not
    assert warp_error(wrong, 0) > 5 * warp_error(flipped, 0)


def test_flips_and_transposes_change_the_signs_they_must(item):
    x, y, t = aug.flip(item, "x"), aug.flip(item, "y"), aug.transpose(item)
    views = item["views"].tolist()
    j = views.index([0, 1])  # grid position (0, 1) now holds the mirror of (0, 3) / (4, 1) / (1, 0)
    for out, src, image in ((x, [0, 3], lambda a: a.flip(-1)), (y, [4, 1], lambda a: a.flip(-2)), (t, [1, 0], lambda a: a.transpose(-1, -2))):
        i = views.index(src)
        assert torch.equal(out["disparity"][:, j], image(item["disparity"][:, i]))
        assert torch.equal(out["depth"][:, j], image(item["depth"][:, i]))
        assert out["views"].tolist() == views and torch.equal(out["offsets"], item["offsets"])
    i = views.index([0, 3])
    for key in ("flow_fwd", "flow_bwd"):
        assert torch.equal(x[key][:, j, 0], -item[key][:, i, 0].flip(-1)) and torch.equal(x[key][:, j, 1], item[key][:, i, 1].flip(-1))
    i = views.index([4, 1])
    assert torch.equal(y[key][:, j, 1], -item[key][:, i, 1].flip(-2)) and torch.equal(y[key][:, j, 0], item[key][:, i, 0].flip(-2))
    i = views.index([1, 0])
    assert torch.equal(t["flow_fwd"][:, j, 0], item["flow_fwd"][:, i, 1].transpose(-1, -2))
    assert torch.equal(t["flow_fwd"][:, j, 1], item["flow_fwd"][:, i, 0].transpose(-1, -2))
    r = aug.refocus(item, 2)  # 5x5 grid: margin 4; view (r, c) is read 2*(c-2), 2*(r-2) px further out
    c, corner = views.index([2, 2]), views.index([0, 0])
    assert torch.equal(r["disparity"][:, c], item["disparity"][:, c, 4:-4, 4:-4] - 2)
    assert torch.equal(r["disparity"][:, corner], item["disparity"][:, corner, 8:, 8:] - 2)
    assert torch.equal(r["rgb"][:, corner], item["rgb"][:, corner, :, 8:, 8:])


def test_numpy_items_and_refusals(item):
    np_item = {k: v.numpy() for k, v in item.items()}
    for name, f in AUGMENTS.items():
        a, b = f(item), f(np_item)
        for k in a:
            np.testing.assert_allclose(a[k].numpy().astype(np.float64), np.asarray(b[k], np.float64), rtol=1e-6, atol=1e-6, err_msg=f"{name} {k}")
    corners = {k: v for k, v in item.items()}
    corners["offsets"] = item["offsets"][[0, 1]]  # views (0,0), (0,1): no mirror of (0,1) in the set
    for k in KEYS:
        corners[k] = item[k][:, [0, 1]]
    corners["cam_to_world"], corners["intrinsics"] = item["cam_to_world"][:, [0, 1]], item["intrinsics"][[0, 1]]
    with pytest.raises(LfusdError, match="no mirror"):
        aug.flip(corners, "x")
    with pytest.raises(LfusdError, match="margin"):
        aug.refocus(item, 2, margin=(2, 2))
    with pytest.raises(LfusdError, match="target views"):
        aug.flip(dict(item, target_rgb=item["rgb"]), "x")


def test_colour_jitter_and_noise_touch_only_rgb_and_treat_views_alike(item):
    out = aug.colour_jitter(item, brightness=1.2, contrast=0.8, saturation=0.5)
    for k in KEYS:
        if k != "rgb":
            assert out[k] is item[k]
    assert out["rgb"].min() >= 0 and out["rgb"].max() <= 1
    # one factor for every view: the jitter commutes with moving pixels between views, so the warp stays exact
    assert warp_error(out, 0) < 0.025
    a, b = item["rgb"][0, :, :, 15:25, 15:25], out["rgb"][0, :, :, 15:25, 15:25]
    ratio = (b.std(dim=(-1, -2)) / a.std(dim=(-1, -2)))  # per view and channel: the same contrast change
    assert float(ratio.std()) < 0.2 * float(ratio.mean())
    n = aug.noise(item, 0.05, np.random.default_rng(0))
    diff = (n["rgb"] - item["rgb"])[..., 10:30, 10:30]
    assert 0.04 < float(diff.std()) < 0.06 and n["disparity"] is item["disparity"]


_SHARED = aug.RandomLightField()


def _draws(item):
    return dict(item, draw=torch.tensor(np.random.randint(1 << 30)), aug=torch.tensor(int(_SHARED.rng().integers(1 << 30))))


def test_random_augmentation_in_the_loader_with_seeded_workers():
    from lfusd.torch import LightFieldVideoDataset, data_loader

    ds = FakeDataset(rows=3, cols=3, width=24, height=24, frames=(1, 2, 3, 4))
    assert aug.refocus_margin([[1, 1], [-1, 0]], 2) == (2, 2)
    t = aug.RandomLightField(refocus=2, flip=True, transpose=True, brightness=0.2, contrast=0.1, saturation=0.1, noise=0.01)
    d = LightFieldVideoDataset(ds, keys=("rgb", "disparity"), crop=16 + 2 * 2, random_crop=True, transform=t)
    torch.manual_seed(0)
    batches = list(data_loader(d, batch_size=2, num_workers=2))
    assert [tuple(b["rgb"].shape) for b in batches] == [(2, 9, 3, 16, 16)] * 2
    assert all(torch.isfinite(b["disparity"]).all() for b in batches)
    # NumPy's global generator and the augmentation's own differ between workers, even when the
    # augmentation drew in the parent before the workers forked (they would repeat its draws)
    _SHARED.rng().integers(10)
    d = LightFieldVideoDataset(ds, keys=("disparity",), views="centre", transform=_draws)
    batches = list(data_loader(d, batch_size=1, num_workers=2))
    assert len({int(b["draw"]) for b in batches}) == 4 and len({int(b["aug"]) for b in batches}) == 4


@pytest.mark.render
def test_augmented_rendered_views_warp_onto_the_augmented_centre(box_dataset):
    """On a rendered scene (3x3 views, 48x48 of 64x48): a neighbour view warped by the augmented
    centre disparity matches the augmented centre view as well as before the augmentation (and,
    after a refocus, the unshifted disparity does not); the rendered positions, depth and disparity
    agree through the augmented cameras."""
    from lfusd import Dataset
    from lfusd.torch import LightFieldVideoDataset

    _, out = box_dataset
    item = LightFieldVideoDataset(Dataset(out, rig="main"), keys=("rgb", "disparity", "depth", "position"), crop=48)[0]
    item = {k: (v[None] if k in ("rgb", "disparity", "depth", "position", "cam_to_world") else v) for k, v in item.items()}  # as a clip of one

    def error(it, i, disparity=None):
        return warp_error(it, i, disparity, least=0.1)

    base = [error(item, i) for i in (1, 3, 5, 7)]  # the four neighbours of the centre
    assert max(base) < 0.05
    for name in ("refocus+1", "flip x", "flip y", "transpose", "all"):
        out_item = AUGMENTS[name](item)
        errs = [error(out_item, i) for i in (1, 3, 5, 7)]
        assert max(errs) < 1.5 * max(base) + 0.01, (name, errs, base)
    shifted = aug.refocus(item, 1)
    wrong = shifted["disparity"].numpy()[0] + 1  # the disparity before the shift
    assert error(shifted, 1, wrong) > 2 * error(shifted, 1)
    for name in AUGMENTS:  # and the rendered positions, depth and disparity agree through the augmented cameras
        check_geometry(AUGMENTS[name](item), motion=False)


@pytest.mark.parametrize("dx, dy", [(3, -2), (0, 4), (-4, -4)])
def test_translating_the_next_frame_adds_the_shift_to_the_flow_where_the_points_land(dx, dy):
    """translate_next against the closed-form light field: the point seen at pixel p of frame t
    (position + scene flow, projected by frame t+1's camera in the source image) lands at p + flow'
    in the translated frame t+1, whose images and disparities are the source's moved by (dx, dy)."""
    from lfusd.torch import LightFieldVideoDataset

    m = 4
    ds = FakeDataset(rows=3, cols=3, width=49, height=51, frames=(1, 2, 3, 4))
    src = LightFieldVideoDataset(ds, keys=("rgb", "disparity", "flow_fwd", "position", "scene_flow"), views="all", clip=2, frames=[2], crop=(46, 44))[0]
    item = {k: v for k, v in src.items() if k not in ("position", "scene_flow")}
    out = aug.translate_next(item, dx, dy, m)
    h, w = 46 - 2 * m, 44 - 2 * m
    assert out["rgb"].shape[-2:] == (h, w) and out["flow_fwd"].shape == (2, 9, 2, h, w)
    pos, sf = (src[k].numpy().astype(np.float64) for k in ("position", "scene_flow"))
    poses, ks = src["cam_to_world"].numpy(), src["intrinsics"].numpy()
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    flow = out["flow_fwd"].numpy().astype(np.float64)
    for i in range(9):
        u, v, _ = project(pos[0, i] + sf[0, i], poses[1, i], ks[i])  # source pixels of frame t+1
        u, v = u[m : m + h, m : m + w] - (m - dx), v[m : m + h, m : m + w] - (m - dy)  # in the translated frame t+1
        np.testing.assert_allclose(u, xx + flow[0, i, 0], atol=2e-3)
        np.testing.assert_allclose(v, yy + flow[0, i, 1], atol=2e-3)
        np.testing.assert_array_equal(out["rgb"][1, i].numpy(), src["rgb"][1, i, :, m - dy : m - dy + h, m - dx : m - dx + w].numpy())
        np.testing.assert_array_equal(out["disparity"][0, i].numpy(), src["disparity"][0, i, m : m + h, m : m + w].numpy())
        np.testing.assert_array_equal(out["disparity"][1, i].numpy(), src["disparity"][1, i, m - dy : m - dy + h, m - dx : m - dx + w].numpy())
    np.testing.assert_allclose(flow[1], src["flow_fwd"].numpy()[1, :, :, m - dy : m - dy + h, m - dx : m - dx + w] - np.reshape([dx, dy], (2, 1, 1)))


def test_translate_next_refuses_what_it_cannot_keep_exact(item):
    with pytest.raises(LfusdError, match="not position"):
        aug.translate_next(item, 1, 0, 2)
    small = {k: v for k, v in item.items() if k in ("rgb", "flow_fwd", "cam_to_world", "offsets", "intrinsics", "views", "frames")}
    with pytest.raises(LfusdError, match="margin of at least 3"):
        aug.translate_next(small, 3, 0, 2)
    assert aug.translate_next(small, 0, 0, 2)["rgb"].shape[-2:] == (42, 40)
