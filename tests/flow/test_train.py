"""flow/train_disparity.py and flow/train_asr.py --tiny: they render (or reuse) a tiny dataset,
the loss decreases, checkpoints resume where they stopped, and the trained model is scored
through `lfusd eval` (the same numbers as the command on the prediction folder)."""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from support.flow_scripts import load_script, run_script

ROOT = Path(__file__).resolve().parents[2]


def _script(name: str, *args) -> tuple[subprocess.CompletedProcess, float]:
    t0 = time.time()
    r = run_script(name, *args, timeout=600)
    return r, time.time() - t0


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    """Where the first run renders the tiny dataset and the second reuses it."""
    return tmp_path_factory.mktemp("learned") / "tiny_data"


def _load(name: str):
    return load_script(name)


def _bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sample (C,H,W) at float pixel positions; also where all four neighbours are inside."""
    c, h, w = img.shape
    u0, v0 = np.floor(u).astype(int), np.floor(v).astype(int)
    inside = (u0 >= 0) & (v0 >= 0) & (u0 + 1 < w) & (v0 + 1 < h)
    u0, v0 = np.clip(u0, 0, w - 2), np.clip(v0, 0, h - 2)
    a, b = u - u0, v - v0
    out = (1 - a) * (1 - b) * img[:, v0, u0] + a * (1 - b) * img[:, v0, u0 + 1] + (1 - a) * b * img[:, v0 + 1, u0] + a * b * img[:, v0 + 1, u0 + 1]
    return out, inside


@pytest.mark.render
def test_the_training_items_true_disparity_aligns_the_rendered_views(data_dir):
    """What train_disparity.py trains on obeys CONVENTIONS.md: the centre pixel (u, v) at disparity d
    is seen at (u - d*sx, v - d*sy) in the view at relative offset (sx, sy)."""
    _load("training").tiny_dataset(data_dir)
    views, rel, gt, frame = _load("train_disparity").CentreDisparity(data_dir, [1], None, False)[0]
    views, rel, gt = views.numpy().astype(np.float64), rel.numpy().astype(np.float64), gt.numpy().astype(np.float64)
    centre = int(np.flatnonzero((rel == 0).all(1))[0])
    h, w = gt.shape
    vv, uu = np.mgrid[0:h, 0:w].astype(float)
    errs = {"true": [], "zero": [], "flipped": []}
    for i, (sx, sy) in enumerate(rel):
        if i == centre:
            continue
        for name, d in (("true", gt), ("zero", np.zeros_like(gt)), ("flipped", -gt)):
            warped, inside = _bilinear(views[i], uu - d * sx, vv - d * sy)
            m = inside & (gt > 1.0)  # a surface that moves by more than a pixel between neighbours
            errs[name].append(np.abs(warped - views[centre]).mean(0)[m])
    true, zero, flipped = (np.concatenate(errs[k]) for k in ("true", "zero", "flipped"))
    assert true.size > 1000, true.size
    # most of these surfaces are plain, so compare where colour varies: the 90th percentile
    p90 = {k: np.percentile(np.concatenate(e), 90) for k, e in errs.items()}
    assert p90["true"] < 0.5 * p90["zero"] < 0.5 * p90["flipped"], (p90, true.size)
    assert np.mean(true) < 0.6 * np.mean(zero), (np.mean(true), np.mean(zero))


def _check_run(name: str, task: str, data: Path, out: Path, main_key: str, capsys) -> None:
    first, seconds = _script(name, "--tiny", "--data", data, "--out", out, "--steps", 80, "--quiet")
    assert first.returncode == 0, first.stderr
    with capsys.disabled():
        print(f"\n{name} --tiny --steps 80 (rendering included when needed): {seconds:.1f} s")
    logd = json.loads((out / "train_log.json").read_text())
    losses = [h["loss"] for h in logd["history"]]
    assert [h["step"] for h in logd["history"]] == list(range(1, 81))
    assert np.mean(losses[-10:]) < 0.8 * np.mean(losses[:10]), losses
    ckpt = torch.load(out / "checkpoints" / "last.pt", map_location="cpu", weights_only=False)
    assert ckpt["step"] == 80 and ckpt["optimizer"]["state"]

    # the scores are lfusd eval's on the prediction folder, with the pixels each compared
    ev = json.loads((out / "pred" / f"eval_{task}.json").read_text())
    assert ev["rows"] and all(r["pixels"] > 0 for r in ev["rows"])
    from lfusd.cli import main as lfusd_main

    again = out / "again.json"
    assert lfusd_main(["eval", "--task", task, "--pred", str(out / "pred"), "--gt", str(data), "--json", str(again), "--csv", str(out / "again.csv")]) == 0
    cli = json.loads(again.read_text())
    assert [(r["frame"], r["row"], r["col"]) for r in cli["rows"]] == [(r["frame"], r["row"], r["col"]) for r in ev["rows"]]
    assert np.allclose([r[main_key] for r in cli["rows"]], [r[main_key] for r in ev["rows"]], rtol=1e-12)
    summary = json.loads((out / "eval.json").read_text())
    assert summary["model"]["pixels"] == sum(r["pixels"] for r in ev["rows"]) and "plane_sweep" in summary

    # --resume continues from step 80 with the optimiser state: steps 81..100, losses near where they stopped
    second, _ = _script(name, "--out", out, "--resume", "--steps", 100, "--quiet")
    assert second.returncode == 0, second.stderr
    logd = json.loads((out / "train_log.json").read_text())
    assert logd["resumed_at"] == [80]
    assert [h["step"] for h in logd["history"]] == list(range(1, 101))
    resumed = [h["loss"] for h in logd["history"][80:90]]
    assert np.mean(resumed) < 0.8 * np.mean(losses[:10]), (resumed, losses[:10])
    assert torch.load(out / "checkpoints" / "last.pt", map_location="cpu", weights_only=False)["step"] == 100


@pytest.mark.render
@pytest.mark.slow
def test_train_disparity_tiny(data_dir, tmp_path, capsys):
    _check_run("train_disparity", "disparity", data_dir, tmp_path / "disp", "mse_x100", capsys)


@pytest.mark.render
@pytest.mark.slow
def test_train_asr_tiny(data_dir, tmp_path, capsys):
    _check_run("train_asr", "views", data_dir, tmp_path / "asr", "psnr_db", capsys)


def test_errors_are_one_line(tmp_path):
    r, _ = _script("train_disparity", "--data", tmp_path / "missing", "--out", tmp_path / "run")
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [f"train_disparity: error: {tmp_path / 'missing'} holds no lfusd dataset (manifest.json missing); render one with lfusd render-video"]
    r, _ = _script("train_asr", "--out", tmp_path / "run2", "--resume")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "run once without --resume" in r.stderr
