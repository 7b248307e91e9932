"""Predict the centre view's disparity of a light field with a trained DisparityNet (flow/models.py).

    python flow/predict_disparity.py LF_DIR -o DISP.pfm [--weights W]
    python flow/predict_disparity.py DATASET -o DISP.pfm [--weights W] [--frame 1] [--rig rig_00]

LF_DIR holds input_Cam000.png ... input_Cam080.png in the HCI 4D benchmark layout (row-major,
Cam000 top left; a parameters.cfg there is not read): an N x N grid of views, N*N files. Or an
lfusd dataset folder: the views of one frame (--frame, default the first) of one rig (--rig).
The output is the disparity of the view the HCI toolkit takes as centre (camera int(N*N/2), the
true centre of odd grids) in pixels per view step, HCI's sign convention (a point at disparity d
at (u, v) in the centre view is at (u - d*sx, v - d*sy) in the view at grid offset (sx, sy):
docs/CONVENTIONS.md) and HCI's file format: a little-endian, bottom-up PFM, written by the same
function as `lfusd export hci` writes gt_disp_lowres.pfm with.

W is a checkpoint of flow/train_disparity.py (OUT/checkpoints/last.pt) or a file holding its
``model`` (name -> tensor) and ``config``, loaded with torch.load(weights_only=True). The image is
processed in overlapping tiles (--tile, --overlap), so memory stays flat at any size.
"""

from __future__ import annotations

import argparse
import logging
import math
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
NAME = "predict_disparity"
# the shipped weights: trained on lfusd data alone by the commands of flow/README.md ("Shipped weights")
SHIPPED = Path(__file__).resolve().parent / "weights" / "disparity.pt"
CONFIG_KEYS = ("ang", "d_min", "d_max", "disparities", "channels", "blocks", "cost_channels")


def load_weights(path) -> tuple[dict, dict]:
    """(config, state dict) of a DisparityNet from ``path`` (weights_only=True); one-line LfusdError otherwise."""
    state = training.load_weights(path, "train_disparity")
    config = state["config"]
    if any(k not in config for k in CONFIG_KEYS):
        raise LfusdError(f"{path} lacks the network's config ({', '.join(CONFIG_KEYS)}); give a checkpoint of flow/train_disparity.py")
    return config, state["model"]


def load_model(weights=None, device=None):
    """(the network in eval mode on ``device``, its config, the weights' path) from a checkpoint or weights file;
    ``weights`` None: the shipped weights (:data:`SHIPPED`)."""
    from train_disparity import build

    path = Path(weights) if weights is not None else SHIPPED
    if weights is None and not path.is_file():
        raise LfusdError(f"the shipped weights {path} are missing from this checkout; give --weights (a checkpoint of flow/train_disparity.py)")
    config, state = load_weights(path)
    model = build(config)
    try:
        model.load_state_dict(state)
    except RuntimeError as e:
        raise LfusdError(f"{path} does not fit the network its config describes ({str(e).splitlines()[0][:160]})") from None
    model.eval()
    if device is not None:
        model.to(device)
    return model, config, path


def read_hci_views(folder: Path) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """(views [N*N, H, W, 3] float32 in [0, 1], offsets [N*N, 2] (sx, sy) from the centre, centre (row, col))."""
    n, views = training.read_hci(folder)
    centre = divmod(n * n // 2, n)  # the HCI toolkit's centre camera
    rows, cols = np.divmod(np.arange(n * n), n)
    offsets = np.stack([cols - centre[1], rows - centre[0]], 1).astype(np.float32)
    return views, offsets, centre


def read_dataset_views(folder: Path, frame: int | None, rig: str | None) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """The same from an lfusd dataset: one frame's views of a uniform planar parallel rig (row-major)."""
    from lfusd.exports.hci import hci_centre_view

    ds, t = training.dataset_frame(folder, frame, rig, "the disparity network")
    if ds.rig.rows != ds.rig.cols:
        raise LfusdError(f"the disparity network needs a square grid of views, this dataset's is {ds.rig.rows}x{ds.rig.cols}")
    views = sorted(tuple(v) for v in ds.views)
    centre = hci_centre_view(ds)
    imgs = np.stack([np.asarray(ds.read(t, v, "rgb"), np.float32)[..., :3] / 255.0 for v in views])
    offsets = np.array([ds.rig.offsets(v) for v in views], np.float32) - np.array(ds.rig.offsets(centre), np.float32)
    return imgs, offsets, centre


@torch.no_grad()
def predict(model, views: np.ndarray, offsets: np.ndarray, tile: int = 128, overlap: int = 32) -> np.ndarray:
    """The reference view's disparity [H, W] float32: the network on overlapping tiles, each keeping its
    centre part (``overlap`` pixels of context on every inner side)."""
    n, h, w, _ = views.shape
    x = torch.from_numpy(np.ascontiguousarray(views.transpose(0, 3, 1, 2)))[None]  # 1, N, 3, H, W
    dev = next(model.parameters()).device
    rel = torch.from_numpy(offsets)[None].to(dev)
    out = np.zeros((h, w), np.float32)
    for part, seen, inner in training.tiles(h, w, tile, overlap):
        out[part] = model(x[(..., *seen)].to(dev), rel)[0].cpu().numpy()[inner]
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog=__doc__.split("\n\n", 1)[1])
    p.add_argument("-o", "--output", required=True, help="the PFM file to write (HCI's gt_disp_lowres.pfm format)")
    p.add_argument("--weights", default=None, help="a checkpoint of flow/train_disparity.py (default: the shipped weights, flow/weights/disparity.pt)")
    training.predict_args(p, overlap=32)
    a = p.parse_args(argv)
    folder, out = training.check_predict_args(a), Path(a.output)
    if out.suffix.lower() != ".pfm":
        raise LfusdError(f"output {out} must end in .pfm (HCI's disparity format)")
    device = training.device_of(a.device, a.threads)
    model, config, _ = load_model(a.weights, device)
    t0 = time.time()
    if training.is_hci(folder):
        views, offsets, centre = read_hci_views(folder)
    else:
        views, offsets, centre = read_dataset_views(folder, a.frame, a.rig)
    n = math.isqrt(len(views))
    if n != config["ang"]:
        raise LfusdError(f"the weights are for a {config['ang']}x{config['ang']} grid, {folder} holds {n}x{n} views")
    disp = predict(model, views, offsets, a.tile, a.overlap)
    out.parent.mkdir(parents=True, exist_ok=True)
    formats.write_pfm(out, disp)
    log.info("%s: %dx%d views of %dx%d, centre view %s: disparity %.3f..%.3f px -> %s in %.1f s", folder, n, n, views.shape[2],
             views.shape[1], centre, float(disp.min()), float(disp.max()), out, time.time() - t0)
    return 0


if __name__ == "__main__":
    sys.exit(training.main_wrapper(NAME, main))
