"""Train a DistgDisp-like network (flow/models.py DisparityNet) for the centre view's disparity.

    python flow/train_disparity.py --tiny --out runs/disp                     # toy run on CPU, ~1 min
    python flow/train_disparity.py --data OUT --out runs/disp --device cuda   # full size
    python flow/train_disparity.py ... --resume --steps 40000                 # continue a run

Reads the light field through lfusd.torch (all views of a square grid, random crops), minimises
the L1 error of the disparity (pixels per baseline step, 0 at infinity) over every pixel, and
scores the trained model on the evaluation frames through `lfusd eval --task disparity`
(predictions in OUT/pred/, named <frame>_<row>_<col>.npy), beside the plane-sweep baseline of
lfusd.evaluation.baselines scored the same way (OUT/pred_plane_sweep/). The disparity candidates
span the training frames' true range (centre view) with a 10 % margin, as HCI gives disp_min/max.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

import training  # noqa: E402
from models import DisparityNet, StarDisparityNet  # noqa: E402
from lfusd import LfusdError  # noqa: E402

log = logging.getLogger("lfusd.flow")
NAME = "train_disparity"
TINY = dict(steps=300, batch=2, crop=32, lr=2e-3, save_every=50, log_every=1, channels=8, blocks=1, cost_channels=8, disparities=9)
FULL = dict(steps=20000, batch=8, crop=64, lr=1e-3, save_every=500, log_every=50, channels=16, blocks=4, cost_channels=32, disparities=33)


class CentreDisparity(torch.utils.data.Dataset):
    """Items of lfusd.torch.LightFieldVideoDataset (rgb of all views) with the centre view's disparity in the same crop."""

    def __init__(self, path, frames, crop, random_crop, rig=None):
        from lfusd.torch import LightFieldVideoDataset

        self.lf = LightFieldVideoDataset(path, keys=("rgb",), views="all", frames=frames, crop=crop, random_crop=random_crop, rig=rig)
        r = self.lf.ds.rig
        if r.rows != r.cols:
            raise LfusdError(f"the disentangling network needs a square grid of views, got {r.rows}x{r.cols}; render with --grid NxN")
        self.centre = tuple(r.centre_view)
        self.ci = self.lf.views.index(self.centre)

    def __len__(self):
        return len(self.lf)

    def __getitem__(self, i):
        item = self.lf[i]
        (y0, x0), (h, w) = item["crop"].tolist(), item["rgb"].shape[-2:]
        gt = np.asarray(self.lf.ds.read(int(item["frames"][0]), self.centre, "disparity"), np.float32)[y0 : y0 + h, x0 : x0 + w]
        rel = (item["offsets"] - item["offsets"][self.ci]).to(torch.float32)
        return item["rgb"], rel, torch.from_numpy(np.ascontiguousarray(gt)), item["frames"][0]


def disparity_range(ds, frames, margin=0.1) -> tuple[float, float]:
    c = tuple(ds.rig.centre_view)
    d = np.concatenate([np.ravel(ds.read(f, c, "disparity")) for f in frames])
    d = d[np.isfinite(d)]
    lo, hi = float(d.min()), float(d.max())
    pad = margin * max(hi - lo, 0.5)
    return lo - pad, hi + pad


ARCHS = ("distg", "star")  # config "arch"; checkpoints from before it was recorded are "distg"


def build(config: dict) -> DisparityNet | StarDisparityNet:
    """The network a run's configuration describes (also what predict_disparity.py loads)."""
    arch = config.get("arch", "distg")
    if arch == "star":
        return StarDisparityNet(config["ang"], config["d_min"], config["d_max"], config["disparities"], ch=config["channels"], n_blocks=config["blocks"],
                                cost_ch=config["cost_channels"])
    if arch != "distg":
        raise LfusdError(f"unknown disparity network {arch!r} in the run's config; this code knows {', '.join(ARCHS)}")
    return DisparityNet(config["ang"], config["d_min"], config["d_max"], config["disparities"], ch=config["channels"], n_blocks=config["blocks"], cost_ch=config["cost_channels"])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__.split("\n\n", 1)[1])
    training.common_args(p)
    p.add_argument("--channels", type=int, default=None, help="feature channels")
    p.add_argument("--blocks", type=int, default=None, help="Distg blocks in the feature extractor")
    p.add_argument("--cost-channels", type=int, default=None, help="channels of the cost volume")
    p.add_argument("--disparities", type=int, default=None, help="disparity candidates of the cost volume")
    a = p.parse_args(argv)
    t_start = time.time()
    run, state, device, data, ds, train_frames, eval_frames = training.start(a, NAME, TINY, FULL)
    if state:
        config = state["config"]
    else:
        d_min, d_max = disparity_range(ds, train_frames)
        config = {"ang": ds.rig.rows, "d_min": d_min, "d_max": d_max, **{k: getattr(a, k) for k in ("disparities", "channels", "blocks", "cost_channels")}}
        config.update(data=str(data), train_frames=train_frames, eval_frames=eval_frames, crop=a.crop, batch=a.batch, lr=a.lr, tiny=a.tiny)
    train = CentreDisparity(data, train_frames, min(config["crop"], ds.rig.height, ds.rig.width), True, a.rig)
    model = build(config).to(device)
    opt = torch.optim.Adam(model.parameters(), lr=config["lr"])
    start = 0
    if state:
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        start = state["step"]
    run.log["config"] = config
    log.info("%s: %d training frames, %d views, %d parameters, disparity candidates %.2f..%.2f px", data, len(train_frames), config["ang"] ** 2, sum(q.numel() for q in model.parameters()), config["d_min"], config["d_max"])

    sampler = torch.utils.data.RandomSampler(train, replacement=True, num_samples=max(a.steps - start, 1) * config["batch"])
    loader = torch.utils.data.DataLoader(train, batch_size=config["batch"], sampler=sampler, num_workers=a.workers, drop_last=True)

    def step(batch):
        views, rel, gt, _ = batch
        pred = model(views.to(device), rel.to(device))
        return (pred - gt.to(device)).abs().mean()

    training.train_loop(model, opt, training.endless(loader), step, run, config, start, a, "disparity")

    t0 = time.time()
    run.log["eval"] = evaluate(model, ds, data, eval_frames, config, Path(a.out), device, a)
    run.log["timing"]["eval_s"] = time.time() - t0
    run.log["timing"]["total_s"] = time.time() - t_start
    run.write_log()
    m = run.log["eval"]["model"]["mean"]
    log.info("frames %s: MSEx100 %.3f, BadPix0.07 %.2f %% over %d pixels (log %s)", eval_frames, m["mse_x100"], m["badpix_0.07_pct"], m["pixels"], run.log_path)
    return 0


@torch.no_grad()
def evaluate(model, ds, data, frames, config, out: Path, device, a) -> dict:
    """Predict the centre view of every frame, write it where `lfusd eval` reads it and score it; the same for the plane sweep."""
    from lfusd.evaluation import baselines

    model.eval()
    full = CentreDisparity(data, frames, None, False, a.rig)
    centre = full.centre
    pred_dir = out / "pred"
    pred_dir.mkdir(exist_ok=True)
    for views, rel, _, frame in torch.utils.data.DataLoader(full, batch_size=1):
        d = model(views.to(device), rel.to(device))[0].cpu().numpy().astype(np.float32)
        np.save(pred_dir / f"{training.pred_name(int(frame), centre)}.npy", d)

    def pixels(frame, view):  # the pixels the lfusd protocol scores: those with a surface
        return np.isfinite(ds.read(frame, view, "depth")).sum()

    res = {"model": training.score(ds, pred_dir, "disparity", pixels)}
    if not a.no_baselines:
        base_dir = out / "pred_plane_sweep"
        base_dir.mkdir(exist_ok=True)
        offsets = {tuple(v): ds.rig.offsets(tuple(v)) for v in ds.views}
        for f in frames:
            imgs = {tuple(v): ds.read(f, tuple(v), "rgb") for v in ds.views}
            d = baselines.plane_sweep_disparity(imgs, offsets, offsets[centre], (config["d_min"], config["d_max"]), 64, 9, device=device)
            np.save(base_dir / f"{training.pred_name(f, centre)}.npy", d)
        res["plane_sweep"] = training.score(ds, base_dir, "disparity", pixels)
    (out / "eval.json").write_text(json.dumps({k: v["mean"] for k, v in res.items()}, indent=1, default=float))
    return res


if __name__ == "__main__":
    sys.exit(training.main_wrapper(NAME, main))
