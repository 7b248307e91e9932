"""What the predict scripts share (flow/training.py): their options and the light field they read.
An HCI-layout folder is N*N views input_Cam000.png ... read row-major, each as stored (a grey PNG
repeated into three channels, alpha dropped) and scaled by its own bit depth; anything else is
refused in one line, by every script the same way, and a folder that is neither an HCI folder nor
an lfusd dataset gets the HCI reader's message."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from lfusd import LfusdError
from lfusd.data import formats
from support.flow_scripts import load_script


def _write(folder, images) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for i, img in enumerate(images):
        formats.write_png(folder / f"input_Cam{i:03d}.png", img)


def _distinct(count: int, shape, dtype, step: int = 1) -> list[np.ndarray]:
    """``count`` images, image i filled with i * step: a view read in the wrong place shows."""
    return [np.full(shape, i * step, dtype) for i in range(count)]


def test_hci_views_are_read_row_major_as_stored_and_scaled_by_their_depth(tmp_path):
    training = load_script("training")
    _write(tmp_path / "rgb", _distinct(9, (5, 7, 3), np.uint8, 20))
    n, files = training.hci_files(tmp_path / "rgb")
    assert n == 3 and [f.name for f in files] == [f"input_Cam{i:03d}.png" for i in range(9)]
    n, views = training.read_hci(tmp_path / "rgb")
    assert n == 3 and views.shape == (9, 5, 7, 3) and views.dtype == np.float32
    assert np.allclose(views[:, 0, 0, 0], np.arange(9) * 20 / 255.0)
    # grey PNGs: the grey value in all three channels; RGBA: alpha dropped; 16 bits kept
    grey = _distinct(4, (4, 6), np.uint16, 1000)
    _write(tmp_path / "grey", grey)
    view = training.read_view(tmp_path / "grey" / "input_Cam003.png")
    assert view.shape == (4, 6, 3) and view.dtype == np.uint16 and (view == 3000).all()
    n, views = training.read_hci(tmp_path / "grey")
    assert n == 2 and views.shape == (4, 4, 6, 3) and np.allclose(views[:, 0, 0], (np.arange(4) * 1000 / 65535.0)[:, None])
    bgra = np.zeros((4, 6, 4), np.uint8)
    bgra[..., 0], bgra[..., 1], bgra[..., 2], bgra[..., 3] = 10, 20, 30, 255
    assert cv2.imwrite(str(tmp_path / "grey" / "input_Cam001.png"), bgra)  # lfusd writes no alpha; other tools do
    formats.write_png(tmp_path / "grey" / "input_Cam002.png", np.full((4, 6), 51, np.uint8))
    _, views = training.read_hci(tmp_path / "grey")  # an 8-bit view among 16-bit ones: each by its own depth
    assert np.allclose(views[1], np.array([30, 20, 10]) / 255.0) and np.allclose(views[2], 0.2) and np.allclose(views[3], 3000 / 65535.0)


@pytest.mark.parametrize("names, why", [
    ([f"input_Cam{i:03d}.png" for i in range(8)], "not a square"),
    (["input_Cam000.png"], "one view"),
    ([f"input_Cam{i:03d}.png" for i in range(8)] + ["input_Cam009.png"], "a gap"),
    ([f"input_Cam{i:03d}.png" for i in range(8)] + ["input_Cam0008.png"], "four digits"),
])
def test_an_hci_folder_of_other_files_is_refused_in_one_line(tmp_path, names, why):
    training = load_script("training")
    tmp_path.joinpath("lf").mkdir()
    for name in names:
        formats.write_png(tmp_path / "lf" / name, np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(LfusdError, match=r"needs N\*N of them numbered from input_Cam000.png") as e:
        training.read_hci(tmp_path / "lf")
    assert len(str(e.value).splitlines()) == 1, why


def test_hci_views_of_different_sizes_are_refused(tmp_path):
    training = load_script("training")
    _write(tmp_path / "lf", _distinct(3, (4, 4, 3), np.uint8) + [np.zeros((4, 5, 3), np.uint8)])
    with pytest.raises(LfusdError, match="differ in size"):
        training.read_hci(tmp_path / "lf")


def test_predict_sceneflow_reads_grey_hci_views_as_three_channels(tmp_path):
    """predict_sceneflow.py's HCI input goes through the shared reader: a grey view becomes [3, H, W]."""
    psf = load_script("predict_sceneflow")
    _write(tmp_path / "lf", _distinct(9, (5, 7), np.uint8, 25))
    views, n = psf.read_hci(tmp_path / "lf")
    assert n == 3 and tuple(views.shape) == (9, 3, 5, 7) and views.dtype == torch.float32
    assert torch.allclose(views[:, :, 2, 3], torch.arange(9.0)[:, None].expand(9, 3) * 25 / 255)


@pytest.mark.parametrize("script", ["predict_views", "predict_disparity"])
def test_the_one_light_field_scripts_check_their_shared_options_alike(tmp_path, capsys, script):
    mod = load_script(script)
    out = tmp_path / ("o.pfm" if script == "predict_disparity" else "o")

    def run(*args) -> str:
        code = mod.training.main_wrapper(mod.NAME, mod.main, [str(a) for a in args])
        err = capsys.readouterr().err
        assert code == 2 and len(err.strip().splitlines()) == 1, err
        return err

    weights = tmp_path / "w.pt"
    if script == "predict_disparity":
        config = {"ang": 3, "d_min": -1.0, "d_max": 1.0, "disparities": 3, "channels": 4, "blocks": 1, "cost_channels": 4}
        torch.save({"model": load_script("train_disparity").build(config).state_dict(), "config": config}, weights)
    else:
        config = {"n": 3, "channels": 4, "blocks": 1}
        torch.save({"model": load_script("train_asr").build(config).state_dict(), "config": config}, weights)
    (tmp_path / "empty").mkdir()
    assert "--tile must be at least 8" in run(tmp_path / "empty", "-o", out, "--weights", weights, "--tile", 4)
    assert "--overlap at least 0" in run(tmp_path / "empty", "-o", out, "--weights", weights, "--overlap", -1)
    assert "is not a folder" in run(tmp_path / "nowhere", "-o", out, "--weights", weights)
    # neither input_Cam000.png nor an lfusd manifest: the HCI reader says what is missing
    assert "holds 0 input_CamNNN.png files" in run(tmp_path / "empty", "-o", out, "--weights", weights)
    assert not out.exists()


@pytest.mark.parametrize("h, w, tile, overlap", [(37, 50, 16, 5), (8, 8, 128, 32), (24, 24, 12, 24), (9, 30, 8, 0)])
def test_tiles_cover_the_image_once_and_see_their_context(h, w, tile, overlap):
    training = load_script("training")
    covered = np.zeros((h, w), int)
    for part, seen, inner in training.tiles(h, w, tile, overlap):
        covered[part] += 1
        rows, cols = np.mgrid[0:h, 0:w]
        # the part stands where ``inner`` says in the input the tile sees
        assert np.array_equal(rows[seen][inner], rows[part]) and np.array_equal(cols[seen][inner], cols[part])
        for out, ctx, size in ((part[0], seen[0], h), (part[1], seen[1], w)):
            assert out.stop - out.start <= tile and (out.stop - out.start == tile or out.stop == size)
            assert ctx.start == max(out.start - overlap, 0) and ctx.stop == min(out.stop + overlap, size)
    assert (covered == 1).all()
