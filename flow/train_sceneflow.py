"""Train a light-field scene-flow network (flow/models.py SceneFlowNet) for the centre view.

    python flow/train_sceneflow.py --tiny --out runs/sf                       # toy run on CPU
    python flow/train_sceneflow.py --data OUT --out runs/sf --device cuda     # full size
    python flow/train_sceneflow.py ... --resume --steps 40000                 # continue a run

Reads pairs of frames (t, t+1) of the light field through lfusd.torch (clips of two frames, all
views of a square grid, random crops, the augmentations of lfusd.data.augment that keep the ground
truth consistent: refocus, flips, colour, noise) from a dataset folder or a training cache (`lfusd
export cache`, given with --cache; evaluation reads --data). The network predicts the centre
view's optical flow (PWC-lite), the disparity at t and t+1 (DisparityNet on each light field) and
the disparity change (the disparity at t+1 sampled where the flow carries each pixel, minus the
one at t); the loss is the L1 error of the disparity
at t and t+1 over every pixel plus the end-point error of the flow and the L1 error of the
disparity change over the pixels with valid forward motion. Scene flow follows through the camera
(lfusd.evaluation.baselines.scene_flow_from_change). The model is scored on the evaluation frames
through `lfusd eval --task sceneflow` and `--task flow` (OUT/pred/, OUT/pred_flow/), beside the
classical composition (plane sweep + DIS, OUT/pred_composition/, OUT/pred_composition_flow/).
Training frames are clip starts t (t+1 and t+2 must be in the dataset: the loader reads the
forward motion of both frames); evaluation frames are pairs t -> t+1.
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
from models import SceneFlowNet  # noqa: E402
from lfusd import LfusdError, layout  # noqa: E402
from lfusd.data.folder import require_pinhole  # noqa: E402

log = logging.getLogger("lfusd.flow")
NAME = "train_sceneflow"
KEYS = ("rgb", "disparity", "flow_fwd", "disparity_change", "valid_fwd")
TINY = dict(steps=200, batch=2, crop=32, lr=2e-3, save_every=50, log_every=1, channels=8, blocks=1, cost_channels=8, disparities=9,
            flow_channels=8, flow_levels=2, radius=2, refocus=0, translate=0, flow_arch="pwc")
FULL = dict(steps=40000, batch=8, crop=64, lr=5e-4, save_every=500, log_every=50, channels=16, blocks=4, cost_channels=32, disparities=33,
            flow_channels=24, flow_levels=4, radius=4, refocus=1, translate=6, flow_arch="pwc")
# the --tiny dataset: frames 1-4 of the bundled street (cars, people) seen by its 3x3 rig at 48x48
TINY_SCENE = (training.ROOT / "stages" / "street_dynamic_00.usda", None,
              ["--rig", "rig_00", "--frames", "1-4", "--resolution", "48x48", "--samples", "4", "--quiet"])
NET = ("disparities", "channels", "blocks", "cost_channels", "flow_channels", "flow_levels", "radius", "flow_arch")


def build(config: dict) -> SceneFlowNet:
    """The network a run's configuration describes (also what predict_sceneflow.py loads): its
    disparity half is train_disparity.py's network of ``config["disparity_net"]`` when the run
    started from disparity weights (--disparity-weights), else a DisparityNet of the run's size."""
    disparity = None
    if config.get("disparity_net"):
        from train_disparity import build as build_disparity

        disparity = build_disparity(config["disparity_net"])
    return SceneFlowNet(config["ang"], config["d_min"], config["d_max"], config["disparities"], ch=config["channels"], n_blocks=config["blocks"],
                        cost_ch=config["cost_channels"], flow_ch=config["flow_channels"], flow_levels=config["flow_levels"], radius=config["radius"],
                        disparity=disparity, flow_arch=config.get("flow_arch", "pwc"))


def start_disparity(path: str, ang: int) -> tuple[dict, dict]:
    """(the disparity network's config, its weights) of a train_disparity.py checkpoint, checked to
    take this grid."""
    state = training.load_weights(path, "train_disparity")
    config = dict(state["config"])
    if int(config.get("ang", -1)) != int(ang):
        raise LfusdError(f"the disparity weights {path} take a {config.get('ang')}x{config.get('ang')} grid, the data has {ang}x{ang}; "
                         "train disparity on this grid or leave --disparity-weights out")
    keep = ("ang", "d_min", "d_max", "arch", "disparities", "channels", "blocks", "cost_channels")
    return {k: config[k] for k in keep if k in config}, state["model"]


def split_pairs(ds, a) -> tuple[list[int], list[int]]:
    """Training clip starts (t with t+1 and t+2 in the dataset) and evaluation pairs (t with t+1):
    by default the last pair is evaluated and every earlier start trained on."""
    frames = list(ds.frames)
    train = training.parse_frames(a.train_frames) or [t for t in frames[:-2] if t + 2 in frames]
    evalf = training.parse_frames(a.eval_frames) or [t for t in frames[-2:-1] if t + 1 in frames]
    bad_t = [t for t in train if t not in frames or t + 1 not in frames or t + 2 not in frames]
    bad_e = [t for t in evalf if t not in frames or t + 1 not in frames]
    if bad_t or bad_e or not train or not evalf:
        raise LfusdError(f"scene flow trains on frames t with t+1 and t+2 and evaluates frames t with t+1 in the dataset "
                         f"({frames[0]}..{frames[-1]}, {len(frames)} frames); {bad_t + bad_e or 'none are left'}: "
                         "render at least 3 frames or pick --train-frames/--eval-frames inside it")
    return train, evalf


def clips(data, frames, crop, random_crop, rig=None):
    """Two-frame clips of every view with the motion keys (lfusd.torch.LightFieldVideoDataset)."""
    from lfusd.torch import LightFieldVideoDataset

    return LightFieldVideoDataset(data, keys=KEYS, views="all", frames=frames, clip=2, crop=crop, random_crop=random_crop, rig=rig)


def centre_index(item_views, centre) -> int:
    return [tuple(v) for v in item_views.tolist()].index(tuple(centre))


def loss_of(out: dict, batch: dict, ci: int, device) -> torch.Tensor:
    """L1 of the disparity at t and t+1 (every pixel), flow EPE and L1 of the disparity change where
    the forward motion is valid; each term averaged over its pixels."""
    disp = batch["disparity"][:, :, ci].to(device)  # B,T,h,w
    flow = batch["flow_fwd"][:, 0, ci].to(device)  # B,2,h,w
    dch = batch["disparity_change"][:, 0, ci].to(device)
    valid = batch["valid_fwd"][:, 0, ci].to(device) & torch.isfinite(flow).all(1) & torch.isfinite(dch)
    n = valid.sum().clamp(min=1)
    l_disp = (out["disparity"] - disp[:, 0]).abs().mean() + (out["disparity_next"] - disp[:, 1]).abs().mean()
    epe = torch.linalg.vector_norm(out["flow"] - torch.nan_to_num(flow), dim=1)
    l_flow = (epe * valid).sum() / n
    l_dch = ((out["disparity_change"] - torch.nan_to_num(dch)).abs() * valid).sum() / n
    return l_disp + l_flow + l_dch


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__.split("\n\n", 1)[1])
    training.common_args(p)
    training.disparity_net_args(p, "Distg blocks in the disparity network's feature extractor")
    p.add_argument("--flow-channels", type=int, default=None, help="feature channels of the flow network's finest level")
    p.add_argument("--flow-levels", type=int, default=None, help="pyramid levels of the flow network")
    p.add_argument("--radius", type=int, default=None, help="search radius of the flow correlation in pixels of each level")
    p.add_argument("--flow-arch", choices=("pwc", "dis"), default=None, help="pwc: the PWC-lite FlowNet (default); dis: OpenCV DIS refined by a CNN "
                   "(models.DISRefineFlow: --flow-channels wide, --flow-levels dilated layers)")
    p.add_argument("--refocus", type=int, default=None, help="largest refocus shift k of the augmentation (disparity d -> d - k); 0: none")
    p.add_argument("--translate", type=int, default=None, help="translate frame t+1 of half the samples by up to this many whole pixels in x and y "
                   "(lfusd.data.augment.translate_next: every pixel's flow grows by the shift), so that the flow network sees every pixel move; 0: none")
    p.add_argument("--cache", default=None, help="read the training samples from this training cache of --data (lfusd export cache DATA CACHE): memory maps, "
                   "no decoding; for a recipe dataset a folder holding one per scene, named as the scene")
    p.add_argument("--split", default="train", help="the split of a recipe dataset given as --data to train on (default train)")
    p.add_argument("--eval-split", default="test", help="the split of a recipe dataset scored after training, every pair t -> t+1 of each scene (default test)")
    p.add_argument("--disparity-weights", default=None, help="start the disparity half from this train_disparity.py checkpoint (its network and "
                   "candidates replace --channels ... --disparities), e.g. flow/weights/disparity.pt")
    p.add_argument("--references", choices=("centre", "all"), default=None, help="the reference view the network is trained to predict: centre "
                   "(default), or all: each batch a view drawn at random, so that one network serves every view (lfusd bench scores every view)")
    p.add_argument("--freeze-disparity", action="store_true", help="with --disparity-weights: keep the disparity half fixed and train the flow network "
                   "(loss: flow and disparity change)")
    a = p.parse_args(argv)
    t_start = time.time()
    recipe = None
    if not a.resume and a.data and any((Path(a.data) / n).is_file() for n in (layout.RECIPE_COPY, layout.BENCH_RECORD)):
        recipe = Path(a.data)
        scenes = training.recipe_scenes(recipe, a.split)
        a.data = str(scenes[0])  # the reference scene: rig, frames and the network's grid
    if a.freeze_disparity and not a.disparity_weights and not a.resume:
        raise LfusdError("--freeze-disparity keeps trained disparity weights fixed; give them with --disparity-weights W")
    run, state, device, data, ds, _, _ = training.start(a, NAME, TINY, FULL, TINY_SCENE)
    r = ds.rig
    if r.rows != r.cols:
        raise LfusdError(f"the disentangling network needs a square grid of views, got {r.rows}x{r.cols}; render with --grid NxN")
    from lfusd.data.dataset import open_dataset

    disparity_weights = None
    if state:
        config = state["config"]
    else:
        train_frames, eval_frames = split_pairs(ds, a)
        scenes = scenes if recipe else [Path(data)]
        for sc in scenes[1:]:
            sds = open_dataset(sc, a.rig)
            require_pinhole(sds, "training a light-field network (it shifts views by disparity times their grid offsets)")
            if (sds.rig.rows, sds.rig.cols) != (r.rows, r.cols) or any(f not in sds.frames for t in train_frames for f in (t, t + 1, t + 2)):
                raise LfusdError(f"{sc} lacks frames {train_frames} (+2) of a {r.rows}x{r.cols} grid that {scenes[0]} has; one run takes one grid and clip")
        k = int(a.refocus)  # refocusing by k moves every disparity by -k
        if a.disparity_weights:
            disparity_net, disparity_weights = start_disparity(a.disparity_weights, r.rows)
            d_min, d_max = disparity_net["d_min"], disparity_net["d_max"]
            sizes = {n: disparity_net.get(n) for n in ("disparities", "channels", "blocks", "cost_channels")}
        else:
            from train_disparity import disparity_range

            disparity_net, sizes = None, {}
            ranges = [disparity_range(open_dataset(sc, a.rig), sorted(set(train_frames) | {t + 1 for t in train_frames})) for sc in scenes]
            d_min, d_max = min(x[0] for x in ranges) - k, max(x[1] for x in ranges) + k
        config = {"ang": r.rows, "d_min": d_min, "d_max": d_max, **{n: getattr(a, n) for n in NET}, **sizes}
        caches = None
        if a.cache:
            caches = [str(Path(a.cache) / sc.name) for sc in scenes] if recipe else [a.cache]
        config.update(data=str(data), train_frames=train_frames, eval_frames=eval_frames, crop=a.crop, batch=a.batch, lr=a.lr, tiny=a.tiny,
                      refocus=k, centre=list(r.centre_view), baseline=float(r.baseline), recipe=str(recipe) if recipe else None,
                      scenes=[str(sc) for sc in scenes], caches=caches, cache=caches[0] if caches and not recipe else None,
                      eval_split=a.eval_split if recipe else None, disparity_net=disparity_net, disparity_weights=a.disparity_weights,
                      freeze_disparity=bool(a.freeze_disparity), translate=int(a.translate), references=a.references or "centre")
    from lfusd.data.augment import refocus_margin

    offsets = [r.offsets(v) for v in ds.views]
    my, mx = refocus_margin(offsets, config["refocus"])
    shift = int(config.get("translate", 0))
    crop = (min(config["crop"] + 2 * (my + shift), r.height), min(config["crop"] + 2 * (mx + shift), r.width))
    augment = dict(refocus=config["refocus"], flip=True, brightness=0.2, contrast=0.2, saturation=0.2, noise=0.02)
    scenes = [Path(sc) for sc in config.get("scenes") or [config["data"]]]
    if config.get("recipe"):
        caches = config.get("caches") or [None] * len(scenes)
        sources = [training.scene_source(sc, Path(c) if c else None, open_dataset(sc, a.rig), KEYS) for sc, c in zip(scenes, caches)]
    else:
        cache = a.cache or config.get("cache")
        sources = [training.scene_source(Path(data), Path(cache) if cache else None, ds, KEYS)]
        config["cache"] = a.cache or config.get("cache")
    refs = len(ds.views) if config.get("references") == "all" else None
    train = Samples([clips(src, config["train_frames"], crop, True, a.rig) for src in sources], a.seed, augment, shift, refs, config["batch"])
    model = build(config).to(device)
    if disparity_weights is not None:
        model.disparity.load_state_dict(disparity_weights)
    if config.get("freeze_disparity"):
        model.disparity.requires_grad_(False)
    opt, start = training.optimiser(model, config["lr"], state)
    run.log["config"] = config
    log.info("%s: %d scenes, %d training pairs each, %d views, %d parameters (%d trained), disparity candidates %.2f..%.2f px",
             config.get("recipe") or data, len(scenes), len(config["train_frames"]), config["ang"] ** 2, sum(q.numel() for q in model.parameters()),
             sum(q.numel() for q in model.parameters() if q.requires_grad), config["d_min"], config["d_max"])

    b = config["batch"]
    loader = torch.utils.data.DataLoader(train, batch_size=b, sampler=range(start * b, max(a.steps, start + 1) * b), num_workers=a.workers, drop_last=True)
    centre = tuple(config["centre"])

    def step(batch):
        ci = int(batch["ref"][0]) if "ref" in batch else centre_index(batch["views"][0], centre)
        rel = (batch["offsets"] - batch["offsets"][:, ci : ci + 1]).to(device, torch.float32)
        rgb = batch["rgb"].to(device)  # B,T,V,3,h,w
        out = model(rgb[:, 0], rgb[:, 1], rel, ci)
        return loss_of(out, batch, ci, device)

    training.train_loop(model, opt, training.endless(loader), step, run, config, start, a, "scene flow")

    t0 = time.time()
    if config.get("recipe"):
        run.log["eval"] = evaluate_split(model, config, Path(a.out), device, a)
        m, f = run.log["eval"]["pooled"]["model"], run.log["eval"]["pooled"]["model_flow"]
    else:
        run.log["eval"] = evaluate(model, ds, config, Path(a.out), device, a)
        m, f = run.log["eval"]["model"]["mean"], run.log["eval"]["model_flow"]["mean"]
    run.log["timing"]["eval_s"] = time.time() - t0
    run.log["timing"]["total_s"] = time.time() - t_start
    run.write_log()
    log.info("EPE3D %.4f m, flow EPE %.3f px (log %s)", m["epe3d_m"], f["epe_px"], run.log_path)
    return 0


class Samples(torch.utils.data.Dataset):
    """Training sample n of a run: a scene and a clip of it drawn, cropped (lfusd.torch's random crop) and augmented
    (lfusd.data.augment.RandomLightField, then for half the samples translate_next by up to
    ``translate`` px) from the run's seed and n alone, in any process, so that
    a resumed run sees exactly the batches the uninterrupted one would have seen. With ``references``
    (the number of views), each sample's ``ref`` is the index of the view its loss is taken on,
    drawn per batch of ``batch`` samples (the network takes one reference view per batch)."""

    def __init__(self, clips: list, seed: int, augment: dict, translate: int = 0, references: int | None = None, batch: int = 1):
        self.clips, self.seed, self.augment, self.translate = list(clips), int(seed), augment, int(translate)
        self.references, self.batch = references, max(int(batch), 1)

    def __len__(self):
        return 2**62

    def __getitem__(self, n: int) -> dict:
        from lfusd.data.augment import RandomLightField

        with torch.random.fork_rng(devices=[]):
            torch.manual_seed((self.seed * 2_654_435_761 + int(n)) % 2**63)
            c = self.clips[int(torch.randint(len(self.clips), ())) if len(self.clips) > 1 else 0]  # a scene, then one of its clips
            item = c[int(torch.randint(len(c), ()))]
        item = RandomLightField(seed=[self.seed, int(n)], **self.augment)(item)
        if self.references:
            # an index into the item's views: flips and transposes reorder the pixels, not the offsets
            item = {**item, "ref": int(np.random.default_rng([self.seed, int(n) // self.batch, 2]).integers(self.references))}
        if not self.translate:
            return item
        from lfusd.data.augment import translate_next

        rng = np.random.default_rng([self.seed, int(n), 1])
        dx, dy = rng.integers(-self.translate, self.translate + 1, 2) if rng.random() < 0.5 else (0, 0)
        return translate_next(item, int(dx), int(dy), self.translate)


@torch.no_grad()
def predict(model, views0, views1, rel, ref: int) -> dict:
    """The network's outputs for one pair as NumPy arrays: flow (H,W,2), disparity, disparity_next,
    disparity_change (H,W); views [N,3,H,W] float in [0, 1], rel [N,2]."""
    model.eval()
    p = next(model.parameters())
    return as_arrays(model(views0[None].to(p), views1[None].to(p), rel[None].to(p), ref))


def as_arrays(out: dict) -> dict:
    """The first item of the network's outputs as NumPy float32: flow (H,W,2), the others (H,W)."""
    res = {k: v[0].cpu().numpy().astype(np.float32) for k, v in out.items()}
    res["flow"] = np.ascontiguousarray(res["flow"].transpose(1, 2, 0))
    return res


def write_prediction(dest: Path, stem: str, res: dict, sf: np.ndarray) -> list[Path]:
    """Where `lfusd eval --task sceneflow` reads a prediction: <stem>.npy (scene flow) with
    <stem>_disp.pfm, <stem>_disp2.pfm (disparity at t+1 of the point seen at t) and <stem>_flow.flo;
    also <stem>_dchange.pfm and <stem>_disp_next.pfm (disparity at t+1 of its own pixels)."""
    from lfusd.data import formats

    dest.mkdir(parents=True, exist_ok=True)
    files = {f"{stem}_disp.pfm": res["disparity"], f"{stem}_disp2.pfm": res["disparity"] + res["disparity_change"],
             f"{stem}_dchange.pfm": res["disparity_change"], f"{stem}_disp_next.pfm": res["disparity_next"]}
    for name, arr in files.items():
        formats.write_pfm(dest / name, arr)
    formats.write_flo(dest / f"{stem}_flow.flo", res["flow"])
    np.save(dest / f"{stem}.npy", sf.astype(np.float32))
    return [dest / n for n in [*files, f"{stem}_flow.flo", f"{stem}.npy"]]


def scene_flow(res: dict, K, pose0, pose1, baseline: float) -> np.ndarray:
    """World-frame scene flow (H,W,3) of a prediction through lfusd's composition; zero where it is
    undefined (no surface predicted), so every valid ground-truth pixel is scored."""
    from lfusd.evaluation.baselines import scene_flow_from_change

    sf, ok = scene_flow_from_change(res["disparity"], res["disparity_change"], res["flow"], K, pose0, pose1, baseline)
    return np.where(ok[..., None], sf, 0.0).astype(np.float32)


def load_pair(ds, t: int, views):
    """All views of frames t and t+1 as float tensors [N,3,H,W] in [0, 1]."""
    def one(f):
        return torch.stack([torch.from_numpy(np.asarray(ds.read(f, v, "rgb"), np.float32) / 255.0).permute(2, 0, 1) for v in views])

    return one(t), one(t + 1)


def evaluate(model, ds, config, out: Path, device, a, frames=None, sweep_range=None) -> dict:
    """Predict the centre view of every evaluation pair (``frames``, default the run's), write it
    where `lfusd eval` reads it and score it (scene flow and flow); the same for the plane sweep +
    DIS composition, its plane sweep over ``sweep_range`` (default the network's candidates)."""
    from lfusd.evaluation import baselines
    from lfusd.data import formats

    centre = tuple(config["centre"])
    views = [tuple(v) for v in ds.views]
    rel = torch.tensor(np.array([np.subtract(ds.rig.offsets(v), ds.rig.offsets(centre)) for v in views]), dtype=torch.float32)
    ci = views.index(centre)
    K = ds.intrinsics(centre)
    dirs = {n: out / n for n in ("pred", "pred_flow", "pred_composition", "pred_composition_flow")}
    for d in dirs.values():
        d.mkdir(parents=True, exist_ok=True)
    offsets = {v: ds.rig.offsets(v) for v in views}
    for t in frames or config["eval_frames"]:
        stem = training.pred_name(t, centre)
        poses = ds.cam_to_world(t, centre), ds.cam_to_world(t + 1, centre)
        v0, v1 = load_pair(ds, t, views)
        res = predict(model, v0, v1, rel, ci)
        write_prediction(dirs["pred"], stem, res, scene_flow(res, K, *poses, ds.rig.baseline))
        formats.write_flo(dirs["pred_flow"] / f"{stem}.flo", res["flow"])
        if not a.no_baselines:
            rng = sweep_range or (config["d_min"], config["d_max"])
            d = [baselines.plane_sweep_disparity({v: ds.read(f, v, "rgb") for v in views}, offsets, offsets[centre], rng, 64, 9, device=device) for f in (t, t + 1)]
            flow = baselines.dis_flow(ds.read(t, centre, "rgb"), ds.read(t + 1, centre, "rgb"))
            sf, dch, ok = baselines.scene_flow_from(d[0], d[1], flow, K, *poses, ds.rig.baseline)
            comp = {"disparity": d[0], "disparity_change": np.where(ok, dch, 0.0), "disparity_next": d[1], "flow": flow}
            write_prediction(dirs["pred_composition"], stem, comp, np.where(ok[..., None], sf, 0.0))
            formats.write_flo(dirs["pred_composition_flow"] / f"{stem}.flo", flow)
    res = {"model": training.score(ds, dirs["pred"], "sceneflow"), "model_flow": training.score(ds, dirs["pred_flow"], "flow")}
    if not a.no_baselines:
        res["composition"] = training.score(ds, dirs["pred_composition"], "sceneflow")
        res["composition_flow"] = training.score(ds, dirs["pred_composition_flow"], "flow")
    (out / "eval.json").write_text(json.dumps({k: v["mean"] for k, v in res.items()}, indent=1, default=float))
    return res


def evaluate_split(model, config, out: Path, device, a) -> dict:
    """Score every pair t -> t+1 of every scene of the recipe's evaluation split (scenes never
    trained on) as :func:`evaluate` does, into OUT/<split>/<scene>/; the composition's plane sweep
    spans each scene's own true disparity range (+10 %), as flow/disparity_table.py gives it.
    Returns the per-scene scores and their means over every scored pixel per template and pooled."""
    from lfusd.data.dataset import open_dataset
    from lfusd.recipe import scene_template
    from train_disparity import disparity_range

    split = config.get("eval_split") or "test"
    scenes = training.recipe_scenes(Path(config["recipe"]), split)
    per_scene, groups = {}, {}
    for sc in scenes:
        sds = open_dataset(sc, a.rig)
        frames = training.parse_frames(a.eval_frames) or [t for t in sds.frames if t + 1 in sds.frames]
        rng = disparity_range(sds, sorted(set(frames) | {t + 1 for t in frames}))
        res = evaluate(model, sds, config, out / split / sc.name, device, a, frames=frames, sweep_range=rng)
        per_scene[sc.name] = {k: v["mean"] for k, v in res.items()}
        groups.setdefault(scene_template(sc) or sc.name, []).append(per_scene[sc.name])
    pooled = {g: pool(rows) for g, rows in groups.items()}
    pooled["all"] = pool(list(per_scene.values()))
    result = {"split": split, "scenes": per_scene, "groups": pooled, "pooled": pooled["all"]}
    (out / "eval.json").write_text(json.dumps(result, indent=1, default=float))
    return result


def pool(rows: list[dict]) -> dict:
    """Per method, each metric's mean over every scored pixel of the given scenes (each scene's
    mean weighted by its pixel count)."""
    out = {}
    for method in rows[0]:
        ms = [r[method] for r in rows if method in r]
        w = np.array([float(m.get("pixels", 0)) for m in ms])
        keys = [k for k, v in ms[0].items() if isinstance(v, (int, float)) and k != "pixels"]
        out[method] = {k: float(np.average([m[k] for m in ms], weights=w)) if w.sum() > 0 else float(np.mean([m[k] for m in ms])) for k in keys}
        out[method]["pixels"] = int(w.sum())
    return out


if __name__ == "__main__":
    sys.exit(training.main_wrapper(NAME, main))
