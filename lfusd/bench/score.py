"""The benchmark's submission format, its checks, the oracle and the scorer (``lfusd bench score``).

A submission is a folder SUB/<scene>/<frame:04d>_<row:02d>_<col:02d>.npz, one file for every view of
every scored frame (every frame of a test scene but its last) of every test scene, each an
``np.savez`` / ``np.savez_compressed`` archive of four float arrays, every value finite:

- ``flow`` (H,W,2): forward optical flow t -> t+1 in pixels, (du, dv);
- ``disparity`` (H,W): disparity at t in pixels per baseline step (lfusd's d = f_px * b / z);
- ``disparity_change`` (H,W): the disparity at t+1 of the point seen at t, minus its disparity at t;
- ``scene_flow`` (H,W,3): world-frame displacement t -> t+1 of the point seen at (u, v), metres.

Metrics (lfusd.evaluation.metrics, the definitions of ``lfusd eval --protocol lfusd``), pooled
over every pixel of every view and frame (per sequence and overall), in regions: ``all``;
``noc`` / ``occ`` (the point is visible / hidden or outside the image at t+1: ``occlusion_fwd``);
``moving`` / ``static`` (the true scene flow is longer / not longer than :data:`MOVING_M`);
``mixed`` (the pixel's footprint holds more than one surface or motion: the ``mixed`` key).
Disparity is scored where there is a surface (finite depth), everything else where the forward
motion ground truth is defined (``valid_fwd``), each within the region.

- disparity: ``mse_x100``, ``badpix_<t>_pct``;
- flow: ``epe_px``, ``fl_all_pct``, ``epe_gt_1px_pct``;
- disparity change: ``dchange_epe_px`` (mean absolute error);
- scene flow: ``epe3d_m``, ``acc3d_strict_pct``, ``acc3d_relax_pct``, ``outlier3d_pct``;
- KITTI: ``d1_pct``, ``d2_pct`` (disparity at t+1 = disparity + change), ``fl_pct``, ``sf_pct``.

Angular consistency (``angular_spread_m``): for every pixel p of the centre view at a scored frame
t with valid forward motion, and its true world point X (``position``), a view sees X where the
pixel q nearest to X's projection is inside the image, has valid forward motion, and its own true
point lies within one pixel footprint of X (|X_q - X| <= depth_q / f_px; this leaves out the
pixels of another surface, and grazing ones).
With s_v the predicted scene flow at q in each of the n >= 2 views that see X, the spread is
sqrt(sum_v |s_v - mean(s)|^2 / n); ``angular_spread_m`` is its mean over those points.
``angular_spread_gt_m`` is the same with the true scene flows, the floor a perfect prediction gets
(neighbouring pixels see neighbouring points); ``angular_points`` counts the points.
"""

from __future__ import annotations

import csv
import json
import logging
import zipfile
from pathlib import Path

import numpy as np

from .. import layout
from ..errors import LfusdError

log = logging.getLogger(__name__)

ARRAYS = {"flow": 2, "disparity": None, "disparity_change": None, "scene_flow": 3}
REGIONS = ("all", "noc", "occ", "moving", "static", "mixed")
MOVING_M = 1e-3  # m of true scene flow between frames: 4x the scene_flow key's verify limit, far above its storage step
GROUPS = {
    "disparity": ("mse_x100", "badpix_0.01_pct", "badpix_0.03_pct", "badpix_0.07_pct"),
    "flow": ("epe_px", "fl_all_pct", "epe_gt_1px_pct"),
    "dchange": ("dchange_epe_px",),
    "sceneflow": ("epe3d_m", "acc3d_strict_pct", "acc3d_relax_pct", "outlier3d_pct"),
    "kitti": ("d1_pct", "d2_pct", "fl_pct", "sf_pct"),
}
LEADERBOARD = (("EPE px", "epe_px"), ("Fl %", "fl_all_pct"), ("BadPix0.07 %", "badpix_0.07_pct"), ("D1 %", "d1_pct"),
               ("D2 %", "d2_pct"), ("dchange px", "dchange_epe_px"), ("EPE3D m", "epe3d_m"), ("Acc3DS %", "acc3d_strict_pct"),
               ("Acc3DR %", "acc3d_relax_pct"), ("Outlier3D %", "outlier3d_pct"), ("SF %", "sf_pct"))


def submission_path(sub: Path, scene: str, frame: int, view) -> Path:
    return Path(sub) / scene / f"{layout.bench_name(frame, tuple(view))}.npz"


def load_prediction(path: Path, height: int, width: int) -> dict[str, np.ndarray]:
    """The four arrays of one submission file, checked; one-line LfusdError naming the file otherwise."""
    if not path.is_file():
        raise LfusdError(f"{path}: missing; the submission needs one .npz for every view of every scored frame (see `lfusd bench oracle`)")
    try:
        with np.load(path, allow_pickle=False) as z:
            got = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:
        raise LfusdError(f"{path}: not an .npz archive ({e}); write it with numpy.savez") from None
    out = {}
    for k, c in ARRAYS.items():
        if k not in got:
            raise LfusdError(f"{path}: no array {k!r} (it holds {', '.join(sorted(got)) or 'none'}); save flow, disparity, disparity_change and scene_flow")
        a = got[k]
        want = (height, width) if c is None else (height, width, c)
        if a.shape != want:
            raise LfusdError(f"{path}: {k} has shape {a.shape}, expected {want}; predict at the images' resolution")
        if a.dtype.kind != "f":
            raise LfusdError(f"{path}: {k} is {a.dtype}, expected a float array")
        if not np.all(np.isfinite(a)):
            raise LfusdError(f"{path}: {k} holds NaN or infinity at {int((~np.isfinite(a)).sum())} values; predict a finite value at every pixel")
        out[k] = a
    return out


def _truth(ds, frame: int, view) -> dict[str, np.ndarray]:
    keys = ("depth", "disparity", "flow_fwd", "valid_fwd", "occlusion_fwd", "scene_flow", "disparity_change", "mixed", "position")
    return {k: np.asarray(ds.read(frame, view, k)) for k in keys}


def regions(t: dict) -> dict[str, np.ndarray]:
    """The boolean masks of :data:`REGIONS` for one view's ground truth ``t`` (before the per-metric validity)."""
    occ = t["occlusion_fwd"].astype(bool)
    with np.errstate(invalid="ignore"):
        moving = np.linalg.norm(np.nan_to_num(np.asarray(t["scene_flow"], np.float64)), axis=-1) > MOVING_M
    ones = np.ones(occ.shape, bool)
    return {"all": ones, "noc": ~occ, "occ": occ, "moving": moving, "static": ~moving, "mixed": t["mixed"].astype(bool)}


def view_tally(pred: dict, t: dict) -> dict[str, dict[str, list[float]]]:
    """{region: {metric: [value x pixels, pixels]}} of one view and frame, through lfusd.evaluation.metrics.

    Each region's pixels are selected first and handed to the metrics as 1-D lists (their masks are
    then the ground truth's finiteness, as over the image): 6 regions cost one pass each over their pixels."""
    from ..evaluation import metrics

    surface = np.isfinite(t["depth"])
    valid = t["valid_fwd"].astype(bool)
    d2_gt = t["disparity"] + t["disparity_change"]  # float32 sums, as lfusd eval's truth and a submission's disp2
    d2_pred = pred["disparity"] + pred["disparity_change"]
    out: dict[str, dict[str, list[float]]] = {}
    for name, r in regions(t).items():
        acc: dict[str, list[float]] = {}

        def add(values: dict, n: int) -> None:
            for k, v in values.items():
                acc[k] = [v * n if n else 0.0, n]

        m = surface & r
        g = t["disparity"][m]
        add(metrics.disparity(pred["disparity"][m], g), int(np.isfinite(g).sum()))
        m = valid & r
        gf, pf = t["flow_fwd"][m], pred["flow"][m]
        ff = np.all(np.isfinite(gf), -1)
        add(metrics.optical_flow(pf, gf), int(ff.sum()))
        gc = np.asarray(t["disparity_change"][m], np.float64)
        e = np.abs(np.asarray(pred["disparity_change"][m], np.float64) - gc)[np.isfinite(gc)]
        add({"dchange_epe_px": float(e.mean()) if e.size else 0.0}, int(e.size))
        gs = t["scene_flow"][m]
        add(metrics.scene_flow(pred["scene_flow"][m], gs), int(np.all(np.isfinite(gs), -1).sum()))
        gd, g2 = t["disparity"][m], d2_gt[m]
        add(metrics.kitti_outliers(pred["disparity"][m], gd, d2_pred[m], g2, pf, gf), int((np.isfinite(gd) & np.isfinite(g2) & ff).sum()))
        acc.pop("q25_x100", None)  # a quantile does not pool
        out[name] = acc
    return out


def _merge(into: dict, tally: dict) -> None:
    for region, metrics_ in tally.items():
        dst = into.setdefault(region, {})
        for k, (s, n) in metrics_.items():
            a = dst.setdefault(k, [0.0, 0])
            a[0] += s
            a[1] += n


def _finish(tally: dict) -> dict:
    """Pooled values (None where a region has no pixel) with the pixels behind disparity and behind motion."""
    return {region: {k: (s / n if n else None) for k, (s, n) in m.items()}
            | {"pixels_disparity": int(m["mse_x100"][1]), "pixels_motion": int(m["epe_px"][1])}
            for region, m in tally.items()}


# -- angular consistency ----------------------------------------------------------------------

def correspondences(ds, frame: int, truths: dict) -> tuple[np.ndarray, dict]:
    """The centre view's points X (N,3) and, per view, (seen (N,) bool, flat pixel index (N,)); see the module docstring."""
    centre = tuple(ds.rig.centre_view)
    tc = truths[centre]
    ok = tc["valid_fwd"].astype(bool) & np.all(np.isfinite(tc["position"]), -1)
    X = np.asarray(tc["position"], np.float64)[ok]
    K = np.asarray(ds.intrinsics(centre), np.float64)
    h, w = ok.shape
    out = {}
    for v, t in truths.items():
        c2w = ds.cam_to_world(frame, v)
        R, c = c2w[:3, :3], c2w[:3, 3]
        p = (X - c) @ R  # world -> camera (OpenCV): R^T (X - c)
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.rint(K[0, 0] * p[:, 0] / z + K[0, 2])
            vv = np.rint(K[1, 1] * p[:, 1] / z + K[1, 2])
        inside = (z > 0) & (u >= 0) & (u < w) & (vv >= 0) & (vv < h)
        idx = np.where(inside, vv * w + u, 0).astype(np.int64)
        valid = t["valid_fwd"].astype(bool).ravel()[idx]
        q = np.asarray(t["position"], np.float64).reshape(-1, 3)[idx]
        depth = np.asarray(t["depth"], np.float64).ravel()[idx]
        with np.errstate(invalid="ignore"):
            near = np.linalg.norm(q - X, axis=-1) <= depth / K[0, 0]
        out[v] = (inside & valid & near, idx)
    return X, out


def spread(flows: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """Per point, sqrt(sum over the views that see it of |s_v - mean|^2 / n): ``flows`` (V,N,3), ``seen`` (V,N)."""
    n = seen.sum(0)
    wgt = seen[..., None].astype(np.float64)
    mean = (wgt * flows).sum(0) / np.maximum(n, 1)[:, None]
    var = (wgt[..., 0] * np.sum((flows - mean) ** 2, -1)).sum(0) / np.maximum(n, 1)
    return np.sqrt(var)


def angular(ds, frame: int, truths: dict, preds: dict) -> tuple[float, float, int]:
    """(sum of predicted spreads, sum of true spreads, points) of one frame over the points seen by >= 2 views."""
    _, corr = correspondences(ds, frame, truths)
    views = list(corr)
    seen = np.stack([corr[v][0] for v in views])
    keep = seen.sum(0) >= 2
    if not keep.any():
        return 0.0, 0.0, 0
    seen = seen[:, keep]

    def gather(key_of):
        return np.stack([np.asarray(key_of(v), np.float64).reshape(-1, 3)[corr[v][1][keep]] for v in views])

    sp = spread(gather(lambda v: preds[v]["scene_flow"]), seen)
    sg = spread(np.nan_to_num(gather(lambda v: truths[v]["scene_flow"])), seen)
    return float(sp.sum()), float(sg.sum()), int(keep.sum())


# -- scoring ----------------------------------------------------------------------------------

def _test_scenes(root: Path, rec: dict):
    from ..data.dataset import Dataset
    from ..data.folder import require_pinhole

    for scene in rec["splits"]["test"]:
        ds = Dataset(Path(root) / layout.BENCH_GT / scene)
        require_pinhole(ds, "the bench's scoring (its angular consistency projects with K)", "score it on a bench made without a lens")
        yield scene, ds


def score_submission(sub, root, progress=None) -> dict:
    """Score submission folder ``sub`` against benchmark folder ``root``: {"overall", "sequences", ...}."""
    from .make import check_gt, read_record

    root, sub = Path(root), Path(sub)
    rec = read_record(root)
    if not sub.is_dir():
        raise LfusdError(f"submission {sub} is not a folder; give the folder holding <scene>/<frame>_<row>_<col>.npz")
    check_gt(root, rec)
    overall: dict = {}
    ang_all = [0.0, 0.0, 0]
    sequences = {}
    for scene, ds in _test_scenes(root, rec):
        seq: dict = {}
        ang = [0.0, 0.0, 0]
        h, w = ds.rig.height, ds.rig.width
        for f in ds.frames[:-1]:
            truths, preds = {}, {}
            for v in ds.views:
                v = tuple(v)
                pred = load_prediction(submission_path(sub, scene, f, v), h, w)
                truth = _truth(ds, f, v)
                tally = view_tally(pred, truth)
                _merge(seq, tally)
                _merge(overall, tally)
                # kept for the frame's angular consistency: only what it reads (a 9x9 rig at 1024x1024 holds 81 views)
                truths[v] = {k: truth[k] for k in ("valid_fwd", "position", "depth", "scene_flow")}
                preds[v] = {"scene_flow": pred["scene_flow"]}
            a = angular(ds, f, truths, preds)
            ang = [ang[0] + a[0], ang[1] + a[1], ang[2] + a[2]]
            if progress:
                progress(scene, f)
        ang_all = [ang_all[0] + ang[0], ang_all[1] + ang[1], ang_all[2] + ang[2]]
        sequences[scene] = _finish(seq) | {"angular": _angular_row(ang)}
    return {"benchmark": rec["name"], "definition": rec["definition"], "submission": str(sub),
            "overall": _finish(overall) | {"angular": _angular_row(ang_all)}, "sequences": sequences}


def _angular_row(a) -> dict:
    return {"angular_spread_m": a[0] / a[2] if a[2] else None, "angular_spread_gt_m": a[1] / a[2] if a[2] else None, "angular_points": a[2]}


def csv_rows(result: dict) -> list[dict]:
    """One row per (sequence or 'overall', region), every metric a column; angular on the region 'all' rows."""
    rows = []
    for scope, res in [*result["sequences"].items(), ("overall", result["overall"])]:
        for region in REGIONS:
            row = {"sequence": scope, "region": region} | res[region]
            if region == "all":
                row |= res["angular"]
            rows.append(row)
    return rows


def leaderboard_row(result: dict, method: str) -> str:
    """The Markdown leaderboard row of the overall 'all' region (header in :func:`leaderboard_header`)."""
    a = result["overall"]["all"]
    cells = [method] + [_fmt(a.get(k)) for _, k in LEADERBOARD] + [_fmt(result["overall"]["angular"]["angular_spread_m"])]
    return "| " + " | ".join(cells) + " |"


def leaderboard_header() -> str:
    names = ["method"] + [n for n, _ in LEADERBOARD] + ["angular spread m"]
    return "| " + " | ".join(names) + " |\n|" + "---|" * len(names)


def _fmt(v) -> str:
    return "-" if v is None else f"{v:.4g}"


def write_results(result: dict, out: Path, method: str) -> dict[str, Path]:
    """Write score.json, score.csv and leaderboard.md into ``out``; their paths."""
    from ..files import atomic_write

    out.mkdir(parents=True, exist_ok=True)
    paths = {"json": out / "score.json", "csv": out / "score.csv", "md": out / "leaderboard.md"}
    atomic_write(paths["json"], json.dumps(result | {"method": method}, indent=1) + "\n")
    rows = csv_rows(result)
    keys = list(dict.fromkeys(k for r in rows for k in r))

    def write_csv(tmp):
        with open(tmp, "w", newline="") as f:
            wr = csv.DictWriter(f, fieldnames=keys)
            wr.writeheader()
            wr.writerows(rows)

    atomic_write(paths["csv"], write_csv)
    atomic_write(paths["md"], leaderboard_header() + "\n" + leaderboard_row(result, method) + "\n")
    return paths


# -- the oracle -------------------------------------------------------------------------------

def write_oracle(root, sub) -> int:
    """Write the test ground truth as a submission into ``sub`` (non-finite values as 0); the files written."""
    from ..files import atomic_write
    from .make import check_gt, read_record

    root, sub = Path(root), Path(sub)
    rec = read_record(root)
    check_gt(root, rec)
    n = 0
    for scene, ds in _test_scenes(root, rec):
        (sub / scene).mkdir(parents=True, exist_ok=True)
        for f in ds.frames[:-1]:
            for v in ds.views:
                t = {k: ds.read(f, tuple(v), key) for k, key in (("flow", "flow_fwd"), ("disparity", "disparity"),
                                                                  ("disparity_change", "disparity_change"), ("scene_flow", "scene_flow"))}
                arrays = {k: np.nan_to_num(np.asarray(a, np.float32), nan=0.0, posinf=0.0, neginf=0.0) for k, a in t.items()}
                atomic_write(submission_path(sub, scene, f, v), lambda tmp, a=arrays: _savez(tmp, a), suffix=".npz")
                n += 1
    return n


def _savez(path, arrays: dict) -> None:
    with open(path, "wb") as f:
        np.savez_compressed(f, **arrays)
