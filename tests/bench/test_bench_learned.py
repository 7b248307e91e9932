"""Baseline (c) of `lfusd bench`: flow/predict_sceneflow.py --bench writes, from the public test
inputs alone, a submission of the learned scene-flow network (weights trained for a few steps here
on the benchmark's public train scene) that `lfusd bench score` scores; every view is predicted with
itself as the network's reference, which submission.json says; a grid the weights do not fit is
refused in one line before anything is written."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch

from support.cli import run_cli
from support.flow_scripts import load_script

from lfusd.data.dataset import Dataset


@pytest.fixture(scope="module")
def public_only(tiny_bench, tmp_path_factory):
    """The benchmark's bench.json and public/ alone (no render/, no gt/): what a participant has."""
    code, root = tiny_bench
    assert code == 0
    dest = tmp_path_factory.mktemp("public") / "bench"
    dest.mkdir()
    shutil.copy(root / "bench.json", dest / "bench.json")
    shutil.copytree(root / "public", dest / "public")
    return root, dest


def _weights(train_scene, path, ang: int | None = None):
    """A tiny SceneFlowNet trained for 3 steps on frames 1 -> 2 of the public train scene (the centre
    view as reference, as train_sceneflow.py trains), saved as its checkpoints hold it; untrained
    for a grid of ``ang`` x ``ang`` views."""
    tsf = load_script("train_sceneflow")
    ds = Dataset(train_scene)
    views = sorted(tuple(v) for v in ds.views)
    centre = views.index(tuple(ds.rig.centre_view))
    config = {"ang": ang or ds.rig.rows, "d_min": -1.0, "d_max": 4.0, "disparities": 9, "channels": 4, "blocks": 1, "cost_channels": 4,
              "flow_channels": 4, "flow_levels": 2, "radius": 2, "train_frames": [1], "eval_frames": [1]}
    torch.manual_seed(0)
    model = tsf.build(config)
    if ang is not None:  # weights for another grid: untrained
        torch.save({"model": model.state_dict(), "config": config}, path)
        return path
    v0, v1 = tsf.load_pair(ds, 1, views)
    off = np.array([ds.rig.offsets(v) for v in views])
    rel = torch.from_numpy(off - off[centre]).to(torch.float32)[None]
    disp = torch.from_numpy(np.nan_to_num(np.asarray(ds.read(1, views[centre], "disparity"), np.float32)))
    flow = torch.from_numpy(np.nan_to_num(np.asarray(ds.read(1, views[centre], "flow_fwd"), np.float32))).permute(2, 0, 1)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    for _ in range(3):
        out = model(v0[None], v1[None], rel, centre)
        loss = (out["disparity"][0] - disp).abs().mean() + torch.linalg.vector_norm(out["flow"][0] - flow, dim=0).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    torch.save({"model": model.state_dict(), "config": config}, path)
    return path


@pytest.mark.render
def test_the_learned_network_writes_a_submission_that_the_scorer_scores(public_only, tmp_path, capsys):
    root, public = public_only
    (train_scene,) = (public / "public" / "train").iterdir()
    w = _weights(train_scene, tmp_path / "w.pt")
    psf = load_script("predict_sceneflow")
    sub = tmp_path / "learned"
    threads = torch.get_num_threads()
    try:
        assert psf.training.main_wrapper(psf.NAME, psf.main, ["--bench", str(public), "-o", str(sub), "--weights", str(w), "--threads", "1"]) == 0
    finally:
        torch.set_num_threads(threads)
    rec = json.loads((root / "bench.json").read_text())
    (scene,) = rec["splits"]["test"]
    gt = Dataset(root / "gt" / scene)
    want = sorted(f"{f:04d}_{r:02d}_{c:02d}.npz" for f in gt.frames[:-1] for r, c in (tuple(v) for v in gt.views))
    assert sorted(p.name for p in (sub / scene).iterdir()) == want  # every view of every scored frame
    meta = json.loads((sub / "submission.json").read_text())
    assert meta["views"] == "every view" and "itself as the network's reference" in meta["reference"]
    # each view's file is the network with that view as its reference (offsets from it, flow on its own pair)
    tsf = load_script("train_sceneflow")
    model, _ = psf.load_model(w)
    views = sorted(tuple(v) for v in gt.views)
    cams = json.loads((public / "public" / "test" / scene / "cameras.json").read_text())
    off = np.array([cams["offsets"][f"{r:02d}_{c:02d}"] for r, c in views])
    from lfusd.data.formats import read_png

    def load(f):
        a = np.stack([read_png(public / "public" / "test" / scene / "rgb" / f"{f:04d}_{r:02d}_{c:02d}.png") for r, c in views])
        return torch.from_numpy(a.astype(np.float32) / 255).permute(0, 3, 1, 2)

    f = gt.frames[0]
    i = len(views) - 1  # a corner view, not the centre
    res = tsf.predict(model, load(f), load(f + 1), torch.from_numpy(off - off[i]).to(torch.float32), i)
    with np.load(sub / scene / f"{f:04d}_{views[i][0]:02d}_{views[i][1]:02d}.npz") as z:
        assert np.allclose(z["disparity"], res["disparity"], atol=1e-5) and np.allclose(z["flow"], res["flow"], atol=1e-5)
        assert np.isfinite(z["scene_flow"]).all()
    # lfusd bench score scores it
    code, out, _ = run_cli(capsys, "bench", "score", sub, "--bench", root, "--method", "(c) learned")
    assert code == 0 and "| (c) learned |" in out
    res = json.loads((sub / "score.json").read_text())["overall"]["all"]
    assert res["epe_px"] > 0 and res["epe3d_m"] > 0 and res["pixels_motion"] > 0


@pytest.mark.render
def test_weights_for_another_grid_are_refused_in_one_line_before_writing(public_only, tmp_path, capsys):
    _, public = public_only
    (train_scene,) = (public / "public" / "train").iterdir()
    w = _weights(train_scene, tmp_path / "w3.pt", ang=3)
    psf = load_script("predict_sceneflow")
    code = psf.training.main_wrapper(psf.NAME, psf.main, ["--bench", str(public), "-o", str(tmp_path / "sub"), "--weights", str(w)])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "the weights are for 3x3 views" in err
    assert not (tmp_path / "sub").exists()


@pytest.mark.render
def test_training_reads_a_benchmarks_public_train_and_val_scenes_and_never_its_test(public_only):
    """train_sceneflow.py --data BENCH: flow/training.recipe_scenes lists public/<split>/ of the
    record's scenes; the test split (ground truth not public) is refused in one line."""
    from lfusd import LfusdError

    _, public = public_only
    training = load_script("training")
    rec = json.loads((public / "bench.json").read_text())
    for split in ("train", "val"):
        assert training.recipe_scenes(public, split) == [public / "public" / split / s for s in rec["splits"][split]]
    with pytest.raises(LfusdError, match="train and val splits only") as e:
        training.recipe_scenes(public, "test")
    assert "\n" not in str(e.value)
