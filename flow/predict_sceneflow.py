"""Light-field scene flow of the centre view with a trained SceneFlowNet (flow/train_sceneflow.py).

    python flow/predict_sceneflow.py DATASET -o OUT --weights RUN/checkpoints/last.pt [--frames 1-9]
    python flow/predict_sceneflow.py LF_T LF_T1 -o OUT --weights W
    python flow/predict_sceneflow.py --bench BENCH -o SUB --weights W           # a benchmark submission

DATASET is an lfusd dataset folder (lfusd render-video): for every frame t with t+1 (or those of
--frames) OUT gets what `lfusd eval --task sceneflow --pred OUT --gt DATASET` scores, named
<frame>_<row>_<col> after the centre view: ``.npy`` (H,W,3 world-frame scene flow in metres),
``_disp.pfm`` (disparity at t), ``_disp2.pfm`` (disparity at t+1 of the point seen at t),
``_flow.flo`` (optical flow), ``_dchange.pfm`` (disparity change) and ``_disp_next.pfm`` (disparity
at t+1 of its own pixels).

LF_T and LF_T1 are two folders in the HCI 4D benchmark layout (``input_Cam000.png`` ... of an
NxN grid, row-major, Cam000 top left, as `lfusd export hci` writes), frames t and t+1. OUT gets
``flow.flo``, ``disparity.pfm``, ``disparity_next.pfm``, ``disparity_change.pfm`` (HCI's PFM
orientation and lfusd's disparity, pixels per view step) for the view HCI takes as centre and, when
LF_T holds a ``parameters.cfg`` (focal length, sensor, baseline), ``scene_flow.npy``: metres in the
camera frame of t (x right, y down, z forward), assuming the rig did not move between the frames.

With --bench BENCH (a folder of `lfusd bench make`), it reads only BENCH/public/test (every test
scene's rgb/ and cameras.json) and writes SUB, a submission that `lfusd bench score SUB --bench
BENCH` scores: baseline (c) of the benchmark. The scorer needs every view, and the network predicts
its reference view, so it runs once per view with that view as its reference (the offsets of the
others taken from it, the flow on that view's two frames), and scene flow is composed through that
view's cameras at t and t+1. Weights trained with ``--references all`` saw every view as
reference; others saw the centre only, and the other views are outside their training
(SUB/submission.json says which, with the weights' sha256).

Weights (a checkpoint of train_sceneflow.py, or a file with its ``model`` and ``config``) are
loaded with ``torch.load(weights_only=True)``: a crafted file cannot run code.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

import training  # noqa: E402
import train_sceneflow as tsf  # noqa: E402
from lfusd import LfusdError  # noqa: E402
from lfusd.data.folder import require_pinhole  # noqa: E402

log = logging.getLogger("lfusd.flow")
NAME = "predict_sceneflow"
DEFAULT_WEIGHTS = Path(__file__).resolve().parent / "weights" / "sceneflow.pt"


def load_model(path) -> tuple[torch.nn.Module, dict]:
    """The SceneFlowNet of a weights file (``model`` state dict and ``config``), read with
    ``weights_only=True``; LfusdError when it is missing or not such a file."""
    state = training.load_weights(path, "train_sceneflow")
    config = state["config"]
    try:
        model = tsf.build(config)
        model.load_state_dict(state["model"])
    except (KeyError, RuntimeError, TypeError) as e:
        why = (str(e).strip().splitlines() or [type(e).__name__])[0][:200]
        raise LfusdError(f"{path} does not hold a SceneFlowNet of train_sceneflow.py ({why}); pass one of its checkpoints") from None
    model.eval()
    return model, config


def grid_offsets(n: int) -> np.ndarray:
    """(sx, sy) of the views of a uniform n x n grid, row-major, relative to its centre (lfusd's
    RigSpec.offsets: x right, y down, in view steps)."""
    k = np.arange(n) - (n - 1) / 2.0
    sy, sx = np.meshgrid(k, k, indexing="ij")
    return np.stack([sx.ravel(), sy.ravel()], 1)


def read_hci(folder) -> tuple[torch.Tensor, int]:
    """The views of an HCI-layout folder as [N*N, 3, H, W] float in [0, 1] and N."""
    folder = Path(folder)
    if not folder.is_dir():
        raise LfusdError(f"{folder} is not a folder; give an lfusd dataset or two HCI-layout folders (input_Cam000.png ...)")
    n, views = training.read_hci(folder)
    return torch.from_numpy(views).permute(0, 3, 1, 2).contiguous(), n


def hci_camera(folder, width: int, height: int) -> tuple[np.ndarray, float] | None:
    """K and baseline (metres) from the folder's parameters.cfg (HCI's f_px = focal / sensor *
    max(W, H); pixel centres at integers as lfusd), or None when it has none."""
    from lfusd.data import formats

    cfg = Path(folder) / "parameters.cfg"
    if not cfg.is_file():
        return None
    p = formats.read_hci_config(cfg)
    f = p["focal_length_mm"] / p["sensor_size_mm"] * max(width, height)
    K = np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
    return K, p["baseline_mm"] / 1000.0


def check_grid(config: dict, n: int, where) -> None:
    if config["ang"] != n:
        raise LfusdError(f"the weights are for {config['ang']}x{config['ang']} views and {where} has {n}x{n}; use weights trained on that grid")


def predict_hci(model, config: dict, lf0, lf1, out: Path) -> list[Path]:
    """Flow, disparities, disparity change (and scene flow with parameters.cfg) of two HCI folders."""
    from lfusd.data import formats

    v0, n = read_hci(lf0)
    v1, n1 = read_hci(lf1)
    if n1 != n or v0.shape != v1.shape:
        raise LfusdError(f"{lf0} and {lf1} differ ({n}x{n} views of {tuple(v0.shape[-2:])} and {n1}x{n1} of {tuple(v1.shape[-2:])}); give two frames of one light field")
    check_grid(config, n, lf0)
    ref = int(n * n / 2)  # the view the HCI toolkit takes as centre (lfusd.exports.hci.hci_centre_view)
    off = grid_offsets(n)
    rel = torch.from_numpy(off - off[ref]).to(torch.float32)
    res = tsf.predict(model, v0, v1, rel, ref)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, key in (("disparity", "disparity"), ("disparity_next", "disparity_next"), ("disparity_change", "disparity_change")):
        formats.write_pfm(out / f"{name}.pfm", res[key])
        written.append(out / f"{name}.pfm")
    formats.write_flo(out / "flow.flo", res["flow"])
    written.append(out / "flow.flo")
    cam = hci_camera(lf0, v0.shape[-1], v0.shape[-2])
    if cam is None:
        log.info("%s has no parameters.cfg: no focal length or baseline, so no scene_flow.npy", lf0)
    else:
        sf = tsf.scene_flow(res, cam[0], np.eye(4), np.eye(4), cam[1])
        np.save(out / "scene_flow.npy", sf)
        written.append(out / "scene_flow.npy")
    return written


def predict_dataset(model, config: dict, data, out: Path, frames=None, rig=None) -> list[Path]:
    """Every frame t with t+1 (or ``frames``) of an lfusd dataset, in `lfusd eval`'s layout."""
    from lfusd.data.dataset import open_dataset

    ds = open_dataset(data, rig)
    require_pinhole(ds, "the scene-flow network (it shifts views by disparity and composes scene flow with K)")
    if ds.rig.rows != ds.rig.cols:
        raise LfusdError(f"the network needs a square grid of views and {data} has {ds.rig.rows}x{ds.rig.cols}")
    check_grid(config, ds.rig.rows, data)
    all_frames = list(ds.frames)
    frames = frames or [t for t in all_frames if t + 1 in all_frames]
    bad = [t for t in frames if t not in all_frames or t + 1 not in all_frames]
    if bad or not frames:
        raise LfusdError(f"frames {bad or frames} have no next frame in {data} ({all_frames[0]}..{all_frames[-1]}); pick --frames t with t+1 in the dataset")
    centre = tuple(ds.rig.centre_view)
    views = [tuple(v) for v in ds.views]
    rel = torch.tensor(np.array([np.subtract(ds.rig.offsets(v), ds.rig.offsets(centre)) for v in views]), dtype=torch.float32)
    K = ds.intrinsics(centre)
    written = []
    for t in frames:
        v0, v1 = tsf.load_pair(ds, t, views)
        res = tsf.predict(model, v0, v1, rel, views.index(centre))
        sf = tsf.scene_flow(res, K, ds.cam_to_world(t, centre), ds.cam_to_world(t + 1, centre), ds.rig.baseline)
        written += tsf.write_prediction(out, training.pred_name(t, centre), res, sf)
        log.info("frame %d -> %d: written", t, t + 1)
    return written


def predict_bench(model, config: dict, bench, sub: Path, weights) -> int:
    """Baseline (c) of `lfusd bench`: a submission for every view of every scored frame of every public
    test scene of ``bench``, each view predicted as the network's reference; SUB/submission.json
    describes it. Every scene's grid is checked before anything is written. The files written."""
    import json

    from lfusd.bench.baseline import public_inputs, public_test_scenes, write_prediction
    from lfusd.files import sha256_of
    from lfusd.layout import view_key
    from models import StarDisparityNet

    if isinstance(model.disparity, StarDisparityNet):
        raise LfusdError(f"{weights} predicts disparity for the centre view only (its disparity half is train_disparity.py's star network), "
                         "and the benchmark scores every view; use weights trained without --disparity-weights")
    scenes = []
    for scene, scene_dir in public_test_scenes(bench):
        cams, rgb = public_inputs(scene_dir)
        views = sorted(tuple(v) for v in cams["views"])
        n = int(round(len(views) ** 0.5))
        if views != [(r, c) for r in range(n) for c in range(n)]:
            raise LfusdError(f"test scene {scene} has views {views[:3]}...; the network takes a square grid of views")
        check_grid(config, n, scene_dir)
        scenes.append((scene, cams, rgb, views))
    n_files = 0
    for scene, cams, rgb, views in scenes:
        off = np.array([cams["offsets"][view_key(v)] for v in views], np.float64)
        K = np.asarray(cams["intrinsics"], np.float64)
        frames = cams["frames"]

        def load(f):
            imgs = [np.asarray(rgb(f, v))[..., :3] for v in views]
            a = np.stack(imgs).astype(np.float32) / float(np.iinfo(imgs[0].dtype).max)
            return torch.from_numpy(a).permute(0, 3, 1, 2).contiguous()

        rels = [torch.from_numpy(off - off[i]).to(torch.float32) for i in range(len(views))]
        disparity = {}  # (frame, view index) -> the network's disparity: each frame's is needed twice, as t+1 and as t

        def disparity_of(frame, lf, i):  # called under torch.no_grad() below
            if (frame, i) not in disparity:
                disparity[frame, i] = model.disparity(lf[None], rels[i][None])
            return disparity[frame, i]

        for f in cams["scored_frames"]:
            nxt = frames[frames.index(f) + 1]
            v0, v1 = load(f), load(nxt)
            for key in [k for k in disparity if k[0] not in (f, nxt)]:
                del disparity[key]
            for i, v in enumerate(views):
                with torch.no_grad():
                    out = model.motion(v0[None, i], v1[None, i], disparity_of(f, v0, i), disparity_of(nxt, v1, i))
                res = tsf.as_arrays(out)
                c0 = np.asarray(cams["cam_to_world"][str(f)][view_key(v)], np.float64)
                c1 = np.asarray(cams["cam_to_world"][str(nxt)][view_key(v)], np.float64)
                sf = tsf.scene_flow(res, K, c0, c1, float(cams["baseline"]))
                write_prediction(sub, scene, f, v, {"flow": res["flow"], "disparity": res["disparity"],
                                                    "disparity_change": res["disparity_change"], "scene_flow": sf})
                n_files += 1
            log.info("%s: frame %d -> %d, %d views", scene, f, nxt, len(views))
    meta = {"method": "(c) learned scene flow (flow/train_sceneflow.py SceneFlowNet)", "weights": str(weights),
            "weights_sha256": sha256_of(weights), "views": "every view",
            "reference": "each view predicted with itself as the network's reference view; " + (
                "the network was trained with every view as reference (train_sceneflow.py --references all)" if config.get("references") == "all"
                else "the network was trained with the centre view as reference only, so the other views are outside its training"),
            "scene_flow": "composed from the predicted disparity, disparity change and flow through each view's cameras at t and t+1 "
                          "(lfusd.evaluation.baselines.scene_flow_from_change); zero where it has no value",
            "disparity_candidates_px": [config["d_min"], config["d_max"]]}
    sub.mkdir(parents=True, exist_ok=True)
    (sub / "submission.json").write_text(json.dumps(meta, indent=1) + "\n")
    return n_files


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__.split("\n\n", 1)[1])
    p.add_argument("inputs", nargs="*", help="an lfusd dataset folder, or two HCI-layout folders (frame t and t+1)")
    p.add_argument("--bench", default=None, metavar="BENCH", help="write a submission of `lfusd bench` (baseline c) for BENCH/public/test to OUT")
    p.add_argument("-o", "--out", required=True, help="output folder")
    p.add_argument("--weights", default=str(DEFAULT_WEIGHTS), help="a checkpoint of train_sceneflow.py (default: %(default)s)")
    p.add_argument("--frames", default=None, help="dataset frames t to predict (t -> t+1), e.g. 1-5 (default: every frame with a next one)")
    p.add_argument("--rig", default=None, help="rig name, for a dataset with several rigs")
    p.add_argument("--threads", type=int, default=None, help="CPU threads of torch")
    a = p.parse_args(argv)
    if a.threads:
        torch.set_num_threads(a.threads)
    if a.bench and a.inputs:
        raise LfusdError("give either --bench BENCH or input folders, not both")
    model, config = load_model(a.weights)
    out = Path(a.out)
    from lfusd import layout

    if a.bench:
        n = predict_bench(model, config, a.bench, out, a.weights)
        log.info("%s: %d files (baseline c: the learned scene-flow network); score it with lfusd bench score %s --bench %s", out, n, out, a.bench)
        return 0
    if len(a.inputs) == 1:
        if not (Path(a.inputs[0]) / layout.MANIFEST).is_file():
            raise LfusdError(f"{a.inputs[0]} is not an lfusd dataset ({layout.MANIFEST} missing); give a dataset folder or two HCI-layout folders (frame t and t+1)")
        written = predict_dataset(model, config, a.inputs[0], out, training.parse_frames(a.frames), a.rig)
    elif len(a.inputs) == 2:
        written = predict_hci(model, config, a.inputs[0], a.inputs[1], out)
    else:
        raise LfusdError(f"got {len(a.inputs)} inputs; give one lfusd dataset folder or two HCI-layout folders (frame t and t+1)")
    log.info("%d files in %s", len(written), out)
    return 0


if __name__ == "__main__":
    sys.exit(training.main_wrapper(NAME, main))
