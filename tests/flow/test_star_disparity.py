"""flow/models.py StarDisparityNet (issue 36's CPU-affordable disparity network): it uses the views on
the reference's row, column and diagonals, keeps DisparityNet's forward contract (any crop size, odd
ones too), old checkpoints without an ``arch`` still build the original network, and a briefly
trained network puts synthetic fronto-parallel planes (analytic views, tests/support/light_fields.py
plane_views) at known disparities of each sign on the right side of zero, near their value."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "flow"))

import models  # noqa: E402
import train_disparity  # noqa: E402
from support.light_fields import N, centre_offsets, fit_planes, plane_tensor  # noqa: E402

from lfusd import LfusdError  # noqa: E402


def test_star_views_are_the_centre_row_column_and_diagonals():
    got = models.star_views(9)
    assert len(got) == 33 and 40 in got
    for i in range(81):
        r, c = divmod(i, 9)
        assert (i in got) == (r == 4 or c == 4 or abs(r - 4) == abs(c - 4))
    assert models.star_views(3) == list(range(9))


def test_configs_build_their_network_and_old_checkpoints_stay_distg():
    base = {"ang": N, "d_min": -2.0, "d_max": 2.0, "disparities": 9, "channels": 8, "blocks": 1, "cost_channels": 8}
    assert type(train_disparity.build(base)) is models.DisparityNet  # configs written before "arch" existed
    assert type(train_disparity.build({**base, "arch": "star"})) is models.StarDisparityNet
    net = train_disparity.build({**base, "arch": "star"})
    for h, w in [(16, 16), (17, 23)]:
        assert net(torch.rand(2, N * N, 3, h, w), centre_offsets().expand(2, -1, -1)).shape == (2, h, w)
    with pytest.raises(ValueError, match="centre view"):
        net(torch.rand(1, N * N, 3, 8, 8), centre_offsets() + 1)  # offsets from another reference
    with pytest.raises(LfusdError, match="odd grid"):
        train_disparity.build({**base, "ang": 4, "arch": "star"})


def test_a_briefly_trained_star_network_gets_the_sign_of_planes_of_each_sign():
    torch.manual_seed(0)
    net = models.StarDisparityNet(N, -2.2, 2.2, 9, ch=8, n_blocks=1, cost_ch=8)
    fit_planes(net, 200, 2.0, 24)
    with torch.no_grad():
        for d in (-1.5, 1.5):
            got = float(net(plane_tensor(d, np.random.default_rng(7), 32), centre_offsets())[0, 6:-6, 6:-6].median())
            assert np.sign(got) == np.sign(d) and abs(got - d) < 0.5, (d, got)
