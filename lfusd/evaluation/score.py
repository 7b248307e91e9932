"""Score predictions against a dataset's ground truth (what `lfusd eval` runs).

Predictions are files in DIR named by frame and view, ``<frame:04d>_<row:02d>_<col:02d>.<ext>``
(e.g. ``0001_04_04.pfm``), the names `lfusd export` uses:

- disparity: ``.pfm``, ``.npy`` (H,W) or a KITTI 16-bit ``.png`` disparity in pixels per baseline step;
- flow: ``.flo`` (pixels flagged unknown, beyond 1e9, are missing predictions, like NaN in
  ``.npy``), ``.npy`` (H,W,2) or a KITTI 16-bit ``.png`` forward flow (t -> t+1);
- sceneflow: ``.npy`` (H,W,3) world-frame displacement in metres (t -> t+1); with
  ``<stem>_disp.{pfm,npy}`` (disparity at t), ``<stem>_disp2.{pfm,npy}`` (disparity at t+1 of the
  point seen at t) and ``<stem>_flow.{flo,npy}`` beside it the KITTI d1/d2/fl/sf outliers are added;
- views: ``.png`` (RGB uint8) or ``.npy`` (H,W,3) in [0, 1].

Masks, NaN policy, percentiles and pooling follow ``--protocol`` (lfusd.evaluation.protocols):
``lfusd`` (default, native) scores disparity over pixels with a surface (finite depth), flow and
scene flow over valid_fwd; ``hci``, ``kitti``, ``sintel``, ``spring``, ``basiclfsr`` and ``distgasr`` reproduce
those benchmarks' official code. The summary row pools or averages as each protocol does.

``--gt`` may also be a KITTI folder written by ``lfusd export kitti`` (DEST or DEST/training), with
``--protocol kitti``: predictions then follow the devkit's submission layout, PRED/disp_0/,
PRED/disp_1/, PRED/flow/ holding ``<index:06d>_10.{png,pfm,flo,npy}``, and the ground truth is the
exported PNGs: rounded to 1/64 px (flow) and 1/256 px (disparity), as the official pipeline sees it.
"""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import numpy as np

from ..errors import LfusdError

TASKS = ("disparity", "flow", "sceneflow", "views")
EXTS = {"disparity": (".pfm", ".npy", ".png"), "flow": (".flo", ".npy", ".png"), "sceneflow": (".npy",), "views": (".png", ".npy")}
NAME = re.compile(r"^(\d+)_(\d+)_(\d+)$")


def _load(path: Path, what: str) -> np.ndarray:
    from ..data import formats

    ext = path.suffix.lower()
    try:
        if ext == ".pfm":
            return formats.read_pfm(path)
        if ext == ".flo":
            return formats.read_flo(path, unknown_as_nan=True)  # a hole is a missing prediction, not a 1e10-px one
        if ext == ".npy":
            return np.load(path, allow_pickle=False)
        if ext == ".png":
            if what == "disparity":
                d, valid = formats.read_kitti_disparity(path)
                d[~valid] = np.nan
                return d
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


class Scores(list):
    """The rows of `lfusd eval` (a list of dicts, one per image) with the protocol's summary row
    (``summary``) and how each metric was summarised (``aggregation``: 'pooled' or 'mean')."""

    def __init__(self, rows, summary: dict, aggregation: dict, protocol: str, task: str):
        super().__init__(rows)
        self.summary, self.aggregation, self.protocol, self.task = summary, aggregation, protocol, task


def dataset_truth(ds, frame: int, view, task: str) -> dict:
    """Ground truth of one image for :func:`lfusd.evaluation.protocols.score`."""
    if task == "views":
        return {"rgb": ds.read(frame, view, "rgb")}
    t = {"depth": ds.read(frame, view, "depth"), "disparity": ds.read(frame, view, "disparity")}
    if task in ("flow", "sceneflow"):
        t |= {"flow": ds.read(frame, view, "flow_fwd"), "valid": np.asarray(ds.read(frame, view, "valid_fwd"), bool), "occluded": np.asarray(ds.read(frame, view, "occlusion_fwd"), bool)}
    if task == "sceneflow":
        t |= {"scene_flow": ds.read(frame, view, "scene_flow"), "disparity2": t["disparity"] + ds.read(frame, view, "disparity_change")}
    return t


def _object_map(ds, frame: int, view) -> np.ndarray | None:
    """KITTI's obj_map of (frame, frame + 1), or None for a dataset without motion keys (a still
    render has no moving objects to split off; its scores then have no bg / fg columns)."""
    from ..exports.kitti import kitti_object_map

    try:
        return kitti_object_map(ds, frame, view)
    except LfusdError:
        return None


def _evaluate_export(fmt, root: Path, pred: Path, task: str, protocol: str) -> Scores:
    """Score predictions in the benchmark's submission layout against an export that ``fmt`` reads
    back (its :class:`lfusd.exports.registry.Reader`): the ground truth as the official pipeline sees it."""
    from . import protocols

    reader = fmt.reader
    if protocol != reader.protocol:
        raise LfusdError(f"{root} is a {fmt.name} export; score it with --protocol {reader.protocol}")
    protocols.check(protocol, task)
    sub = pred / reader.predictions[task]
    rows, tallies = [], []
    for name in reader.names(root, task):
        stem = name[:-4]
        paths = {}
        for key, folder, what in (("main", reader.predictions[task], "disparity" if task == "disparity" else "flow"), ("disp", "disp_0", "disparity"), ("disp2", "disp_1", "disparity")):
            if key != "main" and task != "sceneflow":
                continue
            found = [q for q in (pred / folder / f"{stem}{e}" for e in EXTS[what]) if q.is_file()]
            paths[key] = (found[0], what) if found else None
        if paths["main"] is None:
            continue
        if task == "sceneflow" and None in paths.values():
            raise LfusdError(f"{stem}: the KITTI scene-flow evaluation needs disp_0/, disp_1/ and flow/ predictions of every image; {pred} lacks some")
        p = {k: _load(v[0], v[1]) for k, v in paths.items()}
        prediction = p["main"] if task != "sceneflow" else {"flow": p["main"], "disp": p["disp"], "disp2": p["disp2"]}
        try:
            res, tally = protocols.score(protocol, task, prediction, reader.truth(root, name, task))
        except LfusdError as e:
            raise LfusdError(f"{paths['main'][0].name}: {e}") from None
        rows.append({"scene": root.parent.name if root.name == "training" else root.name, "frame": int(stem.split("_")[0]), "row": "", "col": "", **res})
        tallies.append(tally)
    if not rows:
        raise LfusdError(f"no {task} predictions for the {fmt.name} folder {root}: expected {sub}/000000_10{EXTS['disparity' if task == 'disparity' else 'flow'][0]} (the devkit's submission layout)")
    summary, how = protocols.summarise(rows, tallies, protocol)
    return Scores(rows, {"scene": rows[0]["scene"], "frame": "summary", "row": "", "col": "", **summary}, how, protocol, task)


def evaluate(ds, pred_dir, task: str, rig: str | None = None, protocol: str = "lfusd") -> Scores:
    """Score every prediction file in ``pred_dir`` under ``protocol``; one row per (frame, view).

    ``ds`` is a dataset reader, a dataset folder (then ``rig`` picks the rig of a multi-rig one) or
    a KITTI folder (``--protocol kitti``). The result is a list of rows with ``.summary``.
    """
    from . import protocols
    from .. import exports
    from ..data import dataset
    from ..exports.common import scene_name

    if task not in TASKS:
        raise LfusdError(f"unknown task {task!r}; use one of {', '.join(TASKS)}")
    protocols.check(protocol, task)
    pred = Path(pred_dir)
    if not pred.is_dir():
        raise LfusdError(f"prediction folder {pred} does not exist; give the folder holding <frame>_<row>_<col> files")
    if isinstance(ds, (str, Path)):
        found = exports.find_export(ds)  # an export a format reads back (a KITTI folder)
        if found is not None:
            return _evaluate_export(*found, pred, task, protocol)
        ds = dataset.open_dataset(ds, rig)
    if protocol == "kitti":  # as `lfusd export kitti` refuses it
        from ..data.folder import require_pinhole

        require_pinhole(ds, "the kitti protocol (its noc masks match pixels along image rows, a rectified pinhole pair's)",
                        "score it with --protocol lfusd")
    files = find_predictions(pred, task)
    if not files:
        raise LfusdError(f"no {task} predictions in {pred}: expected files like 0001_04_04{EXTS[task][0]} (frame_row_col)")
    views = {tuple(v) for v in ds.views}
    rows, tallies = [], []
    for frame, view, path in files:
        if frame not in ds.frames:
            raise LfusdError(f"{path.name}: frame {frame} is not in the dataset ({ds.frames[0]}..{ds.frames[-1]})")
        if view not in views:
            raise LfusdError(f"{path.name}: view {view} is not in the dataset's {ds.rig.rows}x{ds.rig.cols} grid")
        if task in ("flow", "sceneflow") and frame + 1 not in ds.frames:
            raise LfusdError(f"{path.name}: frame {frame} is the last one and has no forward motion ground truth; predict frames before it")
        p = _load(path, task)
        if task == "sceneflow":
            d1 = _companion(path, "_disp", (".pfm", ".npy"))
            d2 = _companion(path, "_disp2", (".pfm", ".npy"))
            fl = _companion(path, "_flow", (".flo", ".npy"))
            both = d1 and d2 and fl
            p = {"sceneflow": p, "disp": _load(d1, "disparity") if both else None, "disp2": _load(d2, "disparity") if both else None, "flow": _load(fl, "flow") if both else None}
        truth = dataset_truth(ds, frame, view, task)
        if protocol == "kitti" and frame + 1 in ds.frames:  # the devkit's bg / fg split: the obj_map `lfusd export kitti` writes
            truth["obj_map"] = _object_map(ds, frame, view)
        try:
            res, tally = protocols.score(protocol, task, p, truth)
        except LfusdError as e:
            raise LfusdError(f"{path.name}: {e}") from None
        rows.append({"scene": scene_name(ds), "frame": frame, "row": view[0], "col": view[1], **res})
        tallies.append(tally)
    summary, how = protocols.summarise(rows, tallies, protocol)
    return Scores(rows, {"scene": rows[0]["scene"], "frame": "summary", "row": "", "col": "", **summary}, how, protocol, task)


def aggregation_note(scores: Scores) -> str:
    """One line saying how the summary row was made."""
    pooled = [k for k, v in scores.aggregation.items() if v == "pooled"]
    mean = [k for k, v in scores.aggregation.items() if v == "mean"]
    parts = []
    if pooled:
        parts.append("pooled over every pixel of every image: " + ", ".join(pooled))
    if mean:
        parts.append("mean of per-image values: " + ", ".join(mean))
    return f"summary ({scores.protocol} protocol): " + "; ".join(parts) + f"; pixels = {scores.summary['pixels']} compared"


def write_results(scores: Scores, json_path, csv_path) -> None:
    """Write the rows and the summary as JSON ({task, protocol, rows, summary, aggregation}) and CSV (summary last)."""
    doc = {"task": scores.task, "protocol": scores.protocol, "rows": list(scores), "summary": scores.summary, "aggregation": scores.aggregation}
    Path(json_path).write_text(json.dumps(doc, indent=1, default=float))
    keys = list(dict.fromkeys(k for r in list(scores) + [scores.summary] for k in r))
    with open(csv_path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in list(scores) + [scores.summary]:
            w.writerow(r)
