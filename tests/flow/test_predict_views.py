"""flow/predict_views.py (angular super-resolution, 2x2 -> n x n) and flow/train_asr.py on a recipe.

A synthetic 9x9 HCI-layout folder of a textured plane goes through the script with a 2x2 -> 7x7
ASRNet trained for a few steps inside the test: it writes the 7x7 views in HCI's naming, the
corners are the input's cameras 10, 16, 64, 70 bit for bit (DistgASR's central 7x7 of 9x9), the
others are the network's outputs on those corners, tiles stitch to the whole-image result. On a
rendered scene, train_asr.py trains from a recipe's train split (through a training cache),
resumes, scores the test split beside the baselines, and the script gives the same views on the
dataset folder and on its `lfusd export hci` folder. Errors are one line, exit 2."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from lfusd.data import formats
from support.flow_scripts import load_script, run_main, run_script
from support.light_fields import plane_tensor, plane_views, write_hci

N, SIZE = 9, 20


@pytest.fixture(scope="module")
def weights(tmp_path_factory):
    """A tiny 2x2 -> 7x7 ASRNet trained for 30 steps on random planes (seconds), saved as train_asr.py's checkpoints hold it."""
    ta = load_script("train_asr")
    torch.manual_seed(0)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    rng = np.random.default_rng(0)
    config = {"n": 7, "channels": 8, "blocks": 1, "train_frames": [1], "eval_frames": [1]}
    model = ta.build(config)
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    for _ in range(30):
        lf = plane_tensor(float(rng.uniform(-1, 1)), rng, 16, n=7)
        loss = (model(lf[:, [0, 6, 42, 48]])[0] - lf[0]).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    torch.set_num_threads(threads)
    path = tmp_path_factory.mktemp("asr_weights") / "w.pt"
    torch.save({"model": model.state_dict(), "config": config}, path)
    return path


def _pngs(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def test_an_hci_folder_gives_the_central_7x7_in_hcis_naming(tmp_path, weights, capsys):
    pv = load_script("predict_views")
    lf = write_hci(tmp_path / "lf", plane_views(0.8, np.random.default_rng(1), SIZE))
    r = run_script("predict_views", lf, "-o", tmp_path / "out", "--weights", weights, "--threads", 1)  # the command line, its own process
    assert r.returncode == 0, r.stderr
    out = tmp_path / "out"
    assert _pngs(out) == [f"input_Cam{i:03d}.png" for i in range(49)]
    got = np.stack([formats.read_png(out / f"input_Cam{i:03d}.png") for i in range(49)])
    assert got.shape == (49, SIZE, SIZE, 3) and got.dtype == np.uint8
    # the corners of the central 7x7 of 9x9: rows and columns 1 and 7, HCI cameras 10, 16, 64, 70, copied bit for bit
    src = {i: formats.read_png(lf / f"input_Cam{i:03d}.png") for i in (10, 16, 64, 70)}
    for k, i in ((0, 10), (6, 16), (42, 64), (48, 70)):
        assert np.array_equal(got[k], src[i]), (k, i)
    # every other view is the network's on those corners (in that order), rounded to 8 bits
    model, config = pv.load_model(weights)
    corners = np.stack([src[i].astype(np.float32) / 255 for i in (10, 16, 64, 70)])
    whole = pv.predict(model, corners, tile=128, overlap=0)
    novel = [k for k in range(49) if k not in (0, 6, 42, 48)]
    assert np.abs(got[novel].astype(float) - whole[novel] * 255).max() <= 0.5 + 1e-3
    # tiles with enough context stitch to the whole-image result
    assert np.abs(pv.predict(model, corners, tile=8, overlap=12) - whole).max() < 1e-5
    # 16-bit views give 16-bit views
    lf16 = write_hci(tmp_path / "lf16", plane_views(0.8, np.random.default_rng(1), SIZE), bits=16)
    code, err = run_main("predict_views", capsys, lf16, "-o", tmp_path / "out16", "--weights", weights, "--threads", 1)
    assert code == 0, err
    a = formats.read_png(tmp_path / "out16" / "input_Cam024.png")
    assert a.dtype == np.uint16 and np.abs(a / 65535.0 - got[24] / 255.0).max() < 2.5 / 255


def test_errors_are_one_line_and_write_nothing(tmp_path, weights, capsys):
    if not load_script("predict_views").SHIPPED.is_file():  # no weights shipped yet: --weights is required
        r = run_script("predict_views", tmp_path, "-o", tmp_path / "o")
        assert r.returncode == 2 and r.stderr.strip().splitlines() == [
            "predict_views: error: no --weights given and no shipped weights (flow/weights/asr.pt) yet; train with flow/train_asr.py "
            "and pass --weights OUT/checkpoints/last.pt"]
    few = write_hci(tmp_path / "few", plane_views(0.5, np.random.default_rng(3), SIZE)[:80])  # one view short of 9x9
    code, err = run_main("predict_views", capsys, few, "-o", tmp_path / "o", "--weights", weights)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "N*N of them" in err
    small = write_hci(tmp_path / "small", plane_views(0.5, np.random.default_rng(3), SIZE, n=5))  # 5x5 < the weights' 7x7
    code, err = run_main("predict_views", capsys, small, "-o", tmp_path / "o", "--weights", weights)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "has only 5x5" in err
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    code, err = run_main("predict_views", capsys, small, "-o", tmp_path / "o", "--weights", tmp_path / "bad.pt")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "not a weights file" in err
    code, err = run_main("predict_views", capsys, tmp_path / "nowhere", "-o", tmp_path / "o", "--weights", weights)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "is not a folder" in err
    assert not (tmp_path / "o").exists()
    # an output folder holding views is not overwritten unless asked
    lf = write_hci(tmp_path / "lf", plane_views(0.5, np.random.default_rng(4), SIZE))
    code, err = run_main("predict_views", capsys, lf, "-o", small, "--weights", weights)
    assert code == 2 and "already holds input_CamNNN.png" in err and len(list(small.glob("*.png"))) == 25


def _recipe(root: Path, scene: Path) -> Path:
    """A made recipe dataset of one train and one test scene, both the rendered ``scene`` (its records
    as `lfusd dataset make` writes them): the machinery's check, not a generalisation test."""
    from lfusd.recipe import RECORD_VERSION, _spec_dict, load_recipe, scene_specs

    root.mkdir()
    (root / "recipe.toml").write_text("[dataset]\nname = 't'\ngrid = [3, 3]\nresolution = [32, 32]\nheld_out = ['street']\n"
                                      "[[part]]\nname = 'a'\ntemplates = ['things']\nscenes = 1\nsplit = 'train'\n"
                                      "[[part]]\nname = 'c'\ntemplates = ['street']\nscenes = 1\nsplit = 'test'\n")
    (root / "scenes").mkdir()
    for s in scene_specs(load_recipe(root / "recipe.toml")):
        shutil.copytree(scene, root / "scenes" / s.name)
        (root / "scenes" / f"{s.name}.json").write_text(json.dumps({"version": RECORD_VERSION, "spec": _spec_dict(s), "verified": True}))
    return root


@pytest.mark.render
def test_train_asr_on_a_recipe_and_predict_views_on_a_dataset_and_its_hci_export(tmp_path):
    from lfusd.author.scenes import generate
    from lfusd.cli import main

    generate("things", tmp_path / "s.usda", 3, frames=1, rigs=1, grid=(3, 3), resolution=(32, 32))
    assert main(["render", str(tmp_path / "s.usda"), "-o", str(tmp_path / "ds"), "--rig", "rig_00", "--samples", "1",
                 "--device", "cpu", "--quiet"]) == 0
    recipe = _recipe(tmp_path / "recipe", tmp_path / "ds")
    train_name, test_name = sorted(p.name for p in (recipe / "scenes").iterdir() if p.is_dir())
    caches = tmp_path / "caches"
    assert main(["export", "cache", str(recipe / "scenes" / train_name), str(caches / train_name), "--keys", "rgb"]) == 0
    run = tmp_path / "run"
    args = ("--data", recipe, "--cache", caches, "--out", run, "--n", 3, "--channels", 8, "--blocks", 1, "--batch", 2, "--crop", 16,
            "--save-every", 2, "--log-every", 1, "--threads", 1, "--quiet")
    r = run_script("train_asr", *args, "--steps", 3)
    assert r.returncode == 0, r.stderr
    log = json.loads((run / "train_log.json").read_text())
    assert log["config"]["scenes"] == [str(recipe / "scenes" / train_name)] and log["config"]["caches"] == [str(caches / train_name)]
    r = run_script("train_asr", "--out", run, "--resume", "--steps", 5, "--log-every", 1, "--quiet", "--threads", 1)
    assert r.returncode == 0, r.stderr
    log = json.loads((run / "train_log.json").read_text())
    assert log["resumed_at"] == [3] and [h["step"] for h in log["history"]] == [1, 2, 3, 4, 5]
    # scored on the test split's scene, beside angular blending and the per-view plane sweep, through lfusd eval
    scores = json.loads((run / "eval.json").read_text())
    assert set(scores) == {"model", "blend", "plane_sweep", "scenes"} and list(scores["scenes"]) == [test_name]
    for method, folder in (("model", "pred"), ("blend", "pred_blend"), ("plane_sweep", "pred_plane_sweep")):
        files = sorted(p.name for p in (run / "test" / test_name / folder).glob("*.npy"))
        assert files == [f"0001_{r:02d}_{c:02d}.npy" for r in range(3) for c in range(3) if (r, c) not in ((0, 0), (0, 2), (2, 0), (2, 2))]
        assert scores[method]["views"] == 5 and 5 < scores[method]["psnr_db"] < 80 and 0 < scores[method]["ssim"] <= 1
    # a training cache of the wrong scene (rgb missing) is refused in one line
    r = run_script("train_asr", "--data", recipe, "--cache", tmp_path / "nocache", "--out", tmp_path / "run2", "--n", 3, "--steps", 1, "--quiet")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "is no training cache" in r.stderr
    # predict_views: the dataset folder and its HCI export give the same views
    w = run / "checkpoints" / "last.pt"
    assert main(["export", "hci", str(tmp_path / "ds"), str(tmp_path / "hci")]) == 0
    (hci,) = (tmp_path / "hci").iterdir()
    for src, out in ((tmp_path / "ds", tmp_path / "va"), (hci, tmp_path / "vb")):
        r = run_script("predict_views", src, "-o", out, "--weights", w, "--threads", 1, "--frame", 1) if src.name == "ds" else \
            run_script("predict_views", src, "-o", out, "--weights", w, "--threads", 1)
        assert r.returncode == 0, r.stderr
        assert _pngs(out) == [f"input_Cam{i:03d}.png" for i in range(9)]
    for i in range(9):
        a, b = formats.read_png(tmp_path / "va" / f"input_Cam{i:03d}.png"), formats.read_png(tmp_path / "vb" / f"input_Cam{i:03d}.png")
        assert a.shape == (32, 32, 3) and np.array_equal(a, b), i
