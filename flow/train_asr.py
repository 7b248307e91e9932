"""Train a DistgASR-like network (flow/models.py ASRNet) for 2x2 -> NxN angular super-resolution.

    python flow/train_asr.py --tiny --out runs/asr                           # toy run on CPU: 2x2 -> 3x3, ~1 min
    python flow/train_asr.py --data OUT --out runs/asr --n 7 --device cuda   # full size: 2x2 -> 7x7
    python flow/train_asr.py --data RECIPE_OUT --cache CACHES --out runs/asr # a recipe's train split, scored on its test split
    python flow/train_asr.py ... --resume --steps 40000                      # continue a run

Input: the four corners of the central N x N views of a uniform grid (all of a 7x7 rig, the
central 7x7 of a 9x9 one: DistgASR's protocol); target: all N x N views; L1 loss on RGB in [0, 1],
read through lfusd.torch (views=corners, target_views=the N x N grid, random crops) from the
dataset folders or, with --cache, from training caches (`lfusd export cache SCENE CACHE --keys rgb`;
for a recipe, CACHES/<scene> for each scene). --data is one dataset folder or a made recipe dataset
(lfusd dataset make): then every scene of its `train` split (--split) is trained on (every frame, or
--train-frames of each) and the trained model is scored on every scene of its `test` split
(--eval-split; --eval-frames of each, default its first frame) in OUT/test/<scene>/, the mean over
all of them in OUT/eval.json. A single dataset is scored on its evaluation frames. The scores are
`lfusd eval --task views` (PSNR/SSIM on Y) over the novel views (the grid without its corners;
predictions in pred/ as <frame>_<row>_<col>.npy), beside the classical baselines of
lfusd.evaluation.baselines scored the same way: angular blending of the corners (pred_blend/) and
a plane sweep at each novel view (pred_plane_sweep/)."""

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
from models import ASRNet  # noqa: E402
from lfusd import LfusdError, layout  # noqa: E402
from lfusd.data.folder import require_pinhole  # noqa: E402

log = logging.getLogger("lfusd.flow")
NAME = "train_asr"
TINY = dict(steps=200, batch=2, crop=32, lr=4e-3, save_every=50, log_every=1, channels=32, blocks=1, n=3)
FULL = dict(steps=20000, batch=8, crop=64, lr=5e-4, save_every=500, log_every=50, channels=64, blocks=4, n=7)


def grid_views(rig, n: int) -> tuple[list, list]:
    """The central n x n views (row-major) and their four corners; refuses a non-uniform grid."""
    if n < 3 or n > min(rig.rows, rig.cols):
        raise LfusdError(f"--n {n} does not fit the {rig.rows}x{rig.cols} grid; use 3..{min(rig.rows, rig.cols)}")
    r0, c0 = (rig.rows - n) // 2, (rig.cols - n) // 2
    grid = [(r, c) for r in range(r0, r0 + n) for c in range(c0, c0 + n)]
    off = np.array([rig.offsets(v) for v in grid], np.float64).reshape(n, n, 2)
    if not (np.allclose(np.diff(off[..., 0], axis=1), off[0, 1, 0] - off[0, 0, 0]) and np.allclose(np.diff(off[..., 1], axis=0), off[1, 0, 1] - off[0, 0, 1])):
        raise LfusdError("angular super-resolution needs a uniform grid of views; render with --spacing uniform")
    corners = [grid[0], grid[n - 1], grid[n * (n - 1)], grid[-1]]
    return grid, corners


def build(config: dict) -> ASRNet:
    return ASRNet(config["n"], ch=config["channels"], n_blocks=config["blocks"])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__.split("\n\n", 1)[1])
    training.common_args(p)
    p.add_argument("--n", type=int, default=None, help="output grid: 2x2 -> NxN (default 7; 3 with --tiny)")
    p.add_argument("--channels", type=int, default=None, help="feature channels")
    p.add_argument("--blocks", type=int, default=None, help="Distg blocks")
    p.add_argument("--split", default="train", help="the split of a recipe dataset given as --data to train on (default train)")
    p.add_argument("--eval-split", default="test", help="the split of a recipe dataset the trained model is scored on (default test)")
    p.add_argument("--cache", default=None, help="training cache of --data (lfusd export cache DATA CACHE --keys rgb); "
                   "for a recipe dataset a folder holding one per scene, named as the scene")
    a = p.parse_args(argv)
    t_start = time.time()
    recipe = None
    if not a.resume and a.data and (Path(a.data) / layout.RECIPE_COPY).is_file():
        recipe = Path(a.data)
        scenes = training.recipe_scenes(recipe, a.split)
        training.recipe_scenes(recipe, a.eval_split)  # refused now, not after the training
        a.data = str(scenes[0])  # the reference scene: the run's data and its default frames
    run, state, device, data, ds, train_frames, eval_frames = training.start(a, NAME, TINY, FULL)
    from lfusd.data.dataset import open_dataset
    from lfusd.torch import LightFieldVideoDataset

    if state:
        config = state["config"]
    else:
        config = {"n": a.n, "channels": a.channels, "blocks": a.blocks, "data": str(data), "train_frames": train_frames, "eval_frames": eval_frames, "crop": a.crop, "batch": a.batch, "lr": a.lr, "tiny": a.tiny}
        if recipe:  # frame lists apply to every scene; [] is every frame (training) and the first frame (scoring)
            config.update(recipe=str(recipe), scenes=[str(sc) for sc in scenes], eval_split=a.eval_split,
                          train_frames=training.parse_frames(a.train_frames) or [], eval_frames=training.parse_frames(a.eval_frames) or [])
        if a.cache:
            config["caches"] = [str(Path(a.cache) / Path(sc).name) for sc in config["scenes"]] if recipe else [a.cache]
    scenes = [Path(sc) for sc in config.get("scenes", [config["data"]])]
    caches = config.get("caches") or [None] * len(scenes)
    parts, crop = [], config["crop"]
    for sc, c in zip(scenes, caches):
        sds = open_dataset(sc, a.rig)
        require_pinhole(sds, "training a light-field network (it shifts views by disparity times their grid offsets)")
        grid, corners = grid_views(sds.rig, config["n"])
        crop = min(crop, sds.rig.height, sds.rig.width)
        frames = config["train_frames"] or None
        if frames and config.get("recipe"):
            frames = [f for f in frames if f in sds.frames] or None
            if frames is None:
                raise LfusdError(f"--train-frames {config['train_frames']} are not in {sc} ({sds.frames[0]}..{sds.frames[-1]}); pick frames every training scene has")
        parts.append((training.scene_source(sc, Path(c) if c else None, sds, ("rgb",)), corners, grid, frames))
    train = torch.utils.data.ConcatDataset([LightFieldVideoDataset(src, keys=("rgb",), views=co, target_views=g, frames=fr, crop=crop, random_crop=True, rig=a.rig)
                                            for src, co, g, fr in parts])
    model = build(config).to(device)
    opt, start = training.optimiser(model, config["lr"], state)
    run.log["config"] = config
    log.info("%s: %d scenes, %d training items, 2x2 -> %dx%d views, %d parameters", config.get("recipe") or data, len(scenes), len(train), config["n"],
             config["n"], sum(q.numel() for q in model.parameters()))

    sampler = torch.utils.data.RandomSampler(train, replacement=True, num_samples=max(a.steps - start, 1) * config["batch"])
    loader = torch.utils.data.DataLoader(train, batch_size=config["batch"], sampler=sampler, num_workers=a.workers, drop_last=True)

    def step(batch):
        pred = model(batch["rgb"].to(device))
        return (pred - batch["target_rgb"].to(device)).abs().mean()

    training.train_loop(model, opt, training.endless(loader), step, run, config, start, a, "2x2 -> %dx%d" % (config["n"], config["n"]))

    t0 = time.time()
    if config.get("recipe"):
        run.log["eval"] = evaluate_split(model, Path(config["recipe"]), config, Path(a.out), device, a)
        where = f"{len(run.log['eval']['scenes'])} {config['eval_split']} scenes"
    else:
        grid, corners = grid_views(ds.rig, config["n"])
        run.log["eval"] = evaluate(model, ds, data, eval_frames, grid, corners, Path(a.out), device, a)
        where = f"frames {eval_frames}"
    run.log["timing"]["eval_s"] = time.time() - t0
    run.log["timing"]["total_s"] = time.time() - t_start
    run.write_log()
    m = run.log["eval"]["model"]["mean"]
    log.info("%s, novel views: PSNR %.2f dB, SSIM %.4f over %d pixels (log %s)", where, m["psnr_db"], m["ssim"], m["pixels"], run.log_path)
    return 0


def evaluate_split(model, recipe: Path, config: dict, out: Path, device, a) -> dict:
    """:func:`evaluate` on every scene of the recipe's ``config["eval_split"]`` (its ``eval_frames``, or
    its first frame) into out/test/<scene>/; returns the same dict with each method's mean over every
    scored view of every scene, and the scenes' own results under ``scenes``."""
    from lfusd.data.dataset import open_dataset

    per_scene, rows = {}, {}
    for sc in training.recipe_scenes(recipe, config["eval_split"]):
        sds = open_dataset(sc, a.rig)
        grid, corners = grid_views(sds.rig, config["n"])
        frames = config["eval_frames"] or [sds.frames[0]]
        bad = [f for f in frames if f not in sds.frames]
        if bad:
            raise LfusdError(f"--eval-frames {bad} are not in {sc} ({sds.frames[0]}..{sds.frames[-1]}); pick frames every scored scene has")
        dest = out / "test" / sc.name
        dest.mkdir(parents=True, exist_ok=True)
        res = evaluate(model, sds, sc, frames, grid, corners, dest, device, a)
        per_scene[sc.name] = {k: v["mean"] for k, v in res.items()}
        for k, v in res.items():
            rows.setdefault(k, []).extend(v["rows"])
    out_res = {k: {"rows": r, "mean": {"psnr_db": float(np.mean([x["psnr_db"] for x in r])), "ssim": float(np.mean([x["ssim"] for x in r])),
                                       "pixels": int(sum(x.get("pixels", 0) for x in r)), "views": len(r)}} for k, r in rows.items()}
    (out / "eval.json").write_text(json.dumps({k: v["mean"] for k, v in out_res.items()} | {"scenes": per_scene}, indent=1, default=float))
    return out_res | {"scenes": per_scene}


@torch.no_grad()
def evaluate(model, ds, data, frames, grid, corners, out: Path, device, a) -> dict:
    """Predict every novel view of every frame, write them where `lfusd eval` reads them and score
    them; the same for angular blending and the plane sweep."""
    from lfusd.evaluation import baselines
    from lfusd.torch import LightFieldVideoDataset

    model.eval()
    novel = [v for v in grid if v not in corners]
    full = LightFieldVideoDataset(data, keys=("rgb",), views=corners, frames=frames, rig=a.rig)
    dirs = {"model": out / "pred"}
    if not a.no_baselines:
        dirs |= {"blend": out / "pred_blend", "plane_sweep": out / "pred_plane_sweep"}
    for d in dirs.values():
        d.mkdir(exist_ok=True)
    offsets = {v: ds.rig.offsets(v) for v in grid}
    for item in full:
        f = int(item["frames"][0])
        pred = model(item["rgb"][None].to(device))[0].clamp(0, 1).permute(0, 2, 3, 1).cpu().numpy()
        for i, v in enumerate(grid):
            if v in novel:
                np.save(dirs["model"] / f"{training.pred_name(f, v)}.npy", pred[i].astype(np.float32))
        if a.no_baselines:
            continue
        imgs = {v: ds.read(f, v, "rgb") for v in corners}
        targets = {v: offsets[v] for v in novel}
        c = tuple(ds.rig.centre_view)
        dc = np.asarray(ds.read(f, c, "disparity"))  # the sweep's range, as baseline_table gives it
        lo, hi = float(dc.min()), float(dc.max())
        pad = 0.1 * max(hi - lo, 0.5)
        for name, views in (("blend", baselines.blend_views(imgs, offsets, targets)), ("plane_sweep", baselines.interpolate_views(imgs, offsets, targets, (lo - pad, hi + pad), n_planes=32, device=device))):
            for v, img in views.items():
                np.save(dirs[name] / f"{training.pred_name(f, v)}.npy", np.clip(img, 0, 1).astype(np.float32))

    def pixels(frame, view):
        return ds.rig.height * ds.rig.width

    res = {k: training.score(ds, d, "views", pixels) for k, d in dirs.items()}
    (out / "eval.json").write_text(json.dumps({k: v["mean"] for k, v in res.items()}, indent=1, default=float))
    return res


if __name__ == "__main__":
    sys.exit(training.main_wrapper(NAME, main))
