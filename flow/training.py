"""What flow/train_disparity.py and flow/train_asr.py share: arguments, the tiny dataset,
checkpoints and resume, the JSON training log, the rich progress bar and scoring through
`lfusd eval` (lfusd.evaluation.score); and what the predict scripts share: their options, reading
an HCI-layout folder or opening an lfusd dataset, loading weights and one-line errors."""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lfusd import LfusdError  # noqa: E402
from lfusd import layout  # noqa: E402
from lfusd.data.folder import atomic_write  # noqa: E402

log = logging.getLogger("lfusd.flow")

# The --tiny dataset: the bundled static boxes seen by a small 3x3 rig, two frames.
TINY_STAGE = ROOT / "stages" / "static_boxes.usda"
TINY_RIG = ["--name", "tiny", "--grid", "3x3", "--baseline", "0.25", "--resolution", "48x48", "--at", "0.5,-7,2.2", "--look-at", "0,1,0.6"]
TINY_RENDER = ["--rig", "tiny", "--frames", "1-2", "--samples", "4", "--quiet"]
CHECKPOINT = "last.pt"


def parse_frames(text: str | None) -> list[int] | None:
    """'1-5,8' -> [1, 2, 3, 4, 5, 8]; None stays None."""
    if text is None:
        return None
    out = []
    try:
        for part in text.split(","):
            a, _, b = part.partition("-")
            out += list(range(int(a), int(b or a) + 1))
    except ValueError:
        raise LfusdError(f"frames {text!r} are not N, A-B or a list such as 1-5,8") from None
    return out


def disparity_net_args(p: argparse.ArgumentParser, blocks: str) -> None:
    """The options of a disparity network's size (train_disparity.py's network, the disparity half
    of train_sceneflow.py's): feature channels and blocks, cost-volume channels and candidates."""
    p.add_argument("--channels", type=int, default=None, help="feature channels of the disparity network")
    p.add_argument("--blocks", type=int, default=None, help=blocks)
    p.add_argument("--cost-channels", type=int, default=None, help="channels of the disparity cost volume")
    p.add_argument("--disparities", type=int, default=None, help="disparity candidates of the cost volume")


def common_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--data", default=None, help="dataset folder (lfusd render-video output); with --tiny, rendered there when it holds none")
    p.add_argument("--out", required=True, help="run folder: checkpoints/, train_log.json, pred/, eval_*.json")
    p.add_argument("--rig", default=None, help="rig name, for a dataset with several rigs")
    p.add_argument("--tiny", action="store_true", help="toy run on CPU: a tiny network on a tiny rendered dataset, ~1 minute")
    p.add_argument("--train-frames", default=None, help="frames to train on, e.g. 1-40 (default: all but the last; all when there is one)")
    p.add_argument("--eval-frames", default=None, help="frames to evaluate (default: the last)")
    p.add_argument("--steps", type=int, default=None, help="total optimiser steps (with --resume: up to this many in all)")
    p.add_argument("--batch", type=int, default=None, help="batch size")
    p.add_argument("--crop", type=int, default=None, help="side of the random training crops in pixels")
    p.add_argument("--lr", type=float, default=None, help="Adam learning rate")
    p.add_argument("--save-every", type=int, default=None, help="write a checkpoint every N steps (and at the end)")
    p.add_argument("--log-every", type=int, default=None, help="record the mean loss every N steps in train_log.json")
    p.add_argument("--workers", type=int, default=0, help="DataLoader worker processes")
    p.add_argument("--device", default="cpu", choices=["cpu", "cuda"], help="torch device")
    p.add_argument("--resume", action="store_true", help="continue from OUT/checkpoints/last.pt (model, optimiser, step)")
    p.add_argument("--no-baselines", action="store_true", help="skip scoring the classical baselines beside the model")
    p.add_argument("--threads", type=int, default=None, help="CPU threads of torch (default 1 with --tiny: toy tensors gain nothing from more, and on a busy machine extra threads spin)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def start(a, script: str, tiny: dict, full: dict, tiny_scene: tuple | None = None):
    """Open the run folder (and its checkpoint with --resume), fill unset options with the --tiny or
    full-size defaults, set torch up and find (or render) the dataset.

    ``tiny_scene``: (stage, ``lfusd rig add`` arguments or None to use the stage's rig, ``lfusd
    render-video`` arguments) of the --tiny dataset instead of :data:`TINY_STAGE` and its settings.
    Returns (run, checkpoint state or None, device, dataset folder, reader, train frames, eval frames).
    """
    t0 = time.time()
    if a.data and not a.resume and (Path(a.data) / layout.MANIFEST).is_file():  # refused before the run folder is made
        from lfusd.data.dataset import open_dataset
        from lfusd.data.folder import require_pinhole

        require_pinhole(open_dataset(a.data, a.rig), "training a light-field network (it shifts views by disparity times their grid offsets)")
    run = Run(a.out, script)
    state = run.load() if a.resume else None
    if state:  # a resumed run keeps its kind and its data unless told otherwise
        a.tiny = a.tiny or bool(state["config"].get("tiny"))
        a.data = a.data or state["config"].get("data")
        log.info("resuming %s at step %d", run.ckpt, state["step"])
    fill_defaults(a, tiny, full)
    torch.manual_seed(a.seed)
    if state:
        torch.set_rng_state(state["rng"])
    device = device_of(a.device, a.threads)
    data = resolve_data(a, tiny_scene)
    run.log["timing"]["render_s"] = time.time() - t0
    from lfusd.data.dataset import open_dataset
    from lfusd.data.folder import require_pinhole

    ds = open_dataset(data, a.rig)
    require_pinhole(ds, "training a light-field network (it shifts views by disparity times their grid offsets)")
    if state:
        train, evalf = state["config"]["train_frames"], state["config"]["eval_frames"]
    else:
        train, evalf = split_frames(ds, a)
    return run, state, device, data, ds, train, evalf


def fill_defaults(a, tiny: dict, full: dict) -> None:
    """Unset options take the --tiny or the full-size defaults."""
    for k, v in (tiny if a.tiny else full).items():
        if getattr(a, k, None) is None:
            setattr(a, k, v)
    if a.threads is None and a.tiny:
        a.threads = 1


def device_of(name: str, threads: int | None = None) -> torch.device:
    if threads:
        torch.set_num_threads(threads)
    if name == "cuda" and not torch.cuda.is_available():
        raise LfusdError("--device cuda but PyTorch sees no CUDA device; use --device cpu or a CUDA build of torch")
    return torch.device(name)


def lfusd_cli(*args) -> None:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    r = subprocess.run([sys.executable, "-m", "lfusd", *map(str, args)], env=env, capture_output=True, text=True)
    if r.returncode != 0:
        last = (r.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise LfusdError(f"rendering the tiny dataset failed ({last}); render one yourself and pass --data")


def tiny_dataset(dest: Path, scene: tuple | None = None) -> Path:
    """Render the tiny dataset (``scene``: see :func:`start`) into ``dest`` unless it already holds
    one; returns ``dest``."""
    stage_src, rig_args, render_args = scene or (TINY_STAGE, TINY_RIG, TINY_RENDER)
    if (dest / layout.MANIFEST).is_file():
        log.info("reusing the dataset in %s", dest)
        return dest
    dest.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    stage = dest.parent / f"{dest.name}_stage.usda"
    if stage.exists():
        stage.unlink()
    if rig_args is None:
        stage = stage_src
    else:
        lfusd_cli("rig", "add", stage_src, *rig_args, "-o", stage)
    lfusd_cli("render-video", stage, "-o", dest, *render_args, "--overwrite")
    log.info("rendered the tiny dataset into %s in %.1f s", dest, time.time() - t0)
    return dest


def resolve_data(a, tiny_scene: tuple | None = None) -> Path:
    if a.tiny:
        return tiny_dataset(Path(a.data) if a.data else Path(a.out) / "tiny_data", tiny_scene)
    if not a.data:
        raise LfusdError("no dataset: give --data OUT (a folder written by lfusd render-video) or --tiny")
    if not (Path(a.data) / layout.MANIFEST).is_file():
        raise LfusdError(f"{a.data} holds no lfusd dataset ({layout.MANIFEST} missing); render one with lfusd render-video")
    return Path(a.data)


def split_frames(ds, a) -> tuple[list[int], list[int]]:
    frames = list(ds.frames)
    train = parse_frames(a.train_frames) or (frames[:-1] if len(frames) > 1 else frames)
    evalf = parse_frames(a.eval_frames) or frames[-1:]
    bad = [f for f in train + evalf if f not in frames]
    if bad:
        raise LfusdError(f"frames {bad} are not in the dataset ({frames[0]}..{frames[-1]}); pick --train-frames/--eval-frames inside it")
    return train, evalf


# ---- a recipe's scenes and their training caches ----------------------------------------------


def recipe_scenes(data: Path, split: str) -> list[Path]:
    """The dataset folders to train on: ``data`` itself, the scenes of ``split`` of a made recipe
    dataset (lfusd dataset make: its complete, verified scenes), or of a benchmark folder (lfusd
    bench make: ``public/<split>/``, train and val only; its test ground truth is not public)."""
    from lfusd.recipe import split_scenes

    data = Path(data)
    if (data / layout.BENCH_RECORD).is_file():
        from lfusd.bench.make import read_record

        if split not in ("train", "val"):
            raise LfusdError(f"benchmark {data} publishes ground truth for its train and val splits only; pick --split/--eval-split train or val")
        scenes = [data / layout.BENCH_PUBLIC / split / name for name in read_record(data)["splits"].get(split, [])]
        missing = [sc for sc in scenes if not (sc / layout.MANIFEST).is_file()]
        if missing or not scenes:
            raise LfusdError(f"benchmark {data} has no public {split} scene{f' at {missing[0]}' if missing else 's'}; rerun `lfusd bench make` to finish it")
        return scenes
    if not (data / layout.RECIPE_COPY).is_file():
        return [data]
    scenes = split_scenes(data).get(split, [])
    if not scenes:
        raise LfusdError(f"the recipe dataset {data} has no complete, verified scene in split {split!r}; make it with 'lfusd dataset make' or pick --split")
    return scenes


def scene_source(folder: Path, cache: Path | None, ds, keys):
    """What a scene's items are read from: its training cache when given (rig, frames and ``keys``
    checked against the scene's reader ``ds``), else the scene's folder."""
    if cache is None:
        return folder
    from lfusd.data.cache import TrainingCache, is_cache

    make = f"make it with 'lfusd export cache {folder} {cache} --keys {','.join(keys)}'"
    if not is_cache(cache):
        raise LfusdError(f"{cache} is no training cache; {make}")
    c = TrainingCache(cache)
    a, b = c.rig, ds.rig
    same_rig = (a.rows, a.cols, a.width, a.height) == (b.rows, b.cols, b.width, b.height) and c.rig_name == getattr(ds, "rig_name", b.name)
    if any(k not in c.keys for k in keys) or not same_rig or list(c.frames) != list(ds.frames):
        raise LfusdError(f"the training cache {cache} is not one of {folder} with {', '.join(keys)}; {make}")
    return c


# ---- checkpoints and the training log ----------------------------------------------------------


class Run:
    """The run folder: checkpoints/last.pt and train_log.json (loss history, timing, scores)."""

    def __init__(self, out, script: str):
        self.out = Path(out)
        self.out.mkdir(parents=True, exist_ok=True)
        self.ckpt = self.out / "checkpoints" / CHECKPOINT
        self.log_path = self.out / "train_log.json"
        self.log = {"script": script, "config": {}, "history": [], "resumed_at": [], "timing": {}}

    def save(self, model, opt, step: int, config: dict) -> None:
        """Write the checkpoint (atomically) and the log up to ``step``."""
        self.ckpt.parent.mkdir(exist_ok=True)
        state = {"model": model.state_dict(), "optimizer": opt.state_dict(), "step": step, "config": config, "rng": torch.get_rng_state()}
        atomic_write(self.ckpt, lambda tmp: torch.save(state, tmp))  # a crash mid-write leaves the previous checkpoint whole
        self.log["checkpoint_step"] = step
        self.write_log()

    def load(self) -> dict:
        """The checkpoint, loaded as tensors and plain data only (``weights_only=True``: a crafted
        file cannot run code) and checked field by field (:func:`check_state`)."""
        import pickle

        if not self.ckpt.is_file():
            raise LfusdError(f"no checkpoint at {self.ckpt}; run once without --resume first")
        try:
            state = torch.load(self.ckpt, map_location="cpu", weights_only=True)
        except (pickle.UnpicklingError, RuntimeError, EOFError, ValueError, TypeError, AttributeError, OSError) as e:
            why = (str(e).strip().splitlines() or [type(e).__name__])[0][:200]
            raise LfusdError(f"{self.ckpt} is not a checkpoint these scripts write ({why}); "
                             "delete it and run without --resume") from None
        state = check_state(state, self.ckpt)
        if self.log_path.is_file():
            self.log = json.loads(self.log_path.read_text())
        # losses logged after the checkpoint was written are retrained, so they go
        self.log["history"] = [h for h in self.log["history"] if h["step"] <= state["step"]]
        self.log["resumed_at"].append(state["step"])
        return state

    def write_log(self) -> None:
        self.log_path.write_text(json.dumps(self.log, indent=1, default=float))


def _plain(x, depth: int = 0) -> bool:
    """Whether ``x`` is JSON-like plain data (what a run's config holds)."""
    if x is None or isinstance(x, (bool, int, float, str)):
        return True
    if depth < 4 and isinstance(x, (list, tuple)):
        return all(_plain(v, depth + 1) for v in x)
    if depth < 4 and isinstance(x, dict):
        return all(isinstance(k, str) and _plain(v, depth + 1) for k, v in x.items())
    return False


def check_state(state, path) -> dict:
    """A loaded checkpoint's fields as :meth:`Run.save` writes them (model: name -> tensor,
    optimizer: a state dict, step: a non-negative int, config: plain data with its frame lists,
    rng: a uint8 tensor); LfusdError naming the first field that is not."""
    def bad(what: str) -> LfusdError:
        return LfusdError(f"{path} is not a checkpoint these scripts write ({what}); delete it and run without --resume")

    if not isinstance(state, dict) or not {"model", "optimizer", "step", "config", "rng"} <= set(state):
        raise bad("it lacks model, optimizer, step, config or rng")
    model = state["model"]
    if not isinstance(model, dict) or not all(isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in model.items()):
        raise bad("'model' is not a dict of named tensors")
    if not isinstance(state["optimizer"], dict) or not {"state", "param_groups"} <= set(state["optimizer"]):
        raise bad("'optimizer' is not an optimiser state dict")
    step = state["step"]
    if isinstance(step, bool) or not isinstance(step, int) or step < 0:
        raise bad(f"'step' {str(step)[:40]!r} is not a non-negative integer")
    config = state["config"]
    if not isinstance(config, dict) or not _plain(config):
        raise bad("'config' is not plain data")
    for key in ("train_frames", "eval_frames"):
        frames = config.get(key)
        if key == "train_frames" and frames is None and config.get("recipe"):
            continue  # train_disparity.py on a recipe: every frame of each scene
        if not isinstance(frames, list) or not all(isinstance(f, int) and not isinstance(f, bool) for f in frames):
            raise bad(f"config '{key}' is not a list of frame numbers")
    rng = state["rng"]
    if not isinstance(rng, torch.Tensor) or rng.dtype != torch.uint8 or rng.dim() != 1:
        raise bad("'rng' is not a random generator state")
    return state


def load_weights(path, script: str) -> dict:
    """The checkpoint of ``flow/<script>.py`` at ``path`` (at least ``model``, a dict of named tensors,
    and ``config``, a dict), read with ``weights_only=True`` so that no pickled code runs; one-line
    LfusdError when it is missing, unreadable or lacks either."""
    import pickle

    path = Path(path)
    if not path.is_file():
        raise LfusdError(f"no weights at {path}; train with flow/{script}.py and pass --weights RUN/checkpoints/last.pt")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, EOFError, ValueError, TypeError, AttributeError, OSError) as e:
        why = (str(e).strip().splitlines() or [type(e).__name__])[0][:200]
        raise LfusdError(f"{path} is not a weights file of flow/{script}.py ({why}); pass its checkpoints/last.pt") from None
    model = state.get("model") if isinstance(state, dict) else None
    if not isinstance(model, dict) or not all(isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in model.items()) \
            or not isinstance(state.get("config"), dict):
        raise LfusdError(f"{path} lacks a 'model' of named tensors or its 'config'; pass a checkpoint of flow/{script}.py "
                         "(RUN/checkpoints/last.pt)")
    return state


def optimiser(model, lr: float, state: dict | None):
    """(Adam over ``model``'s parameters, the step to start from): a resumed run's checkpoint
    ``state`` restores the model, the optimiser and the step; without one, step 0."""
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    if not state:
        return opt, 0
    model.load_state_dict(state["model"])
    opt.load_state_dict(state["optimizer"])
    return opt, state["step"]


def progress(quiet: bool):
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("loss {task.fields[loss]:.4f}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        disable=quiet,
        transient=False,
    )


def train_loop(model, opt, batches, step_fn, run: Run, config: dict, start: int, a, description: str) -> None:
    """Optimise from step ``start`` + 1 to ``a.steps``: ``step_fn(batch) -> loss``; checkpoints every
    ``a.save_every`` steps and at the end; the mean loss of every ``a.log_every`` steps goes to the log."""
    model.train()
    acc, n_acc, t0 = 0.0, 0, time.time()
    step = start
    with progress(a.quiet) as bar:
        task = bar.add_task(description, total=a.steps, completed=start, loss=float("nan"))
        for batch in batches:
            if step >= a.steps:
                break
            loss = step_fn(batch)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            step += 1
            acc += float(loss.detach())
            n_acc += 1
            if n_acc == a.log_every or step == a.steps:
                run.log["history"].append({"step": step, "loss": acc / n_acc, "seconds": time.time() - t0})
                bar.update(task, loss=acc / n_acc)
                acc, n_acc = 0.0, 0
            bar.update(task, completed=step)
            if step % a.save_every == 0 or step == a.steps:
                run.save(model, opt, step, config)
    run.log["timing"]["train_s"] = time.time() - t0  # timing is this invocation's


def endless(loader):
    while True:
        yield from loader


# ---- the predict scripts' light field: an HCI-layout folder or an lfusd dataset ------------------


def predict_args(p: argparse.ArgumentParser, overlap: int) -> None:
    """The options of the predict scripts that take one light field (predict_views.py,
    predict_disparity.py): ``lf_dir`` with --frame and --rig for a dataset, the tiles (--tile, and
    --overlap defaulting to ``overlap``) and torch's --threads and --device; :func:`open_light_field`
    checks them."""
    p.add_argument("lf_dir", help="an HCI-layout folder (input_Cam000.png ...) or an lfusd dataset folder")
    p.add_argument("--frame", type=int, default=None, help="frame of an lfusd dataset (default: its first)")
    p.add_argument("--rig", default=None, help="rig of an lfusd dataset with several")
    p.add_argument("--tile", type=int, default=128, help="tile side in pixels (default 128)")
    p.add_argument("--overlap", type=int, default=overlap, help=f"context pixels around each tile (default {overlap})")
    p.add_argument("--threads", type=int, default=None, help="CPU threads of torch (default: torch's)")
    p.add_argument("--device", default="cpu", choices=["cpu", "cuda"], help="torch device")


def check_predict_args(a) -> Path:
    """The folder of :func:`predict_args`' ``lf_dir``, once --tile and --overlap are checked; one-line
    LfusdError when it is not a folder."""
    if a.tile < 8 or a.overlap < 0:
        raise LfusdError(f"--tile must be at least 8 and --overlap at least 0, got {a.tile} and {a.overlap}")
    folder = Path(a.lf_dir)
    if not folder.is_dir():
        raise LfusdError(f"{folder} is not a folder; give an HCI-layout folder (input_Cam000.png ...) or an lfusd dataset folder")
    return folder


def is_hci(folder: Path) -> bool:
    """Whether ``folder`` is read as an HCI-layout folder: it holds input_Cam000.png, or it is no lfusd
    dataset (then the HCI reader names what is missing)."""
    return (folder / "input_Cam000.png").is_file() or not (folder / layout.MANIFEST).is_file()


def dataset_frame(folder: Path, frame: int | None, rig: str | None, what: str):
    """(reader, frame) of an lfusd dataset whose one frame (``frame``, default the first) of one rig
    a predict script reads: a uniform planar parallel grid, as ``what`` needs."""
    from lfusd.data.dataset import open_dataset
    from lfusd.exports.common import check_planar_grid, frames_of

    from lfusd.data.folder import require_pinhole

    ds = open_dataset(folder, rig)
    require_pinhole(ds, f"{what} (it shifts views by disparity times their grid offsets)")
    check_planar_grid(ds, what)
    return ds, frames_of(ds, frame)[0]


def hci_files(folder: Path) -> tuple[int, list[Path]]:
    """(N, the N*N files input_Cam000.png ... row-major from the top-left view) of an HCI-layout folder;
    one-line LfusdError unless it holds exactly those, N at least 2."""
    files = sorted(Path(folder).glob("input_Cam*.png"))
    n = math.isqrt(len(files))
    if n < 2 or n * n != len(files) or [f.name for f in files] != [f"input_Cam{i:03d}.png" for i in range(n * n)]:
        raise LfusdError(f"{folder} holds {len(files)} input_CamNNN.png files; an HCI light field needs N*N of them "
                         "numbered from input_Cam000.png (e.g. 81 for 9x9)")
    return n, files


def read_view(path: Path) -> np.ndarray:
    """One view of an HCI-layout folder as stored: [H, W, 3] uint8 or uint16 (a grey PNG repeated
    into the three channels, alpha dropped)."""
    from lfusd.data import formats

    img = formats.read_png(path)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    return img[..., :3]


def read_hci(folder: Path) -> tuple[int, np.ndarray]:
    """(N, every view [N*N, H, W, 3] float32 in [0, 1], row-major) of an HCI-layout folder, each view
    scaled by its own bit depth; one-line LfusdError when the views differ in size."""
    n, files = hci_files(folder)
    views = [read_view(f) for f in files]
    if len({v.shape for v in views}) != 1:
        raise LfusdError(f"the views in {folder} differ in size; every input_CamNNN.png must have the same size")
    return n, np.stack([v.astype(np.float32) / float(np.iinfo(v.dtype).max) for v in views])


def tiles(h: int, w: int, tile: int, overlap: int):
    """The overlapping tiles a predict script runs its network on, covering an h x w image once: per
    tile (its part of the output, the input it sees: that part and up to ``overlap`` pixels of context
    on every side within the image, where the part stands in that input), each a (rows, cols) pair of
    slices; the parts are ``tile`` pixels square, smaller at the image's right and bottom edges."""
    step = max(tile, 1)
    for y0 in range(0, h, step):
        for x0 in range(0, w, step):
            y1, x1 = min(y0 + step, h), min(x0 + step, w)
            a0, b0 = max(y0 - overlap, 0), max(x0 - overlap, 0)
            a1, b1 = min(y1 + overlap, h), min(x1 + overlap, w)
            yield ((slice(y0, y1), slice(x0, x1)), (slice(a0, a1), slice(b0, b1)),
                   (slice(y0 - a0, y1 - a0), slice(x0 - b0, x1 - b0)))


# ---- scoring through lfusd eval ----------------------------------------------------------------


def pred_name(frame: int, view) -> str:
    """The name `lfusd eval --pred` reads (lfusd.evaluation.score.find_predictions)."""
    return f"{frame:04d}_{int(view[0]):02d}_{int(view[1]):02d}"


def score(ds, pred_dir: Path, task: str, pixels=None) -> dict:
    """`lfusd eval --task TASK --pred pred_dir` (native protocol): rows, each with the pixels it
    compared, and the summary row, also written as pred_dir/eval_<task>.json and .csv like the
    command does. ``pixels(frame, view)`` is a fallback count for rows that carry none."""
    from lfusd.evaluation.score import evaluate, write_results

    scores = evaluate(ds, pred_dir, task)
    rows = [dict(r) for r in scores]
    for r in rows:
        if "pixels" not in r and pixels is not None:
            r["pixels"] = int(pixels(r["frame"], (r["row"], r["col"])))
    write_results(scores, pred_dir / f"eval_{task}.json", pred_dir / f"eval_{task}.csv")
    mean = dict(scores.summary)
    mean["pixels"] = int(sum(r.get("pixels", 0) for r in rows))
    return {"rows": rows, "mean": mean}


def main_wrapper(name: str, main, argv=None) -> int:
    """One-line errors and exit 2 (lfusd's convention)."""
    logging.basicConfig(level=logging.INFO, format=f"{name}: %(message)s")
    try:
        return main(argv)
    except LfusdError as e:
        print(f"{name}: error: {e}", file=sys.stderr)
        return 2

