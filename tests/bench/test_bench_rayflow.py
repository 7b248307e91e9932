"""Baseline (b), ray flow (`lfusd bench baseline --method rayflow`): a submission from the public
inputs alone that `lfusd bench score` scores, and the refusal of a rig it cannot model. Its accuracy
against analytic motion is tests/evaluation/test_rayflow.py's."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from support.cli import assert_one_line_error, run_cli

from lfusd.bench import baseline


@pytest.mark.render
@pytest.mark.parametrize("solver", ["global", "local"])
def test_baseline_b_ray_flow_writes_a_submission_from_the_public_inputs_alone(tiny_bench, tmp_path, capsys, solver):
    code, root = tiny_bench
    assert code == 0
    public_only = tmp_path / "public_only"
    public_only.mkdir()
    shutil.copy(root / "bench.json", public_only / "bench.json")
    shutil.copytree(root / "public", public_only / "public")
    sub = tmp_path / "rayflow"
    code, out, _ = run_cli(capsys, "bench", "baseline", public_only, "-o", sub, "--method", "rayflow", "--solver", solver, "--planes", "16")
    assert code == 0 and f"ray flow, {solver} solver" in out, out
    code, out, _ = run_cli(capsys, "bench", "score", sub, "--bench", root, "--method", "ray flow")
    assert code == 0 and "| ray flow |" in out
    res = json.loads((sub / "score.json").read_text())["overall"]["all"]
    # the tiny scene barely moves (its true scene flow is under a millimetre on average): a diverging
    # solver or a wrong unit in the composition (baselines for metres, a world/camera mix-up) gives
    # errors of decimetres and pixels; the measured figures are a few millimetres and a tenth of a pixel
    assert 0 < res["epe3d_m"] < 0.05 and 0 < res["epe_px"] < 0.5 and res["dchange_epe_px"] < 0.1, res


def _pose(rot=np.eye(3), pos=(0.0, 0.0, 0.0)):
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = rot, pos
    return m.tolist()


@pytest.mark.parametrize("second", [_pose(np.diag([1.0, -1.0, -1.0])), _pose(pos=(0.5, 0.0, 0.1)), _pose(pos=(0.0, 0.5, 0.0))],
                         ids=["turned", "off-plane", "off-offset"])
def test_ray_flow_refuses_a_rig_that_is_not_planar_and_parallel(tmp_path, capsys, monkeypatch, second):
    # view 00_01 belongs 0.5 m right of 00_00 (offset 1 baseline of 0.5 m)
    cams = {"baseline": 0.5, "offsets": {"00_00": [-0.5, 0.0], "00_01": [0.5, 0.0]},
            "cam_to_world": {"1": {"00_00": _pose(), "00_01": second}}}
    scene = tmp_path / "public" / "test" / "s"
    scene.mkdir(parents=True)
    (scene / "cameras.json").write_text(json.dumps(cams))
    monkeypatch.setattr("lfusd.bench.make.read_record", lambda root: {"splits": {"test": ["s"]}})
    baseline._check_parallel_rig(cams | {"cam_to_world": {"1": {"00_00": _pose(), "00_01": _pose(pos=(0.5, 0.0, 0.0))}}})  # the right place passes
    code, _, err = run_cli(capsys, "bench", "baseline", tmp_path, "-o", tmp_path / "sub", "--method", "rayflow")
    assert_one_line_error(code, err, "view 00_01", "planar, parallel rig", "--method dis")
    assert not (tmp_path / "sub").exists()  # refused before anything is written


def test_ray_flow_shares_each_frame_pairs_image_work_and_predicts_what_a_fresh_ray_flow_does(monkeypatch):
    """predict_scene_rayflow builds one LightFieldPair per frame pair (the next pair borrowing its t+1)
    for every reference view; each view's prediction is the ray flow computed afresh from the images."""
    from lfusd.evaluation import baselines as bl
    from lfusd.evaluation import rayflow
    from lfusd.layout import view_key

    n, f, b = 32, 30.0, 0.1
    rng = np.random.default_rng(5)
    waves = [(rng.uniform(-1, 1, 2) / rng.uniform(0.2, 0.5), rng.uniform(0, 6.3)) for _ in range(12)]
    views = [(r, c) for r in range(3) for c in range(3)]
    offsets = {view_key(v): [v[1] - 1.0, v[0] - 1.0] for v in views}
    frames = [0, 1, 2]

    def rgb(t, v):  # a textured plane at 2 m moving by (1, -1, 5) cm per frame: views of one rig, closed form
        yy, xx = np.mgrid[0:n, 0:n].astype(np.float64)
        z = 2.0 + 0.05 * t
        X = b * (v[1] - 1) + (xx - (n - 1) / 2) / f * z - 0.01 * t
        Y = b * (v[0] - 1) + (yy - (n - 1) / 2) / f * z + 0.01 * t
        ch = [0.5 + sum(0.1 * np.sin(2 * np.pi * (q[0] * X + q[1] * Y) + p) for q, p in waves[4 * c:4 * c + 4]) for c in range(3)]
        return np.round(255 * np.clip(np.stack(ch, -1), 0, 1)).astype(np.uint8)

    def pose(v):
        m = np.eye(4)
        m[:2, 3] = [b * (v[1] - 1), b * (v[0] - 1)]
        return m.tolist()

    K = [[f, 0, (n - 1) / 2], [0, f, (n - 1) / 2], [0, 0, 1]]
    cams = {"views": [list(v) for v in views], "offsets": offsets, "intrinsics": K, "disparity_range": [1.0, 2.0], "baseline": b,
            "frames": frames, "scored_frames": [0, 1], "cam_to_world": {str(t): {view_key(v): pose(v) for v in views} for t in frames}}
    monkeypatch.setattr(baseline, "_inputs", lambda scene_dir: (cams, rgb))
    built = []
    real = rayflow.LightFieldPair

    class Spy(real):
        def __init__(self, *a, previous=None, **k):
            built.append(previous)
            super().__init__(*a, previous=previous, **k)

    monkeypatch.setattr(rayflow, "LightFieldPair", Spy)
    preds = {(t, v): arr for t, v, arr in baseline.predict_scene_rayflow(None, n_planes=12, window=5, device="cpu")}
    assert len(built) == 2 and built[0] is None and isinstance(built[1], real)  # one per frame pair; the second borrows
    offs = {v: tuple(offsets[view_key(v)]) for v in views}
    for t, v in ((0, (0, 0)), (1, (1, 2))):
        i0, i1 = {u: rgb(t, u) for u in views}, {u: rgb(t + 1, u) for u in views}
        d0 = bl.plane_sweep_disparity({u: i0[u] for u in views if u[0] == v[0] or u[1] == v[1]}, offs, offs[v], (1.0, 2.0), 12, 5, device="cpu")
        motion = rayflow.ray_flow(i0, i1, offs, v, np.asarray(K, float), d0)
        flow, dchange, sf = rayflow.compose(d0, motion, np.asarray(K, float), b, np.asarray(pose(v)), np.asarray(pose(v)))
        np.testing.assert_array_equal(preds[(t, v)]["disparity"], d0)
        np.testing.assert_allclose(preds[(t, v)]["scene_flow"], sf.astype(np.float32), rtol=0, atol=1e-7)
        np.testing.assert_allclose(preds[(t, v)]["flow"], flow.astype(np.float32), rtol=0, atol=1e-5)


def test_an_even_sweep_window_is_refused_before_anything_is_written(tmp_path):
    with pytest.raises(baseline.LfusdError, match="odd number of pixels, got 8; use 7 or 9"):
        baseline.write_baseline(tmp_path / "bench", tmp_path / "sub", window=8)
    assert not (tmp_path / "sub").exists()
