"""Score predictions against a dataset's ground truth (what `lfusd eval` runs).

Predictions are files in DIR named by frame and view, ``<frame:04d>_<row:02d>_<col:02d>.<ext>``
(e.g. ``0001_04_04.pfm``), the names `lfusd export` uses:

- disparity: ``.pfm`` or ``.npy`` (H,W) disparity in pixels per baseline step;
- flow: ``.flo``, ``.npy`` (H,W,2) or a KITTI 16-bit ``.png`` forward flow (t -> t+1);
- sceneflow: ``.npy`` (H,W,3) world-frame displacement in metres (t -> t+1); with
  ``<stem>_disp.{pfm,npy}`` (disparity at t), ``<stem>_disp2.{pfm,npy}`` (disparity at t+1 of the
  point seen at t) and ``<stem>_flow.{flo,npy}`` beside it the KITTI d1/d2/fl/sf outliers are added;
- views: ``.png`` (RGB uint8) or ``.npy`` (H,W,3) in [0, 1].

Masks: disparity over pixels with a surface (finite depth); flow and scene flow over valid_fwd.
"""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import numpy as np

from ..errors import LfusdError

TASKS = ("disparity", "flow", "sceneflow", "views")
EXTS = {"disparity": (".pfm", ".npy"), "flow": (".flo", ".npy", ".png"), "sceneflow": (".npy",), "views": (".png", ".npy")}
NAME = re.compile(r"^(\d+)_(\d+)_(\d+)$")


def _load(path: Path, what: str) -> np.ndarray:
    from ..data import formats

    ext = path.suffix.lower()
    try:
        if ext == ".pfm":
            return formats.read_pfm(path)
        if ext == ".flo":
            return formats.read_flo(path)
        if ext == ".npy":
            return np.load(path, allow_pickle=False)
        if ext == ".png":
            if what == "flow":
                f, valid = formats.read_kitti_flow(path)
                f[~valid] = np.nan
                return f
            return formats.read_png(path)
    except ValueError as e:
        raise LfusdError(f"{path} could not be read ({e}); write it with numpy.save or the format's writer") from None
    raise LfusdError(f"{path}: unsupported file type {ext}")


def find_predictions(pred: Path, task: str) -> list[tuple[int, tuple[int, int], Path]]:
    found = {}
    for p in sorted(pred.iterdir()):
        m = NAME.match(p.stem)
        if m and p.suffix.lower() in EXTS[task] and p.is_file():
            key = (int(m.group(1)), (int(m.group(2)), int(m.group(3))))
            if key in found:
                raise LfusdError(f"two predictions for frame {key[0]} view {key[1]}: {found[key].name} and {p.name}; keep one")
            found[key] = p
    return [(f, v, p) for (f, v), p in sorted(found.items())]


def _companion(path: Path, suffix: str, exts) -> Path | None:
    for e in exts:
        q = path.with_name(f"{path.stem}{suffix}{e}")
        if q.is_file():
            return q
    return None


def evaluate(ds, pred_dir, task: str, rig: str | None = None) -> list[dict]:
    """Score every prediction file in ``pred_dir``; one row per (frame, view) with its metrics.

    ``ds`` is a dataset reader or a dataset folder (then ``rig`` picks the rig of a multi-rig one).
    """
    from . import metrics
    from ..data import export

    if isinstance(ds, (str, Path)):
        ds = export.open_dataset(ds, rig)
    if task not in TASKS:
        raise LfusdError(f"unknown task {task!r}; use one of {', '.join(TASKS)}")
    pred = Path(pred_dir)
    if not pred.is_dir():
        raise LfusdError(f"prediction folder {pred} does not exist; give the folder holding <frame>_<row>_<col> files")
    files = find_predictions(pred, task)
    if not files:
        raise LfusdError(f"no {task} predictions in {pred}: expected files like 0001_04_04{EXTS[task][0]} (frame_row_col)")
    views = {tuple(v) for v in ds.views}
    rows = []
    for frame, view, path in files:
        if frame not in ds.frames:
            raise LfusdError(f"{path.name}: frame {frame} is not in the dataset ({ds.frames[0]}..{ds.frames[-1]})")
        if view not in views:
            raise LfusdError(f"{path.name}: view {view} is not in the dataset's {ds.rig.rows}x{ds.rig.cols} grid")
        if task in ("flow", "sceneflow") and frame + 1 not in ds.frames:
            raise LfusdError(f"{path.name}: frame {frame} is the last one and has no forward motion ground truth; predict frames before it")
        p = _load(path, task)
        try:
            if task == "disparity":
                depth = ds.read(frame, view, "depth")
                res = metrics.disparity(p, ds.read(frame, view, "disparity"), np.isfinite(depth))
            elif task == "flow":
                res = metrics.optical_flow(p, ds.read(frame, view, "flow_fwd"), ds.read(frame, view, "valid_fwd"))
            elif task == "sceneflow":
                valid = np.asarray(ds.read(frame, view, "valid_fwd"), bool)
                res = metrics.scene_flow(p, ds.read(frame, view, "scene_flow"), valid)
                d1 = _companion(path, "_disp", (".pfm", ".npy"))
                d2 = _companion(path, "_disp2", (".pfm", ".npy"))
                fl = _companion(path, "_flow", (".flo", ".npy"))
                if d1 and d2 and fl:
                    dg = ds.read(frame, view, "disparity")
                    res.update(metrics.kitti_outliers(_load(d1, "disparity"), dg, _load(d2, "disparity"), dg + ds.read(frame, view, "disparity_change"), _load(fl, "flow"), ds.read(frame, view, "flow_fwd"), valid))
            else:
                p = np.asarray(p)
                res = metrics.view_synthesis(p.astype(np.float64) / 255.0 if p.dtype == np.uint8 else p, ds.read(frame, view, "rgb"))
        except LfusdError as e:
            raise LfusdError(f"{path.name}: {e}") from None
        rows.append({"scene": export.scene_name(ds), "frame": frame, "row": view[0], "col": view[1], **res})
    return rows


def mean_row(rows: list[dict]) -> dict:
    """The mean of every metric over ``rows`` (NaN-aware), as a row with frame 'mean'."""
    keys = [k for k in rows[0] if k not in ("scene", "frame", "row", "col")]
    return {"scene": rows[0]["scene"], "frame": "mean", "row": "", "col": "", **{k: float(np.nanmean([r.get(k, np.nan) for r in rows])) for k in keys}}


def write_results(rows: list[dict], task: str, json_path, csv_path) -> None:
    """Write ``rows`` and their mean as JSON ({task, rows, mean}) and CSV (mean last)."""
    mean = mean_row(rows)
    Path(json_path).write_text(json.dumps({"task": task, "rows": rows, "mean": mean}, indent=1, default=float))
    keys = list(dict.fromkeys(k for r in rows for k in r))
    with open(csv_path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in rows + [mean]:
            w.writerow(r)
