"""flow/predict_disparity.py: a synthetic 9x9 HCI-layout folder of a textured fronto-parallel plane at
a known disparity goes through the script with weights trained for a few steps inside the test; the
views it reads carry HCI's grid convention (shifting them by the true disparity aligns them), the PFM
it writes is byte for byte what `lfusd export hci` writes for the same array (little-endian, rows
bottom-up) and reads back through the reader HCI files are read with; errors are one line."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lfusd.data import formats
from support.flow_scripts import load_script, run_main, run_script
from support.light_fields import fit_planes, plane_views, write_hci

N, SIZE = 9, 24


@pytest.fixture(scope="module")
def weights(tmp_path_factory):
    """A tiny 9x9 DisparityNet trained for 40 steps on random 16x16 planes (about 30 s on one idle core)."""
    td = load_script("train_disparity")
    models = load_script("models")
    torch.manual_seed(0)
    config = {"ang": N, "d_min": -2.0, "d_max": 2.0, "disparities": 9, "channels": 8, "blocks": 1, "cost_channels": 8,
              "train_frames": [1], "eval_frames": [1]}
    model = td.build(config)
    fit_planes(model, 40, 1.8, 16)
    path = tmp_path_factory.mktemp("weights") / "w.pt"
    torch.save({"model": model.state_dict(), "config": config}, path)
    assert models.DisparityNet  # the script's network
    return path


def test_the_views_it_reads_follow_hcis_grid_convention(tmp_path):
    pdm = load_script("predict_disparity")
    models = load_script("models")
    d = 1.25
    folder = write_hci(tmp_path / "lf", plane_views(d, np.random.default_rng(1)))
    views, offsets, centre = pdm.read_hci_views(folder)
    assert views.shape == (N * N, SIZE, SIZE, 3) and centre == (4, 4)
    assert offsets[0].tolist() == [-4, -4] and offsets[8].tolist() == [4, -4] and offsets[40].tolist() == [0, 0]
    feat = torch.from_numpy(views.transpose(0, 3, 1, 2).copy())[None]
    rel = torch.from_numpy(offsets)[None]
    inner = (slice(None), slice(None), slice(None), slice(6, -6), slice(6, -6))
    aligned = models.shift_views(feat, rel, d)[inner]
    wrong = models.shift_views(feat, rel, -d)[inner]
    spread = lambda x: (x - x[:, 40:41]).abs().mean().item()  # noqa: E731  (views against the centre)
    assert spread(aligned) < 0.01 < 0.5 * spread(wrong), (spread(aligned), spread(wrong))


def test_a_plane_goes_through_the_script_into_hcis_pfm(tmp_path, weights, capsys):
    pdm = load_script("predict_disparity")
    td = load_script("train_disparity")
    rng = np.random.default_rng(2)
    config, state = pdm.load_weights(weights)
    model = td.build(config)
    model.load_state_dict(state)
    model.eval()
    means = {}
    for d in (-1.5, 1.5):
        folder = write_hci(tmp_path / f"lf{d}", plane_views(d, rng))
        out = tmp_path / f"disp{d}.pfm"
        args = (folder, "-o", out, "--weights", weights, "--tile", 16, "--overlap", 8, "--threads", 1)
        if d < 0:  # the command line once, in its own process
            r = run_script("predict_disparity", *args)
            assert r.returncode == 0, r.stderr
        else:
            code, err = run_main("predict_disparity", capsys, *args)
            assert code == 0, err
        got = formats.read_pfm(out)  # the reader of HCI's gt_disp_lowres.pfm
        assert got.shape == (SIZE, SIZE) and got.dtype == np.float32
        # byte for byte what `lfusd export hci` writes for this array: 'Pf', W H, -1 (little-endian), rows bottom-up
        ref = tmp_path / "ref.pfm"
        formats.write_pfm(ref, got)
        raw = out.read_bytes()
        assert raw == ref.read_bytes() and raw.startswith(f"Pf\n{SIZE} {SIZE}\n-1.0\n".encode())
        assert raw[-4 * SIZE:] == got[0].astype("<f4").tobytes()  # the top row is stored last
        # the numbers are the network's on these views (tiles stitched where they belong)
        views, offsets, _ = pdm.read_hci_views(folder)
        whole = pdm.predict(model, views, offsets, tile=128, overlap=0)
        assert np.abs(pdm.predict(model, views, offsets, tile=12, overlap=24) - whole).max() < 1e-5
        inner = got[6:-6, 6:-6]
        means[d] = float(inner.mean())
    # a few steps of training already give the right sign on a plane of each sign
    assert means[-1.5] < 0 < means[1.5], means


def test_errors_are_one_line(tmp_path, weights, capsys, monkeypatch):
    r = run_script("predict_disparity", tmp_path, "-o", tmp_path / "d.pfm", "--weights", tmp_path / "none.pt")  # the command line's exit status
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        f"predict_disparity: error: no weights at {tmp_path / 'none.pt'}; train with flow/train_disparity.py and pass --weights RUN/checkpoints/last.pt"]
    pdm = load_script("predict_disparity")
    monkeypatch.setattr(pdm, "SHIPPED", tmp_path / "gone.pt")  # a checkout without the shipped weights
    lf = write_hci(tmp_path / "plane", plane_views(0.5, np.random.default_rng(3)))
    code = pdm.training.main_wrapper(pdm.NAME, pdm.main, [str(lf), "-o", str(tmp_path / "d.pfm")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "shipped weights" in err and "--weights" in err
    lf = write_hci(tmp_path / "few", plane_views(0.5, np.random.default_rng(3))[:80])  # one view short of 9x9
    code, err = run_main("predict_disparity", capsys, lf, "-o", tmp_path / "d.pfm", "--weights", weights)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "N*N of them" in err
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    code, err = run_main("predict_disparity", capsys, tmp_path / "few", "-o", tmp_path / "d.pfm", "--weights", tmp_path / "bad.pt")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "not a weights file" in err
    assert not (tmp_path / "d.pfm").exists()


@pytest.mark.render
def test_an_lfusd_dataset_and_its_hci_export_give_the_same_pfm(tmp_path):
    """The script on a rendered dataset folder (its HCI centre view, frame 1) writes what it writes on the
    folder `lfusd export hci` makes of that frame: same views in the same order, same offsets."""
    from lfusd.author.scenes import generate
    from lfusd.cli import main

    td = load_script("train_disparity")
    generate("things", tmp_path / "s.usda", 3, frames=1, rigs=1, grid=(3, 3), resolution=(32, 32))
    assert main(["render", str(tmp_path / "s.usda"), "-o", str(tmp_path / "ds"), "--rig", "rig_00", "--samples", "1",
                 "--device", "cpu", "--quiet"]) == 0
    assert main(["export", "hci", str(tmp_path / "ds"), str(tmp_path / "hci")]) == 0
    torch.manual_seed(1)
    config = {"ang": 3, "d_min": 0.0, "d_max": 8.0, "disparities": 9, "channels": 4, "blocks": 1, "cost_channels": 4}
    torch.save({"model": td.build(config).state_dict(), "config": config}, tmp_path / "w.pt")
    (folder,) = (tmp_path / "hci").iterdir()
    for src, out in ((tmp_path / "ds", tmp_path / "a.pfm"), (folder, tmp_path / "b.pfm")):
        r = run_script("predict_disparity", src, "-o", out, "--weights", tmp_path / "w.pt", "--threads", 1)
        assert r.returncode == 0, r.stderr
    a, b = formats.read_pfm(tmp_path / "a.pfm"), formats.read_pfm(tmp_path / "b.pfm")
    assert a.shape == b.shape == formats.read_pfm(folder / "gt_disp_lowres.pfm").shape == (32, 32)
    assert np.abs(a - b).max() < 1e-5
