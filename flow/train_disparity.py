"""Train a disparity network (flow/models.py StarDisparityNet, or the original DisparityNet with
--arch distg) for the centre view's disparity.

    python flow/train_disparity.py --tiny --out runs/disp                     # toy run on CPU, ~1 min
    python flow/train_disparity.py --data OUT --out runs/disp --device cuda   # full size
    python flow/train_disparity.py --data RECIPE_OUT --cache CACHES --out runs/disp   # a recipe's train split
    python flow/train_disparity.py ... --resume --steps 40000                 # continue a run

--data is one dataset folder or a made recipe dataset (lfusd dataset make): then every scene of its
`train` split (--split) is trained on, and the run is scored afterwards with `lfusd export hci`,
predict_disparity.py and `lfusd eval` (flow/README.md). Items are read through lfusd.torch (all
views of a square grid, random crops) from the dataset folders or, with --cache, from training
caches (`lfusd export cache`: for a recipe, CACHES/<scene> for each scene), and augmented with
lfusd.data.augment keeping the ground truth exact: each item is refocused by an integer k drawn
from 0..shift_px of its scene's disparity design (`things` stages; 0 for other scenes) widened by
--refocus, so that its disparity d - k takes both signs (HCI's range at k = shift_px) and the
unshifted range of exported scenes (k = 0) is seen too; then flipped and transposed (the grid
with the image, so the disparity keeps its sign) and colour-jittered with noise. The loss is the
L1 error of the disparity (pixels per baseline step, 0 at infinity) over every pixel. A single
dataset is scored on its evaluation frames through `lfusd eval --task disparity` (predictions in
OUT/pred/, named <frame>_<row>_<col>.npy), beside the plane-sweep baseline of
lfusd.evaluation.baselines scored the same way (OUT/pred_plane_sweep/). The disparity candidates
span the training frames' true range (centre view, every refocus shift) with a 10 % margin, as
HCI gives disp_min/max.
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
from lfusd.data.folder import require_pinhole  # noqa: E402

log = logging.getLogger("lfusd.flow")
NAME = "train_disparity"
TINY = dict(steps=300, batch=2, crop=32, lr=2e-3, save_every=50, log_every=1, arch="star", channels=8, blocks=1, cost_channels=8, disparities=9,
            refocus=0)
FULL = dict(steps=20000, batch=8, crop=64, lr=1e-3, save_every=500, log_every=50, arch="star", channels=16, blocks=3, cost_channels=16,
            disparities=17, refocus=1)
# the original DistgDisp-like network's full size (--arch distg): about 25x the CPU time of FULL's
FULL_DISTG = dict(channels=16, blocks=4, cost_channels=32, disparities=33)
KEYS = ("rgb", "disparity")
AUGMENT = dict(flip=True, transpose=True, brightness=0.2, contrast=0.2, saturation=0.2, noise=0.02)


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


def disparity_range(ds, frames, margin=0.1, shifts=(0,)) -> tuple[float, float]:
    """The centre view's true disparity range over ``frames`` after every refocus shift k in
    ``shifts`` (d -> d - k), widened by ``margin`` of its span (at least 0.5 px) on each side."""
    c = tuple(ds.rig.centre_view)
    d = np.concatenate([np.ravel(ds.read(f, c, "disparity")) for f in frames])
    d = d[np.isfinite(d)]
    lo, hi = float(d.min()) - max(shifts), float(d.max()) - min(shifts)
    pad = margin * max(hi - lo, 0.5)
    return lo - pad, hi + pad


def design_shift(folder: Path) -> int:
    """shift_px of the disparity design of a recipe scene (its record scenes/<scene>.json; `things`
    stages), 0 for a dataset without one."""
    from lfusd import layout

    rec = folder.parent / f"{folder.name}.json"
    if folder.parent.name != layout.RECIPE_SCENES or not rec.is_file():
        return 0
    try:
        design = json.loads(rec.read_text()).get("disparity_design") or {}
        return int(design.get("shift_px", 0))
    except (OSError, ValueError, TypeError, AttributeError):
        return 0


def training_scenes(data: Path, split: str) -> list[Path]:
    """The dataset folders to train on: ``data`` itself, or the scenes of ``split`` of a made recipe dataset."""
    return training.recipe_scenes(data, split)


def scene_source(folder: Path, cache: Path | None, ds):
    """What a scene's items are read from: its training cache (with rgb and disparity) or its folder."""
    return training.scene_source(folder, cache, ds, KEYS)


class Augmented(torch.utils.data.Dataset):
    """Training sample n of a run: a scene, frame and crop drawn from the run's seed and n alone (so a
    resumed run sees the batches the uninterrupted one would have), refocused by k in
    shift - refocus .. shift + refocus of its scene clipped at 0 below (lfusd.data.augment.refocus:
    disparity d -> d - k), then flipped, transposed, colour-jittered and noised (RandomLightField).
    Items: (views [V, 3, crop, crop], offsets from the centre view [V, 2], centre disparity [crop, crop])."""

    def __init__(self, sources, shifts, frames, crop: int, refocus: int, seed: int, rig=None, augment: dict = AUGMENT):
        from lfusd.data.augment import refocus_margin
        from lfusd.torch import LightFieldVideoDataset

        self.items, self.ks, self.margins = [], [], []
        for src, shift in zip(sources, shifts):
            ks = refocus_shifts(shift, refocus)
            lf = LightFieldVideoDataset(src, keys=KEYS, views="all", frames=frames, crop=None, rig=rig)
            r = lf.ds.rig
            if r.rows != r.cols:
                raise LfusdError(f"the disentangling network needs a square grid of views, got {r.rows}x{r.cols}; render with --grid NxN")
            m = refocus_margin([r.offsets(v) for v in lf.views], max(abs(k) for k in ks))
            size = (crop + 2 * m[0], crop + 2 * m[1])
            if size[0] > r.height or size[1] > r.width:
                raise LfusdError(f"crops of {crop} px refocused by up to {max(abs(k) for k in ks)} px per view step need {size[0]}x{size[1]} px of the "
                                 f"{r.height}x{r.width} images of {src}; give a smaller --crop or --refocus")
            self.items.append(LightFieldVideoDataset(src, keys=KEYS, views="all", frames=frames, crop=size, random_crop=True, rig=rig))
            self.ks.append(ks)
            self.margins.append(m)
        self.seed, self.crop, self.augment = int(seed), int(crop), dict(augment)
        self.centre = tuple(self.items[0].ds.rig.centre_view)

    def __len__(self):
        return 2**62

    def __getitem__(self, n: int):
        from lfusd.data.augment import RandomLightField, refocus

        with torch.random.fork_rng(devices=[]):
            torch.manual_seed((self.seed * 2_654_435_761 + int(n)) % 2**63)
            s = int(torch.randint(len(self.items), ()))
            item = self.items[s][int(torch.randint(len(self.items[s]), ()))]
            k = self.ks[s][int(torch.randint(len(self.ks[s]), ()))]
        item = refocus(item, k, margin=self.margins[s])
        item = RandomLightField(seed=[self.seed, int(n)], **self.augment)(item)
        views = [tuple(v) for v in item["views"].tolist()]
        ci = views.index(self.centre)
        rel = (item["offsets"] - item["offsets"][ci]).to(torch.float32)
        return item["rgb"].float(), rel, item["disparity"][ci].float()


ARCHS = ("star", "distg")  # config "arch"; checkpoints from before it was recorded are "distg"


def refocus_shifts(shift: int, refocus: int) -> list[int]:
    """The refocus shifts k an item of a scene whose design shift is ``shift`` is drawn from: 0..shift
    widened by ``refocus`` above (and below 0 for a scene without a design)."""
    return list(range(0, shift + refocus + 1)) if shift > 0 else list(range(-refocus, refocus + 1))


def build(config: dict) -> DisparityNet | StarDisparityNet:
    """The network a run's configuration describes (also what predict_disparity.py loads)."""
    arch = config.get("arch", "distg")
    if arch == "star":
        if config["ang"] % 2 == 0:
            raise LfusdError(f"the star network needs an odd grid of views (its reference is the centre view), got {config['ang']}x{config['ang']}; "
                             "render an odd grid or train with --arch distg")
        return StarDisparityNet(config["ang"], config["d_min"], config["d_max"], config["disparities"], ch=config["channels"], n_blocks=config["blocks"],
                                cost_ch=config["cost_channels"])
    if arch != "distg":
        raise LfusdError(f"unknown disparity network {arch!r} in the run's config; this code knows {', '.join(ARCHS)}")
    return DisparityNet(config["ang"], config["d_min"], config["d_max"], config["disparities"], ch=config["channels"], n_blocks=config["blocks"], cost_ch=config["cost_channels"])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__.split("\n\n", 1)[1])
    training.common_args(p)
    p.add_argument("--arch", default=None, choices=ARCHS, help="star: the CPU-affordable network (default); distg: the original DistgDisp-like one")
    training.disparity_net_args(p, "feature blocks (Distg blocks with --arch distg)")
    p.add_argument("--refocus", type=int, default=None, help="refocus shifts k beyond 0..shift_px of each scene (d -> d - k); 0: only those")
    p.add_argument("--split", default="train", help="the split of a recipe dataset given as --data to train on (default train)")
    p.add_argument("--cache", default=None, help="training cache of --data (lfusd export cache DATA CACHE --keys rgb,disparity); "
                   "for a recipe dataset a folder holding one per scene, named as the scene")
    a = p.parse_args(argv)
    t_start = time.time()
    recipe = None
    if not a.resume and a.data and (Path(a.data) / "recipe.toml").is_file():
        recipe = Path(a.data)
        scenes = training_scenes(recipe, a.split)
        a.data = str(scenes[0])  # the reference scene: rig, frames and the network's grid
    if a.arch == "distg" and not a.tiny:
        for k, v in FULL_DISTG.items():
            setattr(a, k, v if getattr(a, k) is None else getattr(a, k))
    run, state, device, data, ds, train_frames, eval_frames = training.start(a, NAME, TINY, FULL)
    from lfusd.data.dataset import open_dataset

    if state:
        config = state["config"]
    else:
        scenes = scenes if recipe else [Path(data)]
        frames = (training.parse_frames(a.train_frames) if recipe else train_frames) or None
        shifts = [design_shift(sc) for sc in scenes]
        lo, hi = [], []
        for sc, k in zip(scenes, shifts):
            sds = open_dataset(sc, a.rig)
            require_pinhole(sds, "training a light-field network (it shifts views by disparity times their grid offsets)")
            if (sds.rig.rows, sds.rig.cols) != (ds.rig.rows, ds.rig.cols):
                raise LfusdError(f"{sc} has a {sds.rig.rows}x{sds.rig.cols} grid, {scenes[0]} {ds.rig.rows}x{ds.rig.cols}; one network takes one grid")
            r0, r1 = disparity_range(sds, frames or list(sds.frames), shifts=refocus_shifts(k, a.refocus))
            lo.append(r0)
            hi.append(r1)
        caches = None
        if a.cache:
            caches = [str(Path(a.cache) / sc.name) for sc in scenes] if recipe else [a.cache]
        config = {"ang": ds.rig.rows, "d_min": min(lo), "d_max": max(hi), "arch": a.arch,
                  **{k: getattr(a, k) for k in ("disparities", "channels", "blocks", "cost_channels")}}
        config.update(data=str(data), train_frames=frames if recipe else train_frames, eval_frames=eval_frames, crop=a.crop, batch=a.batch, lr=a.lr,
                      tiny=a.tiny, recipe=str(recipe) if recipe else None, scenes=[str(sc) for sc in scenes], shifts=shifts, refocus=a.refocus,
                      caches=caches)
    scenes = [Path(sc) for sc in config.get("scenes", [config["data"]])]
    caches = config.get("caches") or [None] * len(scenes)
    sources = [scene_source(sc, Path(c) if c else None, open_dataset(sc, a.rig)) for sc, c in zip(scenes, caches)]
    train = Augmented(sources, config.get("shifts", [0] * len(scenes)), config["train_frames"], min(config["crop"], ds.rig.height, ds.rig.width),
                      config.get("refocus", 0), a.seed, a.rig)
    model = build(config).to(device)
    opt, start = training.optimiser(model, config["lr"], state)
    run.log["config"] = config
    log.info("%s: %d scenes, %d views, %s network of %d parameters, disparity candidates %.2f..%.2f px", config.get("recipe") or data, len(scenes),
             config["ang"] ** 2, config.get("arch", "distg"), sum(q.numel() for q in model.parameters()), config["d_min"], config["d_max"])

    b = config["batch"]
    loader = torch.utils.data.DataLoader(train, batch_size=b, sampler=range(start * b, max(a.steps, start + 1) * b), num_workers=a.workers, drop_last=True)

    def step(batch):
        views, rel, gt = batch
        pred = model(views.to(device), rel.to(device))
        return (pred - gt.to(device)).abs().mean()

    training.train_loop(model, opt, training.endless(loader), step, run, config, start, a, "disparity")

    if config.get("recipe"):
        log.info("trained on %d scenes of %s; score it on the test split as flow/README.md shows (log %s)", len(scenes), config["recipe"], run.log_path)
        run.log["timing"]["total_s"] = time.time() - t_start
        run.write_log()
        return 0
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
