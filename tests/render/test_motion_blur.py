"""render-video --shutter: Cycles' motion blur in the image, ground truth at the shutter's centre, and the
blur key against the closed-form image speed of a card sliding parallel to the image plane."""

from __future__ import annotations

import numpy as np
import pytest
from support.blur_stage import CARD_Y, RIG, SPEED, write_blur_stage

from lfusd import Dataset

pytestmark = pytest.mark.render

SHUTTER = 0.5
K = 16  # sharp renders at sub-frame times across the shutter


def _render(stage, out, *extra):
    from lfusd.cli import main

    assert main(["render-video", str(stage), "-o", str(out), "--quiet", "--device", "cpu", "--light", "none", *extra]) == 0
    return Dataset(out)


@pytest.fixture(scope="module")
def blurred(tmp_path_factory):
    root = tmp_path_factory.mktemp("blur")
    write_blur_stage(root / "card.usda")
    # --verify: exit 0 only when lfusd verify passes with the effect on
    return _render(root / "card.usda", root / "out", "--samples", "512", "--shutter", str(SHUTTER), "--verify")


def test_blurred_frame_is_the_mean_of_sharp_sub_frame_renders(blurred, tmp_path):
    # the plain stage's times t - s/2 .. t + s/2 at frame 2, one sharp frame at the middle of each of K slices
    times = 2 + SHUTTER * ((np.arange(K) + 0.5) / K - 0.5)
    write_blur_stage(tmp_path / "sub.usda", times=times)
    sharp = _render(tmp_path / "sub.usda", tmp_path / "sub", "--samples", str(512 // K), "--keys", "rgb_linear")
    mean = np.mean([sharp.read(f, (0, 0), "rgb_linear") for f in range(1, K + 1)], axis=0)
    image = blurred.read(2, (0, 0), "rgb_linear")
    psnr = 10 * np.log10(1.0 / np.mean((image - mean) ** 2))
    one_sharp = sharp.read(K // 2, (0, 0), "rgb_linear")
    print(f"PSNR blurred vs mean of {K} sharp: {psnr:.1f} dB")
    assert psnr >= 40, psnr
    assert 10 * np.log10(1.0 / np.mean((image - one_sharp) ** 2)) < psnr - 6  # the blur is there: a sharp frame is far off


def test_ground_truth_is_at_the_shutter_centre_and_blur_is_the_analytic_path_length(blurred):
    ds = blurred
    K_ = ds.intrinsics((0, 0))
    depth = ds.read(2, (0, 0), "depth")
    card = np.isclose(depth, CARD_Y - RIG.at[1], rtol=1e-4)  # planar depth 3: the card
    assert card.sum() > 30
    speed = K_[0, 0] * SPEED / (CARD_Y - RIG.at[1])  # px per frame, parallel to the image plane
    flow = ds.read(2, (0, 0), "flow_fwd")
    assert np.allclose(flow[card, 0], speed, atol=0.01) and np.allclose(flow[card, 1], 0, atol=0.01)  # sharp: frame 2 itself
    blur = ds.read(2, (0, 0), "blur")
    assert np.allclose(blur[card], SHUTTER * speed, atol=0.005)  # s/2 of a frame on either side
    assert np.allclose(blur[~card], 0, atol=0.005)  # the wall does not move
    assert np.isnan(ds.read(1, (0, 0), "blur")[card]).all()  # frame 0 is not in the dataset: unknown
