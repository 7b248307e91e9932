"""The shipped disparity weights (flow/weights/disparity.pt, trained on lfusd data alone: flow/README.md
"Shipped weights"): loaded with weights_only=True by predict_disparity.py without --weights, they put
synthetic fronto-parallel planes at known disparities of each sign on the right side of zero and near
their value (analytic views: tests/support/light_fields.py plane_views, a texture no lfusd
stage has), through the command line on HCI-layout folders, as a user runs them.

The bound is the one the shipped weights are documented to meet, :data:`BOUND_PX`. Issue 36 asks for
0.1 px; the shipped weights are the CPU preview's 1 500 steps, whose medians on these planes are off
by 0.15-0.18 px (measured when they were committed), so the issue's bound is not met yet and is not
claimed: tighten BOUND_PX to 0.1 when weights that meet it ship."""

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
from support.light_fields import plane_views, write_hci

ROOT = Path(__file__).resolve().parents[2]
WEIGHTS = ROOT / "flow" / "weights" / "disparity.pt"
SIZE = 64  # views of 64x64: the inner 32x32 is scored, far from the tiles' and the image's borders
BOUND_PX = 0.25  # the shipped preview weights' documented bound (flow/README.md "Shipped weights"); issue 36's is 0.1


def test_the_shipped_weights_are_small_and_load_without_pickled_code():
    assert WEIGHTS.is_file(), "flow/weights/disparity.pt is missing"
    assert WEIGHTS.stat().st_size <= 10 * 2**20
    state = torch.load(WEIGHTS, map_location="cpu", weights_only=True)
    assert set(state) >= {"model", "config"} and state["config"]["ang"] == 9
    pdm = load_script("predict_disparity")
    assert pdm.SHIPPED == WEIGHTS


@pytest.mark.parametrize("d", [-2.5, -1.0, 1.0, 2.5])
def test_a_plane_of_each_sign_comes_out_of_the_shipped_weights_with_its_sign_and_near_its_value(tmp_path, d):
    lf = write_hci(tmp_path / "lf", plane_views(d, np.random.default_rng(11), SIZE))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    r = subprocess.run([sys.executable, str(ROOT / "flow" / "predict_disparity.py"), str(lf), "-o", str(tmp_path / "d.pfm"), "--threads", "1"],
                       env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    got = formats.read_pfm(tmp_path / "d.pfm")
    inner = got[16:-16, 16:-16]
    med = float(np.median(inner))
    assert np.sign(med) == np.sign(d) and abs(med - d) < BOUND_PX, (d, med, float(inner.min()), float(inner.max()))


SF_WEIGHTS = ROOT / "flow" / "weights" / "sceneflow.pt"
# the shipped scene-flow weights' documented bounds (flow/README.md "Learned scene flow"), on the inner
# 32x32 of the moving planes below: median flow error per component and median |disparity change|
SF_FLOW_BOUND_PX = 0.25
SF_CHANGE_BOUND_PX = 0.05


def test_the_shipped_scene_flow_weights_are_small_and_load_without_pickled_code():
    assert SF_WEIGHTS.is_file(), "flow/weights/sceneflow.pt is missing"
    assert SF_WEIGHTS.stat().st_size <= 10 * 2**20
    state = torch.load(SF_WEIGHTS, map_location="cpu", weights_only=True)
    assert set(state) >= {"model", "config"} and state["config"]["ang"] == 9
    assert load_script("predict_sceneflow").DEFAULT_WEIGHTS == SF_WEIGHTS


@pytest.mark.parametrize("d, fx, fy", [(-1.5, 2, -1), (2.5, 3, 1), (-2.5, 0, -3)])
def test_a_moving_plane_comes_out_of_the_shipped_scene_flow_weights_with_its_flow_and_no_disparity_change(tmp_path, d, fx, fy):
    """A fronto-parallel plane at disparity d whose texture moves by (fx, fy) whole pixels between the
    two frames (the analytic views of plane_views, cropped from a larger canvas at two offsets):
    optical flow (fx, fy), disparity d at both times, disparity change 0 (it keeps its depth)."""
    m = 8
    big = plane_views(d, np.random.default_rng(11), SIZE + 2 * m)
    t0 = write_hci(tmp_path / "t0", big[:, m : m + SIZE, m : m + SIZE])
    t1 = write_hci(tmp_path / "t1", big[:, m - fy : m - fy + SIZE, m - fx : m - fx + SIZE])
    for f in (t0, t1):
        (f / "parameters.cfg").unlink()  # no camera: flow, disparity and its change only
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    r = subprocess.run([sys.executable, str(ROOT / "flow" / "predict_sceneflow.py"), str(t0), str(t1), "-o", str(tmp_path / "out"), "--threads", "1"],
                       env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    inner = (slice(16, -16), slice(16, -16))
    flow = formats.read_flo(tmp_path / "out" / "flow.flo")[inner]
    disp = formats.read_pfm(tmp_path / "out" / "disparity.pfm")[inner]
    change = formats.read_pfm(tmp_path / "out" / "disparity_change.pfm")[inner]
    got = (float(np.median(flow[..., 0])), float(np.median(flow[..., 1])))
    assert abs(got[0] - fx) < SF_FLOW_BOUND_PX and abs(got[1] - fy) < SF_FLOW_BOUND_PX, (d, (fx, fy), got)
    assert np.sign(np.median(disp)) == np.sign(d) and abs(float(np.median(disp)) - d) < BOUND_PX, (d, float(np.median(disp)))
    assert abs(float(np.median(change))) < SF_CHANGE_BOUND_PX, float(np.median(change))


BENCH_WEIGHTS = ROOT / "flow" / "weights" / "sceneflow_bench_preview.pt"


def test_the_benchmark_scene_flow_weights_take_every_view_of_the_preview_grid():
    """flow/weights/sceneflow_bench_preview.pt (docs/commands/bench.md, row (c) of the preview
    leaderboard): small, loaded without pickled code, trained on the preview grid (5x5) with every view
    as reference and a disparity network that takes any reference (not the centre-only star), so that
    `predict_sceneflow.py --bench` accepts it; its candidates span the preview test split's disparity
    (-1.04..23.39 px, recorded in public/test/*/cameras.json when the split was rendered)."""
    assert BENCH_WEIGHTS.is_file() and BENCH_WEIGHTS.stat().st_size <= 10 * 2**20
    state = torch.load(BENCH_WEIGHTS, map_location="cpu", weights_only=True)
    config = state["config"]
    assert config["ang"] == 5 and config["references"] == "all" and not config.get("disparity_net")
    assert config["d_min"] <= -1.04 and config["d_max"] >= 23.39
    model, _ = load_script("predict_sceneflow").load_model(BENCH_WEIGHTS)
    assert type(model.disparity).__name__ == "DisparityNet"
    # any view is a reference: a corner's offsets in, its disparity map out
    views = torch.rand(1, 25, 3, 24, 24, generator=torch.Generator().manual_seed(0))
    k = torch.arange(5.0) - 2
    off = torch.stack(torch.meshgrid(k, k, indexing="ij")[::-1], -1).reshape(1, 25, 2)
    with torch.no_grad():
        d = model.disparity(views, off - off[:, :1])
    assert d.shape == (1, 24, 24) and torch.isfinite(d).all()
