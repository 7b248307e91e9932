"""Checkpoints from elsewhere (issue 29): ``--resume`` loads OUT/checkpoints/last.pt as tensors and
plain data only, so a crafted pickle cannot run code, and checks its fields before using them."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch
from support.flow_scripts import run_script

ROOT = Path(__file__).resolve().parents[2]


class Payload:
    """Unpickling this runs code: it writes the marker file (what an attacker's checkpoint would do)."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (exec, (f"open({self.marker!r}, 'w').write('payload ran')",))


def _training():
    sys.path.insert(0, str(ROOT / "flow"))
    import training

    return training


def _good_state() -> dict:
    model = torch.nn.Linear(2, 1)
    opt = torch.optim.Adam(model.parameters())
    return {"model": model.state_dict(), "optimizer": opt.state_dict(), "step": 3, "rng": torch.get_rng_state(),
            "config": {"train_frames": [1], "eval_frames": [2], "lr": 1e-3, "tiny": True, "data": "/d"}}


@pytest.mark.timeout(600)  # its subprocess may take 300 s
def test_a_pickle_payload_checkpoint_does_not_run_with_resume(tmp_path):
    marker = tmp_path / "pwned.txt"
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    torch.save({**_good_state(), "config": Payload(marker)}, run / "checkpoints" / "last.pt")
    for script in ("train_disparity", "train_asr", "train_sceneflow"):
        r = run_script(script, "--out", run, "--resume", "--data", tmp_path)
        assert r.returncode == 2, r.stderr
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and "last.pt is not a checkpoint these scripts write" in lines[0], r.stderr
        assert not marker.exists()
    # and the same file, loaded the old way, does run its payload: the test's input is real
    torch.load(run / "checkpoints" / "last.pt", weights_only=False)
    assert marker.read_text() == "payload ran"


@pytest.mark.parametrize("field,value,named", [
    ("step", -1, "'step'"), ("step", "7", "'step'"), ("model", {"w": [1.0]}, "'model'"),
    ("config", {"train_frames": "1-3", "eval_frames": [2]}, "train_frames"), ("rng", torch.zeros(3), "'rng'"),
])
def test_checkpoint_fields_are_checked(tmp_path, field, value, named):
    from lfusd.errors import LfusdError

    training = _training()
    run = training.Run(tmp_path / "run", "test")
    run.ckpt.parent.mkdir(parents=True)
    torch.save(_good_state(), run.ckpt)
    assert run.load()["step"] == 3  # what save writes loads
    torch.save({**_good_state(), field: value}, run.ckpt)
    with pytest.raises(LfusdError, match=named):
        training.Run(tmp_path / "run", "test").load()
