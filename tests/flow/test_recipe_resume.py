"""A run trained on a recipe dataset resumes: train_disparity.py records ``train_frames: None``
(every frame of each scene) in its checkpoint's config when --train-frames is not given, and the
checkpoint check must accept it there (it refused it, so `--resume` of the CPU preview training
failed), while still refusing a missing frame list outside a recipe run."""

from __future__ import annotations

import pytest
import torch

from support.flow_scripts import load_script

from lfusd import LfusdError


def _save(run, config: dict) -> None:
    model = torch.nn.Linear(2, 1)
    run.save(model, torch.optim.Adam(model.parameters()), 3, config)


def test_a_recipe_runs_checkpoint_without_a_frame_list_resumes(tmp_path):
    training = load_script("training")
    run = training.Run(tmp_path / "run", "train_disparity")
    _save(run, {"recipe": "data/train_preview", "train_frames": None, "eval_frames": [4]})
    state = training.Run(tmp_path / "run", "train_disparity").load()
    assert state["step"] == 3 and state["config"]["train_frames"] is None
    other = training.Run(tmp_path / "other", "train_disparity")
    _save(other, {"train_frames": None, "eval_frames": [4]})  # not a recipe run: the frame list is required
    with pytest.raises(LfusdError, match="'train_frames' is not a list"):
        training.Run(tmp_path / "other", "train_disparity").load()
