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


def test_every_view_references_are_drawn_per_batch_from_the_seed_alone():
    """Samples(references=N, batch=B): the B samples of a batch share one reference view (the network
    takes one per batch), drawn from the run's seed and the batch number alone (a resumed run or
    another process draws the same), and over many batches every view is drawn."""
    tsf = load_script("train_sceneflow")
    item = {"rgb": np.zeros((2, 9, 3, 4, 4), np.float32), "views": np.array([[r, c] for r in range(3) for c in range(3)])}
    plain = dict(refocus=0, flip=False)

    def refs(seed, n):
        samples = tsf.Samples([[item]], seed, plain, 0, references=9, batch=3)
        return [samples[i]["ref"] for i in range(n)]

    got = refs(7, 300)
    assert all(got[i] == got[i - i % 3] for i in range(300))  # one view per batch of 3
    assert set(got) == set(range(9))  # every view, over 100 batches
    assert refs(7, 300) == got and refs(8, 300) != got  # the seed alone decides
    assert "ref" not in tsf.Samples([[item]], 7, plain, 0)[0]  # the centre-only default


@pytest.mark.render
def test_a_run_on_every_reference_view_records_it_for_predict(video, tmp_path):
    """--references all: the run trains (each step on the drawn view's ground truth) and its checkpoint
    says so, which a benchmark submission reports."""
    train = _train_main()
    threads = torch.get_num_threads()
    try:
        assert train(["--tiny", "--data", str(video), "--out", str(tmp_path / "run"), "--steps", "2", "--references", "all", "--no-baselines", "--quiet"]) == 0
    finally:
        torch.set_num_threads(threads)
    state = torch.load(tmp_path / "run" / "checkpoints" / "last.pt", weights_only=True)
    assert state["step"] == 2 and state["config"]["references"] == "all"
    log = json.loads((tmp_path / "run" / "train_log.json").read_text())
    assert all(np.isfinite(h["loss"]) for h in log["history"])


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


def _disparity_checkpoint(path: Path, ang: int = 3) -> dict:
    """A train_disparity.py-shaped checkpoint of a tiny StarDisparityNet (seeded weights)."""
    from support.flow_scripts import load_script

    config = {"ang": ang, "d_min": -2.0, "d_max": 3.0, "arch": "star", "disparities": 5, "channels": 4, "blocks": 1, "cost_channels": 4}
    torch.manual_seed(7)
    model = load_script("train_disparity").build(config)
    torch.save({"model": model.state_dict(), "config": config}, path)
    return model.state_dict()


@pytest.mark.render
def test_training_from_disparity_weights_keeps_them_when_frozen_and_predict_loads_the_run(video, tmp_path):
    """--disparity-weights starts the disparity half from a train_disparity checkpoint (its
    architecture and candidates); with --freeze-disparity those weights come out unchanged while the
    flow network trains, without it they train too; predict_sceneflow builds the same network."""
    given = _disparity_checkpoint(tmp_path / "disp.pt")
    from models import StarDisparityNet  # flow/ is on the path now
    train = _train_main()
    threads = torch.get_num_threads()
    common = ["--tiny", "--data", str(video), "--no-baselines", "--quiet", "--disparity-weights", str(tmp_path / "disp.pt")]
    try:
        assert train([*common, "--out", str(tmp_path / "frozen"), "--freeze-disparity", "--steps", "1"]) == 0
        first = torch.load(tmp_path / "frozen" / "checkpoints" / "last.pt", weights_only=True)
        assert train(["--out", str(tmp_path / "frozen"), "--resume", "--steps", "3", "--quiet", "--no-baselines"]) == 0  # frozen again on resume
        assert train([*common, "--out", str(tmp_path / "free"), "--steps", "3"]) == 0
    finally:
        torch.set_num_threads(threads)
    frozen, free = (torch.load(tmp_path / n / "checkpoints" / "last.pt", weights_only=True) for n in ("frozen", "free"))
    assert frozen["step"] == 3 and frozen["config"]["disparity_net"]["arch"] == "star" and frozen["config"]["freeze_disparity"]
    assert (frozen["config"]["d_min"], frozen["config"]["d_max"]) == (-2.0, 3.0)  # the given network's candidates
    for k, v in given.items():
        assert torch.equal(frozen["model"][f"disparity.{k}"], v), k  # untouched: no arithmetic on a frozen tensor
    assert any(not torch.equal(free["model"][f"disparity.{k}"], v) for k, v in given.items() if v.is_floating_point())
    assert any(not torch.equal(frozen["model"][k], first["model"][k]) for k in first["model"] if k.startswith("flow."))  # the flow trains
    sys.path.insert(0, str(ROOT / "flow"))
    import predict_sceneflow

    model, config = predict_sceneflow.load_model(tmp_path / "frozen" / "checkpoints" / "last.pt")
    assert isinstance(model.disparity, StarDisparityNet) and config["disparity_net"]["disparities"] == 5


@pytest.mark.render
def test_disparity_weights_are_refused_in_one_line_when_they_do_not_fit(video, tmp_path):
    _disparity_checkpoint(tmp_path / "disp5.pt", ang=5)
    r = _script("train_sceneflow", "--tiny", "--data", video, "--out", tmp_path / "a", "--steps", 1, "--quiet", "--disparity-weights", tmp_path / "disp5.pt")
    last = r.stderr.strip().splitlines()[-1]
    assert r.returncode == 2 and "5x5 grid" in last and last.startswith("train_sceneflow: error:") and r.stderr.count("error") == 1, r.stderr
    r = _script("train_sceneflow", "--tiny", "--data", video, "--out", tmp_path / "b", "--steps", 1, "--quiet", "--freeze-disparity")
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [r.stderr.strip()] and "--disparity-weights" in r.stderr, r.stderr


def _recipe_of(video: Path, root: Path) -> Path:
    """A made recipe dataset whose scenes are the video (one `things` train scene, one held-out
    `street` test scene), with the records `lfusd dataset make` writes for verified scenes."""
    import lfusd.recipe as rc
    from lfusd import layout

    root.mkdir()
    (root / layout.RECIPE_COPY).write_text(
        '[dataset]\nname = "t"\ngrid = [3, 3]\nresolution = [40, 32]\nheld_out = ["street"]\n'
        '[[part]]\nname = "train"\nsplit = "train"\ntemplates = ["things"]\nscenes = 1\n'
        '[[part]]\nname = "test"\nsplit = "test"\ntemplates = ["street"]\nscenes = 1\nfirst_seed = 100\n')
    (root / layout.RECIPE_SCENES).mkdir()
    for spec in rc.scene_specs(rc.load_recipe(root / layout.RECIPE_COPY)):
        (root / layout.RECIPE_SCENES / spec.name).symlink_to(video, target_is_directory=True)
        rec = {"version": rc.RECORD_VERSION, "spec": rc._spec_dict(spec), "verified": True}
        (root / layout.RECIPE_SCENES / f"{spec.name}.json").write_text(json.dumps(rec))
    return root


@pytest.mark.render
def test_a_recipe_run_trains_on_its_train_split_and_scores_every_pair_of_the_test_split(video, tmp_path):
    """--data RECIPE_OUT: the run trains on the train split's scenes (their caches under --cache)
    and scores every pair t -> t+1 of each test scene beside the composition, pooled per template
    over every scored pixel."""
    from lfusd.cli import main
    from lfusd.recipe import split_scenes

    root = _recipe_of(video, tmp_path / "recipe")
    (train_scene,), (test_scene,) = split_scenes(root)["train"], split_scenes(root)["test"]
    caches = tmp_path / "caches"
    assert main(["export", "cache", str(train_scene), str(caches / train_scene.name), "--keys", "rgb,disparity,flow_fwd,disparity_change,valid_fwd"]) == 0
    train = _train_main()
    threads = torch.get_num_threads()
    try:
        assert train(["--tiny", "--data", str(root), "--cache", str(caches), "--out", str(tmp_path / "run"), "--steps", "2", "--quiet"]) == 0
    finally:
        torch.set_num_threads(threads)
    config = torch.load(tmp_path / "run" / "checkpoints" / "last.pt", weights_only=True)["config"]
    assert config["scenes"] == [str(train_scene)] and config["caches"] == [str(caches / train_scene.name)]
    ev = json.loads((tmp_path / "run" / "eval.json").read_text())
    assert ev["split"] == "test" and list(ev["scenes"]) == [test_scene.name] and set(ev["groups"]) == {"street", "all"}
    scored = sorted(p.name for p in (tmp_path / "run" / "test" / test_scene.name / "pred").glob("*.npy"))
    assert scored == ["0001_01_01.npy", "0002_01_01.npy", "0003_01_01.npy"]  # every pair of the 4 frames
    for method in ("model", "model_flow", "composition", "composition_flow"):
        one = ev["scenes"][test_scene.name][method]
        assert ev["pooled"][method]["pixels"] == one["pixels"] > 0
        assert all(np.isclose(ev["pooled"][method][k], v) for k, v in one.items() if isinstance(v, float))


def test_pooling_weights_each_scene_by_its_scored_pixels():
    from support.flow_scripts import load_script

    pool = load_script("train_sceneflow").pool
    got = pool([{"m": {"epe3d_m": 1.0, "fl_pct": 10.0, "pixels": 1}}, {"m": {"epe3d_m": 2.0, "fl_pct": 30.0, "pixels": 3}}])
    assert got == {"m": {"epe3d_m": 1.75, "fl_pct": 25.0, "pixels": 4}}


def test_star_disparity_weights_are_refused_for_a_benchmark_submission_in_one_line(tmp_path):
    """The star disparity network predicts the centre view only; --bench scores every view."""
    from support.flow_scripts import load_script

    tsf = load_script("train_sceneflow")
    disparity_net = {"ang": 3, "d_min": -2.0, "d_max": 3.0, "arch": "star", "disparities": 5, "channels": 4, "blocks": 1, "cost_channels": 4}
    config = {"ang": 3, "d_min": -2.0, "d_max": 3.0, "disparities": 5, "channels": 4, "blocks": 1, "cost_channels": 4, "flow_channels": 4,
              "flow_levels": 2, "radius": 1, "disparity_net": disparity_net}
    torch.save({"model": tsf.build(config).state_dict(), "config": config}, tmp_path / "sf.pt")
    r = _script("predict_sceneflow", "--bench", tmp_path / "no_bench", "-o", tmp_path / "sub", "--weights", tmp_path / "sf.pt")
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [r.stderr.strip()] and "centre view only" in r.stderr, r.stderr
    assert not (tmp_path / "sub").exists()


def test_the_dis_refining_flow_network_starts_as_dis_and_learns_a_correction():
    """models.DISRefineFlow: untrained, exactly OpenCV's DIS flow (the composition baseline's); a few
    steps towards a target move it off DIS."""
    from support.flow_scripts import load_script

    from lfusd.evaluation.baselines import dis_flow

    models = load_script("models")
    rng = np.random.default_rng(3)
    img = rng.uniform(0, 1, (40, 48, 3)).astype(np.float32)
    img0, img1 = img[4:36, 4:44], img[3:35, 6:46]  # frame t+1 shows the texture moved by (-2, 1)
    t0, t1 = (torch.from_numpy(np.ascontiguousarray(a)).permute(2, 0, 1)[None] for a in (img0, img1))
    net = models.DISRefineFlow(8, 2)
    with torch.no_grad():
        got = net(t0, t1)[0].permute(1, 2, 0).numpy()
    np.testing.assert_allclose(got, dis_flow(img0, img1), atol=1e-6)
    opt = torch.optim.Adam(net.parameters(), 1e-2)
    target = torch.zeros(1, 2, 32, 40)
    target[:, 0], target[:, 1] = -2.0, 1.0
    for _ in range(3):
        loss = (net(t0, t1) - target).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        assert not np.allclose(net(t0, t1)[0].permute(1, 2, 0).numpy(), dis_flow(img0, img1), atol=1e-3)
