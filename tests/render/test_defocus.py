"""render-video --fstop --focus: Cycles' thin lens in the image, pinhole ground truth, and the coc key
against the thin-lens formula on a tilted plane and against the spread of a defocused square."""

from __future__ import annotations

import numpy as np
import pytest
from support.lens_stage import FOCUS, FSTOP, PLANE_Y, RIG, SQUARE, TILT, write_lens_stage

from lfusd import Dataset

pytestmark = pytest.mark.render


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    from lfusd.cli import main

    root = tmp_path_factory.mktemp("lens")
    write_lens_stage(root / "lens.usda")
    common = ["--quiet", "--device", "cpu", "--light", "none", "--samples", "256"]
    # --verify: exit 0 only when lfusd verify passes with the effect on
    assert main(["render-video", str(root / "lens.usda"), "-o", str(root / "lens"), *common, "--fstop", str(FSTOP), "--focus", str(FOCUS),
                 "--verify"]) == 0
    assert main(["render-video", str(root / "lens.usda"), "-o", str(root / "pinhole"), *common, "--keys", "rgb_linear"]) == 0
    return Dataset(root / "lens"), Dataset(root / "pinhole")


def test_coc_is_the_thin_lens_formula_on_a_tilted_plane(renders):
    ds, _ = renders
    K, c2w = ds.intrinsics((0, 0)), ds.cam_to_world(1, (0, 0))
    h, w = RIG.height, RIG.width
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    d = np.stack([u, v, np.ones_like(u)], -1) @ (c2w[:3, :3] @ np.linalg.inv(K)).T  # camera-frame z = 1
    C = c2w[:3, 3]
    a = np.radians(TILT)
    n = np.array([-np.sin(a), np.cos(a), 0.0])  # the tilted plane's normal, through (0, PLANE_Y, 0)
    z = (n @ (np.array([0.0, PLANE_Y, 0.0]) - C)) / (d @ n)  # closed-form planar depth of the plane at each pixel
    plane = np.isclose(ds.read(1, (0, 0), "depth"), z, rtol=1e-4)
    assert plane.sum() > 200 and np.ptp(z[plane]) > 1.0  # the plane's depth varies by over a metre across the picture
    aperture = RIG.focal_length_mm * 1e-3 / FSTOP
    want = K[0, 0] * aperture * np.abs(1 / FOCUS - 1 / z)  # thin lens, image plane at the focal length (Cycles)
    got = ds.read(1, (0, 0), "coc")
    assert np.allclose(got[plane], want[plane], rtol=1e-4)
    assert got[plane].min() < 0.05 and got[plane].max() > 0.8  # in focus across a column, blurred away from it


def test_the_square_spreads_as_a_disc_of_the_coc_and_ground_truth_stays_pinhole(renders):
    ds, pinhole = renders
    lens, sharp = (x.read(1, (0, 0), "rgb_linear").sum(axis=-1).astype(np.float64) for x in (ds, pinhole))
    depth = ds.read(1, (0, 0), "depth")
    square = np.isclose(depth, SQUARE[1] - RIG.at[1], rtol=1e-4)
    assert square.sum() > 10
    c = float(ds.read(1, (0, 0), "coc")[square].mean())
    assert c > 4

    def spread(img):  # intensity-weighted variance of u and v, and the total
        v, u = np.mgrid[0 : img.shape[0], 0 : img.shape[1]]
        m = img.sum()
        return (((u - (u * img).sum() / m) ** 2 * img).sum() / m, ((v - (v * img).sum() / m) ** 2 * img).sum() / m), m

    (su, sv), total = spread(lens)
    (pu, pv), total_sharp = spread(sharp)
    assert abs(total / total_sharp - 1) < 0.03  # the lens moves light, it does not make or lose it
    for got in (su - pu, sv - pv):  # a uniform disc of diameter c adds c^2/16 to the variance along each axis
        assert abs(got / (c**2 / 16) - 1) < 0.1, (got, c**2 / 16)
    # the ground truth is the pinhole's: the sharp render's depth of the square is the same
    np.testing.assert_array_equal(ds.read(1, (0, 0), "instance") > 0, depth < np.inf)
