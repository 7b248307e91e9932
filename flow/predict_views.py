"""Angular super-resolution of a light field with a trained ASRNet (flow/models.py): 2x2 -> n x n views.

    python flow/predict_views.py LF_DIR -o OUT_DIR --weights W
    python flow/predict_views.py DATASET -o OUT_DIR --weights W [--frame 1] [--rig rig_00]

LF_DIR holds input_Cam000.png ... in the HCI 4D benchmark layout (row-major, Cam000 top left; an
N x N grid, N*N files; a parameters.cfg there is not read), or it is an lfusd dataset folder (the
views of one frame, --frame, default the first, of one uniform planar parallel rig, --rig). As in
DistgASR's protocol (2x2 -> 7x7 on HCI's 9x9 light fields), the network's input is the four
corner views of the central n x n views (n from the weights: rows and columns (N - n) // 2 ..
(N - n) // 2 + n - 1; for 9 -> 7 the views 1..7, HCI cameras 10, 16, 64 and 70) and its output is
that n x n grid. OUT_DIR gets it in the same layout: input_Cam000.png ... input_Cam{n*n-1}.png,
row-major over the n x n grid, Cam000 its top-left view; the four corners are the input views as
read (bit for bit), the others the network's. PNGs keep the input's bit depth (8 or 16 bits).

W is a checkpoint of flow/train_asr.py (OUT/checkpoints/last.pt) or a file holding its ``model``
(name -> tensor) and ``config`` (default: the shipped flow/weights/asr.pt, once it ships), loaded with torch.load(weights_only=True). The image is processed
in overlapping tiles (--tile, --overlap), so memory stays flat at any size.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import training  # noqa: E402
from lfusd import LfusdError  # noqa: E402
from lfusd.data import formats  # noqa: E402

log = logging.getLogger("lfusd.flow")
NAME = "predict_views"
CONFIG_KEYS = ("n", "channels", "blocks")
# the weights to ship (issue 36), used when --weights is not given
SHIPPED = Path(__file__).resolve().parent / "weights" / "asr.pt"


def load_model(path) -> tuple[torch.nn.Module, dict]:
    """The ASRNet of a weights file (``model`` and ``config``, read with ``weights_only=True``) and its
    config; one-line LfusdError when it is missing or not such a file."""
    from train_asr import build

    state = training.load_weights(path, "train_asr")
    config = state["config"]
    if any(not isinstance(config.get(k), int) for k in CONFIG_KEYS):
        raise LfusdError(f"{path} lacks the network's config ({', '.join(CONFIG_KEYS)}); give a checkpoint of flow/train_asr.py")
    model = build(config)
    try:
        model.load_state_dict(state["model"])
    except RuntimeError as e:
        raise LfusdError(f"{path} does not fit the network its config describes ({str(e).splitlines()[0][:160]}); "
                         "give a checkpoint of flow/train_asr.py") from None
    model.eval()
    return model, config


def central_grid(rows: int, cols: int, n: int, where) -> list[tuple[int, int]]:
    """The central n x n views (row, col) of a rows x cols grid, row-major (DistgASR's crop of HCI's 9x9 to 7x7)."""
    if n > min(rows, cols):
        raise LfusdError(f"the weights make {n}x{n} views from the corners of the central {n}x{n}, and {where} has only {rows}x{cols}; "
                         f"give a light field of at least {n}x{n} views or weights for a smaller grid")
    r0, c0 = (rows - n) // 2, (cols - n) // 2
    return [(r, c) for r in range(r0, r0 + n) for c in range(c0, c0 + n)]


def read_hci_corners(folder: Path, n: int) -> tuple[dict, list, np.dtype]:
    """({corner view: image [H, W, 3] as stored}, the n x n grid, the PNGs' dtype) of an HCI-layout folder."""
    size, files = training.hci_files(folder)
    grid = central_grid(size, size, n, folder)
    images = {v: training.read_view(files[v[0] * size + v[1]]) for v in corners_of(grid, n)}
    return images, grid, check_same(images, folder)


def read_dataset_corners(folder: Path, n: int, frame: int | None, rig: str | None) -> tuple[dict, list, np.dtype]:
    """The same from an lfusd dataset: one frame of a uniform planar parallel rig."""
    ds, t = training.dataset_frame(folder, frame, rig, "angular super-resolution")
    grid = central_grid(ds.rig.rows, ds.rig.cols, n, folder)
    images = {v: np.asarray(ds.read(t, v, "rgb"))[..., :3] for v in corners_of(grid, n)}
    return images, grid, check_same(images, folder)


def corners_of(grid: list, n: int) -> list:
    """Top-left, top-right, bottom-left, bottom-right of a row-major n x n grid (ASRNet's input order)."""
    return [grid[0], grid[n - 1], grid[n * (n - 1)], grid[-1]]


def check_same(images: dict, where) -> np.dtype:
    if len({(a.shape, a.dtype) for a in images.values()}) != 1:
        raise LfusdError(f"the corner views of {where} differ in size or bit depth; every view must have one size and depth")
    dtype = next(iter(images.values())).dtype
    if dtype not in (np.uint8, np.uint16):
        raise LfusdError(f"the views of {where} are {dtype}; give 8- or 16-bit images")
    return dtype


@torch.no_grad()
def predict(model, corners: np.ndarray, tile: int = 128, overlap: int = 16) -> np.ndarray:
    """All n x n views [n*n, H, W, 3] float32 in [0, 1] from the corners [4, H, W, 3] in [0, 1] (row-major):
    the network on overlapping tiles, each keeping its centre part (``overlap`` pixels of context on
    every inner side)."""
    _, h, w, _ = corners.shape
    x = torch.from_numpy(np.ascontiguousarray(corners.transpose(0, 3, 1, 2)))[None]  # 1, 4, 3, H, W
    dev = next(model.parameters()).device
    out = None
    for part, seen, inner in training.tiles(h, w, tile, overlap):
        views = model(x[(..., *seen)].to(dev))[0].clamp(0, 1).cpu().numpy()  # n*n, 3, h', w'
        if out is None:
            out = np.zeros((views.shape[0], h, w, 3), np.float32)
        out[(slice(None), *part)] = views[(slice(None), slice(None), *inner)].transpose(0, 2, 3, 1)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog=__doc__.split("\n\n", 1)[1])
    p.add_argument("-o", "--output", required=True, help="folder to write the n x n views to (input_Cam000.png ...)")
    p.add_argument("--weights", default=None, help="a checkpoint of flow/train_asr.py (default: the shipped weights, flow/weights/asr.pt, once they ship)")
    p.add_argument("--overwrite", action="store_true", help="replace the input_CamNNN.png files OUT_DIR already holds")
    training.predict_args(p, overlap=16)
    a = p.parse_args(argv)
    if a.weights is None:
        if not SHIPPED.is_file():
            raise LfusdError(f"no --weights given and no shipped weights ({SHIPPED.relative_to(training.ROOT)}) yet; "
                             "train with flow/train_asr.py and pass --weights OUT/checkpoints/last.pt")
        a.weights = str(SHIPPED)
    folder, out = training.check_predict_args(a), Path(a.output)
    if out.exists() and (not out.is_dir() or out.resolve() == folder.resolve()):
        raise LfusdError(f"output {out} is {'the input folder' if out.is_dir() else 'a file'}; give a new folder for the views")
    if not a.overwrite and out.is_dir() and any(out.glob("input_Cam*.png")):
        raise LfusdError(f"{out} already holds input_CamNNN.png files; give a new folder or --overwrite")
    model, config = load_model(a.weights)
    n = config["n"]
    t0 = time.time()
    if training.is_hci(folder):
        images, grid, dtype = read_hci_corners(folder, n)
    else:
        images, grid, dtype = read_dataset_corners(folder, n, a.frame, a.rig)
    scale = float(np.iinfo(dtype).max)
    corners = corners_of(grid, n)
    device = training.device_of(a.device, a.threads)
    model.to(device)
    views = predict(model, np.stack([images[v].astype(np.float32) / scale for v in corners]), a.tile, a.overlap)
    out.mkdir(parents=True, exist_ok=True)
    for i, v in enumerate(grid):
        img = images[v] if v in images else np.round(views[i] * scale).astype(dtype)
        formats.write_png(out / f"input_Cam{i:03d}.png", img)
    h, w = views.shape[1:3]
    log.info("%s: corners %s of the central %dx%d -> %d views of %dx%d in %s in %.1f s", folder, corners, n, n, n * n, w, h, out, time.time() - t0)
    return 0


if __name__ == "__main__":
    sys.exit(training.main_wrapper(NAME, main))
