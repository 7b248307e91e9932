"""The shipped disparity weights (flow/weights/disparity.pt, trained on lfusd data alone: flow/README.md
"Shipped weights"): loaded with weights_only=True by predict_disparity.py without --weights, they put
synthetic fronto-parallel planes at known disparities of each sign within 0.1 px (analytic views:
tests/flow/test_predict_disparity.py plane_views, a texture no lfusd stage has), through the
command line on HCI-layout folders, as a user runs them."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from lfusd.data import formats
from support.flow_scripts import load_script
from test_predict_disparity import plane_views, write_hci

ROOT = Path(__file__).resolve().parents[2]
WEIGHTS = ROOT / "flow" / "weights" / "disparity.pt"
SIZE = 64  # views of 64x64: the inner 32x32 is scored, far from the tiles' and the image's borders


def test_the_shipped_weights_are_small_and_load_without_pickled_code():
    assert WEIGHTS.is_file(), "flow/weights/disparity.pt is missing"
    assert WEIGHTS.stat().st_size <= 10 * 2**20
    state = torch.load(WEIGHTS, map_location="cpu", weights_only=True)
    assert set(state) >= {"model", "config"} and state["config"]["ang"] == 9
    pdm = load_script("predict_disparity")
    assert pdm.SHIPPED == WEIGHTS


@pytest.mark.parametrize("d", [-2.5, -1.0, 1.0, 2.5])
def test_a_plane_of_each_sign_comes_out_of_the_shipped_weights_within_a_tenth_of_a_pixel(tmp_path, d):
    lf = write_hci(tmp_path / "lf", plane_views(d, np.random.default_rng(11), SIZE))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    r = subprocess.run([sys.executable, str(ROOT / "flow" / "predict_disparity.py"), str(lf), "-o", str(tmp_path / "d.pfm"), "--threads", "1"],
                       env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    got = formats.read_pfm(tmp_path / "d.pfm")
    inner = got[16:-16, 16:-16]
    med = float(np.median(inner))
    assert np.sign(med) == np.sign(d) and abs(med - d) < 0.1, (d, med, float(inner.min()), float(inner.max()))
