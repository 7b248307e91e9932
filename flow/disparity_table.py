"""The disparity results table of issue 36: a trained network and the plane sweep on a recipe's
held-out scenes, both read back from `lfusd export hci` folders and scored with the HCI protocol.

    python flow/disparity_table.py RECIPE_OUT --weights W [--split test] [--frames 1] --out runs/disp_table

For every scene of the split (``lfusd.recipe.split_scenes``) and every frame asked for, the scene is
exported with `lfusd export hci` (``--shift shift_px`` for a `things` scene, whose design gives
disparities of both signs, HCI's -4..+4 px; unshifted for other templates, whose disparities are
positive), the network predicts the centre view from the exported PNGs exactly as
``predict_disparity.py HCI_DIR`` does, and the plane sweep (lfusd.evaluation.baselines, over the
``disp_min..disp_max`` range the folder's parameters.cfg gives, as HCI gives it to every method)
runs on the same PNGs. Both are scored against the exported ``gt_disp_lowres.pfm`` by the HCI
toolkit's metrics (lfusd.evaluation.protocols, 15-px border). Pooled per template kind ("things,
signed": the held-out seeds of the training template; each held-out template by name) and over
all. Writes OUT/table.md, OUT/table.json and the predictions (OUT/pred/<scene>_f<frame>.pfm).
"""

from __future__ import annotations

import argparse
import configparser
import json
import logging
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import training  # noqa: E402
from lfusd import LfusdError  # noqa: E402

log = logging.getLogger("lfusd.flow")
NAME = "disparity_table"
METRICS = (("mse_x100", "MSE x100"), ("badpix_0.07_pct", "BadPix0.07 %"), ("badpix_0.03_pct", "BadPix0.03 %"), ("badpix_0.01_pct", "BadPix0.01 %"))


def template_of(scene: Path) -> str:
    """A recipe scene folder's template (lfusd.recipe.scene_template), else the folder's name."""
    from lfusd.recipe import scene_template

    return scene_template(scene) or scene.name


def score_folder(hci_dir: Path, pred: np.ndarray) -> dict:
    """HCI-protocol metrics of ``pred`` against the folder's gt_disp_lowres.pfm."""
    from lfusd.data import formats
    from lfusd.evaluation import protocols

    gt = formats.read_pfm(hci_dir / "gt_disp_lowres.pfm")
    row, _ = protocols.score("hci", "disparity", pred, {"disparity": gt})
    return row


def plane_sweep(views: np.ndarray, offsets: np.ndarray, centre_index: int, hci_dir: Path, planes: int, window: int) -> np.ndarray:
    """The plane-sweep baseline on an HCI folder's views over its parameters.cfg disparity range."""
    from lfusd.evaluation import baselines

    cfg = configparser.ConfigParser()
    cfg.read(hci_dir / "parameters.cfg")
    lo, hi = float(cfg.get("meta", "disp_min")), float(cfg.get("meta", "disp_max"))
    pad = 0.1 * max(hi - lo, 0.5)
    images = {i: views[i] for i in range(len(views))}
    offs = {i: tuple(map(float, offsets[i])) for i in range(len(views))}
    return baselines.plane_sweep_disparity(images, offs, offs[centre_index], (lo - pad, hi + pad), planes, window, device="cpu")


def pooled(rows: list[dict]) -> dict:
    """Pixel-weighted means of the rows' metrics (every row is one image of the same border)."""
    w = np.array([r["pixels"] for r in rows], np.float64)
    return {k: float(np.sum(w * np.array([r[k] for r in rows])) / w.sum()) for k, _ in METRICS} | {"pixels": int(w.sum()), "images": len(rows)}


def markdown(groups: dict, header: str) -> str:
    lines = [header, "", "| scenes | images | method | " + " | ".join(t for _, t in METRICS) + " |", "|---|---|---|" + "---|" * len(METRICS)]
    for name, methods in groups.items():
        for method, m in methods.items():
            lines.append(f"| {name} | {m['images']} | {method} | " + " | ".join(f"{m[k]:.2f}" for k, _ in METRICS) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__.split("\n\n", 1)[1])
    p.add_argument("data", help="a made recipe dataset (lfusd dataset make)")
    p.add_argument("--weights", default=None, help="the network's weights (default: the shipped ones, flow/weights/)")
    p.add_argument("--split", default="test", help="the split to score (default test)")
    p.add_argument("--frames", type=int, nargs="*", default=[1], help="frames of each scene (default 1)")
    p.add_argument("--out", required=True, help="folder for the HCI exports, predictions and the table")
    p.add_argument("--planes", type=int, default=64, help="planes of the plane sweep")
    p.add_argument("--window", type=int, default=9, help="cost window of the plane sweep")
    p.add_argument("--threads", type=int, default=None, help="CPU threads of torch")
    a = p.parse_args(argv)
    from lfusd import exports
    from lfusd.data import formats
    from lfusd.data.dataset import open_dataset
    from lfusd.recipe import split_scenes
    from predict_disparity import load_model, predict, read_hci_views
    from train_disparity import design_shift

    data, out = Path(a.data), Path(a.out)
    scenes = split_scenes(data).get(a.split, [])
    if not scenes:
        raise LfusdError(f"{data} has no complete, verified scene in split {a.split!r}; make it with 'lfusd dataset make' or pick --split")
    model, _, weights = load_model(a.weights, device=training.device_of("cpu", a.threads))
    (out / "pred").mkdir(parents=True, exist_ok=True)
    rows, t0 = [], time.time()
    for sc in scenes:
        shift, template = design_shift(sc), template_of(sc)
        group = f"{template}, signed" if shift else f"{template} (held out)" if template != "things" else template
        ds = open_dataset(sc)
        for t in a.frames:
            export = out / "hci" / f"{sc.name}_f{t:04d}"  # one export per scene and frame, kept for reruns
            if not export.is_dir():
                exports.export(ds, "hci", export, frame=t, shift=str(shift) if shift else None)
            (dest,) = [d for d in export.iterdir() if d.is_dir()]
            views, offsets, centre = read_hci_views(dest)
            ci = centre[0] * int(np.sqrt(len(views))) + centre[1]
            t1 = time.process_time()
            d_net = predict(model, views, offsets)
            net_s = time.process_time() - t1
            formats.write_pfm(out / "pred" / f"{sc.name}_f{t:04d}.pfm", d_net)
            d_ps = plane_sweep(views, offsets, ci, dest, a.planes, a.window)
            for method, d in (("network", d_net), ("plane sweep", d_ps)):
                rows.append({"scene": sc.name, "frame": t, "group": group, "method": method, "shift": shift, **score_folder(dest, d)})
            log.info("%s frame %d (%s): network BadPix0.07 %.2f %%, plane sweep %.2f %% (network %.1f CPU-s)", sc.name, t, group,
                     rows[-2]["badpix_0.07_pct"], rows[-1]["badpix_0.07_pct"], net_s)
    groups: dict = {}
    for g in sorted({r["group"] for r in rows}) + ["all"]:
        groups[g] = {m: pooled([r for r in rows if r["method"] == m and g in (r["group"], "all")]) for m in ("network", "plane sweep")}
    header = (f"Disparity on the {a.split} split of {data.name} (frames {', '.join(map(str, a.frames))}; HCI protocol, 15-px border; "
              f"weights {weights}):")
    (out / "table.md").write_text(markdown(groups, header))
    (out / "table.json").write_text(json.dumps({"rows": rows, "groups": groups, "weights": str(weights)}, indent=1))
    print(markdown(groups, header))
    log.info("scored %d images in %.0f s; table in %s", len(rows) // 2, time.time() - t0, out / "table.md")
    return 0


if __name__ == "__main__":
    sys.exit(training.main_wrapper(NAME, main))
