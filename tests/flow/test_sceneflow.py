"""The learned light-field scene-flow baseline (flow/train_sceneflow.py, flow/predict_sceneflow.py,
flow/models.py SceneFlowNet) on a tiny rendered video: lfusd's composition of flow, disparity and
disparity change gives the dataset's scene flow, a resumed training ends where an uninterrupted one
does, and the predict script writes what `lfusd eval` scores, the same on an HCI export."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from lfusd.camera import RigSpec
from support.flow_scripts import load_script, run_script

ROOT = Path(__file__).resolve().parents[2]
RIG = RigSpec(name="lf", rows=3, cols=3, width=40, height=32, baseline=0.1, at=(0.3, -5.0, 1.8), look_at=(0.0, 0.5, 0.6))
RIG_MOTION = (0.05, -0.03, 0.0)  # metres per frame: the camera moves too


_script = run_script


def _train_main():
    return load_script("train_sceneflow").main


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    """The moving boxes of tests/support/scenes.py seen by a moving 3x3 rig, 4 frames at 40x32, 1 sample."""
    from support.scenes import write_motion_stage

    from lfusd.cli import main

    root = tmp_path_factory.mktemp("sceneflow")
    stage = root / "movers.usda"
    write_motion_stage(stage, RIG, 4, RIG_MOTION)
    out = root / "out"
    assert main(["render-video", str(stage), "-o", str(out), "--samples", "1", "--quiet", "--device", "cpu"]) == 0
    return out


@pytest.fixture(scope="module")
def weights(video, tmp_path_factory):
    """A few steps of --tiny training on the video (seconds): weights to predict with."""
    run = tmp_path_factory.mktemp("sf_run")
    r = _script("train_sceneflow", "--tiny", "--data", video, "--out", run, "--steps", 4, "--no-baselines", "--quiet")
    assert r.returncode == 0, r.stderr
    return run / "checkpoints" / "last.pt"


def _quantisation_bound(d1, flow, K, baseline):
    """How far (m) the point at t+1 may move when its disparity and the flow are off by the 2^-9 px
    that lfusd's storage of flow_fwd and disparity_change allows (CONVENTIONS.md), with 50 % slack
    for the first-order expansion, plus scene_flow's own 2^-17 m steps."""
    e, f = 2.0**-9, K[0, 0]
    h, w = d1.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    with np.errstate(divide="ignore"):  # no surface: an infinite bound, and such pixels are not valid
        z1 = f * baseline / d1
    ray = np.sqrt(((u + flow[..., 0] - K[0, 2]) / f) ** 2 + ((v + flow[..., 1] - K[1, 2]) / K[1, 1]) ** 2 + 1)
    return 1.5 * e * (z1**2 / (f * baseline) * ray + z1 * np.sqrt(2) / f) + 2.0**-16


@pytest.mark.render
def test_composition_of_true_flow_disparity_and_change_is_the_scene_flow_key(video):
    """scene_flow_from_change (what the network's outputs go through) on the dataset's own flow,
    disparity and disparity change gives its scene_flow key on every valid pixel; ignoring the rig's
    motion (one pose for both frames) does not."""
    from lfusd import Dataset
    from lfusd.evaluation.baselines import scene_flow_from_change

    ds = Dataset(video)
    c = tuple(ds.rig.centre_view)
    K = ds.intrinsics(c)
    n = 0
    for t in (1, 2, 3):
        disp, dch, flow = ds.read(t, c, "disparity"), ds.read(t, c, "disparity_change"), ds.read(t, c, "flow_fwd")
        gt = ds.read(t, c, "scene_flow")
        valid = np.asarray(ds.read(t, c, "valid_fwd"), bool) & np.isfinite(gt).all(-1)
        p0, p1 = ds.cam_to_world(t, c), ds.cam_to_world(t + 1, c)
        sf, ok = scene_flow_from_change(disp, dch, flow, K, p0, p1, ds.rig.baseline)
        assert ok[valid].all()
        err = np.linalg.norm(sf - gt, axis=-1)[valid]
        bound = _quantisation_bound(disp + dch, flow, K, ds.rig.baseline)[valid]
        assert (err <= bound).all(), (t, np.max(err / bound), np.median(bound))
        assert (np.linalg.norm(gt, axis=-1)[valid] > 0.05).sum() > 50  # the boxes move (the ground stays: zero scene flow)
        still, _ = scene_flow_from_change(disp, dch, flow, K, p0, p0, ds.rig.baseline)
        assert (np.linalg.norm(still - gt, axis=-1)[valid] > bound).mean() > 0.5
        n += int(valid.sum())
    assert n > 1500, n


@pytest.mark.render
def test_resumed_training_ends_where_an_uninterrupted_one_does(video, tmp_path):
    """3 steps, then --resume to 6: the same weights, optimiser state and losses as 6 steps in one go."""
    once, twice = tmp_path / "once", tmp_path / "twice"
    common = ["--tiny", "--data", str(video), "--no-baselines", "--quiet"]
    train = _train_main()  # in this process: three runs of the script's main (no interpreter start-ups)
    threads = torch.get_num_threads()  # --tiny sets one thread; the other tests keep theirs
    try:
        assert train([*common, "--out", str(once), "--steps", "6"]) == 0
        assert train([*common, "--out", str(twice), "--steps", "3"]) == 0
        assert train(["--out", str(twice), "--resume", "--steps", "6", "--quiet", "--no-baselines"]) == 0
    finally:
        torch.set_num_threads(threads)
    a, b = (torch.load(p / "checkpoints" / "last.pt", map_location="cpu", weights_only=True) for p in (once, twice))
    assert a["step"] == b["step"] == 6
    for k in a["model"]:
        assert torch.allclose(a["model"][k], b["model"][k], rtol=1e-5, atol=1e-6), k
    la, lb = (json.loads((p / "train_log.json").read_text()) for p in (once, twice))
    assert lb["resumed_at"] == [3]
    assert [h["step"] for h in lb["history"]] == list(range(1, 7))
    assert np.allclose([h["loss"] for h in la["history"]], [h["loss"] for h in lb["history"]], rtol=1e-5)
    # the samples differ from step to step (the crops and augmentations are drawn per sample)
    assert len({round(h["loss"], 6) for h in la["history"]}) > 3


@pytest.mark.render
def test_training_from_the_cache_is_training_from_the_folder(video, tmp_path):
    """--cache (lfusd export cache) reads the same samples: two steps (refocus augmentation on)
    give the same weights."""
    from lfusd.cli import main

    cache = tmp_path / "cache"
    assert main(["export", "cache", str(video), str(cache)]) == 0
    train = _train_main()
    threads = torch.get_num_threads()
    common = ["--tiny", "--data", str(video), "--no-baselines", "--quiet", "--steps", "2", "--refocus", "1"]
    try:
        assert train([*common, "--out", str(tmp_path / "folder")]) == 0
        assert train([*common, "--out", str(tmp_path / "cached"), "--cache", str(cache)]) == 0
    finally:
        torch.set_num_threads(threads)
    a, b = (torch.load(tmp_path / n / "checkpoints" / "last.pt", weights_only=True) for n in ("folder", "cached"))
    assert b["config"]["cache"] == str(cache) and b["config"]["refocus"] == 1
    for k in a["model"]:
        assert torch.allclose(a["model"][k], b["model"][k], rtol=1e-5, atol=1e-6), k


@pytest.mark.render
def test_predict_on_a_dataset_is_what_lfusd_eval_scores(video, weights, tmp_path):
    out = tmp_path / "pred"
    r = _script("predict_sceneflow", video, "-o", out, "--weights", weights, "--frames", "1-2")
    assert r.returncode == 0, r.stderr
    from lfusd import Dataset
    from lfusd.data import formats
    from lfusd.evaluation.baselines import scene_flow_from_change
    from lfusd.evaluation.score import evaluate

    ds = Dataset(video)
    c = tuple(ds.rig.centre_view)
    for t in (1, 2):
        stem = f"{t:04d}_{c[0]:02d}_{c[1]:02d}"
        disp = formats.read_pfm(out / f"{stem}_disp.pfm")
        disp2 = formats.read_pfm(out / f"{stem}_disp2.pfm")
        dch = formats.read_pfm(out / f"{stem}_dchange.pfm")
        flow = formats.read_flo(out / f"{stem}_flow.flo")
        sf = np.load(out / f"{stem}.npy")
        assert disp.shape == (RIG.height, RIG.width) and flow.shape == (RIG.height, RIG.width, 2) and sf.shape == (RIG.height, RIG.width, 3)
        assert np.allclose(disp2, disp + dch, atol=1e-5)
        # the scene flow is lfusd's composition of the written flow, disparity and change
        ref, ok = scene_flow_from_change(disp, dch, flow, ds.intrinsics(c), ds.cam_to_world(t, c), ds.cam_to_world(t + 1, c), ds.rig.baseline)
        assert np.allclose(sf[ok], ref[ok], atol=1e-5) and (sf[~ok] == 0).all()
    scores = evaluate(ds, out, "sceneflow")
    assert [r["frame"] for r in scores] == [1, 2] and np.isfinite(scores.summary["epe3d_m"]) and "d1_pct" in scores.summary


@pytest.mark.render
def test_predict_on_two_hci_folders_matches_the_dataset(video, weights, tmp_path):
    """`lfusd export hci` of frames 1 and 2 through the HCI path gives the dataset path's disparity,
    flow and disparity change, and scene flow in the camera frame of t (the rig taken as still)."""
    from lfusd import Dataset
    from lfusd.cli import main
    from lfusd.data import formats

    hci = tmp_path / "hci"
    assert main(["export", "hci", str(video), str(hci)]) == 0
    f1, f2 = sorted(p for p in hci.iterdir() if p.name.endswith(("_f0001", "_f0002")))
    r = _script("predict_sceneflow", f1, f2, "-o", tmp_path / "h", "--weights", weights)
    assert r.returncode == 0, r.stderr
    r = _script("predict_sceneflow", video, "-o", tmp_path / "d", "--weights", weights, "--frames", "1")
    assert r.returncode == 0, r.stderr
    ds = Dataset(video)
    c = tuple(ds.rig.centre_view)
    stem = f"0001_{c[0]:02d}_{c[1]:02d}"
    h, d = tmp_path / "h", tmp_path / "d"
    for mine, theirs in (("disparity", "_disp"), ("disparity_change", "_dchange"), ("disparity_next", "_disp_next")):
        assert np.allclose(formats.read_pfm(h / f"{mine}.pfm"), formats.read_pfm(d / f"{stem}{theirs}.pfm"), atol=1e-4), mine
    assert np.allclose(formats.read_flo(h / "flow.flo"), formats.read_flo(d / f"{stem}_flow.flo"), atol=1e-4)
    # camera frame of t with the rig taken as still: R0^T (world scene flow - the rig's own motion)
    p0, p1 = np.asarray(ds.cam_to_world(1, c)), np.asarray(ds.cam_to_world(2, c))
    world = np.load(d / f"{stem}.npy")
    cam = np.load(h / "scene_flow.npy")
    ok = np.any(world != 0, -1)
    expect = (world - (p1[:3, 3] - p0[:3, 3])) @ p0[:3, :3]
    assert ok.sum() > 500 and np.allclose(cam[ok], expect[ok], atol=1e-3)
    # without parameters.cfg there is no focal length: no scene flow, the rest as before
    (f1 / "parameters.cfg").unlink()
    r = _script("predict_sceneflow", f1, f2, "-o", tmp_path / "h2", "--weights", weights)
    assert r.returncode == 0 and not (tmp_path / "h2" / "scene_flow.npy").exists() and (tmp_path / "h2" / "flow.flo").is_file()


def test_predict_errors_are_one_line(tmp_path):
    r = _script("predict_sceneflow", tmp_path, tmp_path, "-o", tmp_path / "o", "--weights", tmp_path / "none.pt")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "no weights at" in r.stderr
    bad = tmp_path / "bad.pt"
    torch.save({"model": {}, "config": {"ang": 3}}, bad)
    r = _script("predict_sceneflow", tmp_path, tmp_path, "-o", tmp_path / "o", "--weights", bad)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "SceneFlowNet" in r.stderr


def test_flow_network_pieces_follow_their_definitions():
    """backward_warp samples at (u, v) + flow; local_correlation's channel for (dx, dy) peaks where
    the second image is the first shifted by (dx, dy); resized flow keeps its vectors in pixels."""
    sys.path.insert(0, str(ROOT / "flow"))
    from models import _resize_flow, backward_warp, local_correlation

    g = torch.Generator().manual_seed(0)
    x = torch.rand(1, 4, 12, 14, generator=g)
    f = torch.zeros(1, 2, 12, 14)
    f[:, 0], f[:, 1] = 2.0, -1.0
    w = backward_warp(x, f)
    assert torch.allclose(w[..., 1:, :12], x[..., :-1, 2:], atol=1e-6)
    y = torch.roll(x, shifts=(1, -2), dims=(2, 3))  # y(u, v) = x(u + 2, v - 1): x moved by (dx, dy) = (-2, +1)
    corr = local_correlation(x, y, 2)
    r = 2
    k = (1 + r) * (2 * r + 1) + (-2 + r)  # row-major over (dy, dx)
    assert int(corr[0, :, 4:-4, 4:-4].mean((1, 2)).argmax()) == k
    lin = torch.stack(torch.meshgrid(torch.linspace(0, 3, 4), torch.linspace(0, 5, 6), indexing="ij")[::-1])[None]  # flow = (u, v)
    big = _resize_flow(lin, (7, 11))  # a flow linear in position stays (u, v) in the new pixels
    yy, xx = torch.meshgrid(torch.arange(7.0), torch.arange(11.0), indexing="ij")
    assert torch.allclose(big[0, 0], xx, atol=1e-5) and torch.allclose(big[0, 1], yy, atol=1e-5)


def test_weights_with_a_pickle_payload_do_not_run(tmp_path):
    """predict_sceneflow.py loads weights with weights_only=True: a crafted file is refused, its code not run."""
    class Payload:  # unpickling it writes the marker (what an attacker's file would do)
        def __reduce__(self):
            return (exec, (f"open({str(marker)!r}, 'w').write('payload ran')",))

    marker = tmp_path / "pwned.txt"
    torch.save({"model": {}, "config": Payload()}, tmp_path / "w.pt")
    r = _script("predict_sceneflow", tmp_path, tmp_path, "-o", tmp_path / "o", "--weights", tmp_path / "w.pt")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "not a weights file" in r.stderr, r.stderr
    assert not marker.exists()
    torch.load(tmp_path / "w.pt", weights_only=False)  # the file's payload is real
    assert marker.exists()
