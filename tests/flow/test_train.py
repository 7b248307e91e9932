"""flow/train_disparity.py and flow/train_asr.py --tiny: they render (or reuse) a tiny dataset,
the loss decreases, checkpoints resume where they stopped, and the trained model is scored
through `lfusd eval` (the same numbers as the command on the prediction folder)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

ROOT = Path(__file__).resolve().parents[2]


def _script(name: str, *args) -> tuple[subprocess.CompletedProcess, float]:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    t0 = time.time()
    r = subprocess.run([sys.executable, str(ROOT / "flow" / f"{name}.py"), *map(str, args)], env=env, capture_output=True, text=True, timeout=600)
    return r, time.time() - t0


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    """Where the first run renders the tiny dataset and the second reuses it."""
    return tmp_path_factory.mktemp("learned") / "tiny_data"


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
    _check_run("train_asr", "views", data_dir, tmp_path / "asr", "psnr", capsys)


def test_errors_are_one_line(tmp_path):
    r, _ = _script("train_disparity", "--data", tmp_path / "missing", "--out", tmp_path / "run")
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [f"train_disparity: error: {tmp_path / 'missing'} holds no lfusd dataset (manifest.json missing); render one with lfusd render-video"]
    r, _ = _script("train_asr", "--out", tmp_path / "run2", "--resume")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "run once without --resume" in r.stderr
