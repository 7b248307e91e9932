"""Evaluation protocols of `lfusd eval --protocol`: each benchmark's masks, borders, NaN policy,
quantiles, pooling and metric names, as its official code computes them.

One function per protocol scores one image (``score(protocol, task, pred, truth)``) and returns its
row and its tally: the (numerator, denominator) of every metric the protocol pools over a set of
images. :func:`summarise` then makes the summary row: pooled metrics are total numerator over total
denominator (every pixel of every image weighs the same), the others the mean of the per-image
values. Every row carries ``pixels``, how many pixels it compared.

``lfusd`` (the default) -- lfusd's native protocol (:mod:`lfusd.evaluation.metrics`): disparity over
pixels with a surface, flow and scene flow over ``valid_fwd``, no border; a non-finite prediction
is an infinite error; Q25 interpolated; summary = mean of per-image values (NaN-aware).

``hci`` -- HCI 4D light-field benchmark, evaluation-toolkit ``toolkit/metrics/general_metrics.py``,
``toolkit/utils/misc.py``, ``toolkit/scenes/base_scene.py`` (github.com/lightfield-analysis/
evaluation-toolkit): every pixel but a 15-px border (``boundary_offset=15``; the toolkit never
reads valid_mask.png), so lfusd's disparity 0 where there is no surface is scored too.
``mse_x100``: mean of (gt - pred)^2 x 100 over the pixels where both are finite; ``badpix_<t>_pct``:
percent of all border-free pixels with |pred - gt| > t (a NaN prediction compares False: good);
``q25_x100``: ``sorted(100 |pred - gt|)[int(N * 25 / 100.)]`` over finite values (not
interpolated). Summary: mean over images (the benchmark ranks the mean of per-scene scores).

``kitti`` -- KITTI 2015 devkit ``evaluate_scene_flow.cpp`` with ``io_flow.h`` / ``io_disp.h``, and
RAFT's ``validate_kitti``. A non-finite prediction is the devkit's invalid pixel: filled by its
``interpolateBackground`` (each row's gaps take the smaller of the two valid neighbours, rows are
extended left and right, then the first / last valid rows up and down); ``density_pct`` is the
share of ground-truth pixels predicted. Outlier: error > 3 px and error / |gt| > 5 %.
``fl_all_occ_pct`` / ``fl_all_noc_pct`` (flow_occ: every pixel with ground truth; flow_noc: those
not occluded at t+1), ``d1_all_occ_pct``, ``d2_all_occ_pct``, ``sf_all_occ_pct`` (outlier in d1,
d2 or fl, over pixels valid in all three) and their ``_noc`` versions where noc ground truth
exists, and, as the devkit's ``bg`` / ``fg`` columns, each of them over the background
(``obj_map`` 0) and the foreground (``obj_map`` > 0: objects that move,
:func:`lfusd.exports.kitti.kitti_object_map`) as ``d1_bg_occ_pct``, ``d1_fg_occ_pct``, ...; all
pooled over the set as the devkit accumulates them; ``epe_occ_px`` is RAFT's
``kitti-epe``: per-image mean EPE over flow_occ, then the mean over images. Ground truth: a
dataset gives the masks ``lfusd export kitti`` writes, unrounded; a KITTI folder
(``--gt DEST/training``) gives the exported PNGs, rounded to 1/64 px (flow) and 1/256 px
(disparity), so the numbers are the official pipeline's. ``noc`` is the devkit readme's: ground truth
whose correspondences (right image at t; left and right images at t+1) fall inside the image,
the same masks in both modes (:func:`lfusd.exports.kitti.kitti_noc`).

``sintel`` -- RAFT ``validate_sintel``: EPE over every pixel with ground truth (Sintel has it
everywhere; lfusd where ``valid_fwd``), pooled over the set (``np.mean(np.concatenate(...))``);
``epe_lt_1px_frac`` / ``_3px_`` / ``_5px_``: fraction (0..1) of pixels with EPE < 1, 3, 5 px
(RAFT's "1px", "3px", "5px"); ``epe_matched_px`` / ``epe_unmatched_px``: the Sintel server's EPE
over pixels visible / not visible at t+1. A non-finite prediction makes EPE non-finite, as in RAFT.

``spring`` -- Spring benchmark (spring-benchmark.org; cv-stuttgart/springwebsite
``springeval/management/commands/evaluation.py``), pooled over all pixels of all images with
ground truth (disparity: pixels with a surface; lfusd's disparity 0 of the sky is NaN, no ground
truth, in ``lfusd export spring`` and here alike, :func:`lfusd.exports.spring.spring_disparity`): flow ``epe_px``, ``fl_pct`` (EPE > 3 and > 5 % of |gt|), ``epe_gt_1px_pct``;
disparity ``abs_px``, ``d1_pct``, ``epe_gt_1px_pct`` (differences taken in float32 as Spring
does); scene flow ``sf_pct`` (outlier in d1, d2 or fl) and ``sf_epe_gt_1px_pct``. Spring's ground
truth is 2x the image resolution and it takes the smallest error of the 4 sub-pixels; lfusd's is
one sample per pixel, so that minimum is the error itself. NaN predictions are refused for flow and
disparity (Spring refuses them) and set to 0 for scene flow (Spring's ``np.nan_to_num``).

``basiclfsr`` -- BasicLFSR ``cal_metrics``: Y of ``rgb2ycbcr``, not clipped (a float prediction
outside [0, 1] is scored as it is), PSNR with peak 1 (skimage's data_range for non-negative floats)
and ``ssim_range2``: skimage 0.19's ``structural_similarity(gt, pred, gaussian_weights=True)`` on
float images, i.e. data_range 2 and sample covariance (x 121/120); summary: mean over views.
BasicLFSR computes in float32 and stores per-view values in float32; lfusd computes in float64
(they differ by about 1e-6).

``distgasr`` -- DistgASR ``utils/utils.py`` ``cal_metrics_RE``: the same unclipped Y, cropped by
:data:`DISTGASR_BORDER` (22) px on each side (``bd = 22``), PSNR as skimage's
``peak_signal_noise_ratio`` (peak 1 for a non-negative ground truth, else 2) and ``ssim_range2``:
``structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False)``
(population covariance, data_range 2 of skimage 0.19's float images); summary: mean over the
views scored (DistgASR leaves its input views out by giving them no prediction here).

Spring stores its ground truth (``create_evalfiles.py``: ``.astype(np.float16)``) and the
submissions as float16: ``spring`` rounds both to float16 before taking differences as
``evaluation.py`` does (flow differences in float16, disparity differences in float32).
"""

from __future__ import annotations

import numpy as np

from ..errors import LfusdError
from . import metrics

PROTOCOLS = ("lfusd", "hci", "kitti", "sintel", "spring", "basiclfsr", "distgasr")
TASKS_OF = {
    "lfusd": ("disparity", "flow", "sceneflow", "views"),
    "hci": ("disparity",),
    "kitti": ("disparity", "flow", "sceneflow"),
    "sintel": ("flow",),
    "spring": ("disparity", "flow", "sceneflow"),
    "basiclfsr": ("views",),
    "distgasr": ("views",),
}
DISTGASR_BORDER = 22  # px cropped on each side (DistgASR cal_metrics_RE: bd = 22)
HCI_BORDER = 15  # px on each side (BaseScene boundary_offset)
HCI_BADPIX = (0.01, 0.03, 0.07)
KITTI_ABS, KITTI_REL = 3.0, 0.05  # devkit ABS_THRESH, REL_THRESH
SPRING_ABS, SPRING_REL = 3.0, 0.05

Tally = dict[str, tuple[float, float, float]]  # key -> (numerator, denominator, scale)


def check(protocol: str, task: str) -> None:
    if protocol not in PROTOCOLS:
        raise LfusdError(f"unknown protocol {protocol!r}; use one of {', '.join(PROTOCOLS)}")
    if task not in TASKS_OF[protocol]:
        raise LfusdError(f"the {protocol} protocol has no {task} task; use --task {' or '.join(TASKS_OF[protocol])}, or --protocol lfusd")


def score(protocol: str, task: str, pred, truth: dict) -> tuple[dict, Tally]:
    """Score one image: ``pred`` is an array (a dict ``{"sceneflow", "disp", "disp2", "flow"}`` for
    scene flow), ``truth`` the ground truth of :func:`lfusd.evaluation.score.dataset_truth` or of a
    KITTI folder. Returns (row metrics with ``pixels``, tally of the pooled metrics)."""
    check(protocol, task)
    return _SCORERS[protocol](task, pred, truth)


def summarise(rows: list[dict], tallies: list[Tally], protocol: str) -> tuple[dict, dict[str, str]]:
    """The summary row of scored rows and how each metric was aggregated ('pooled' or 'mean')."""
    keys = [k for k in rows[0] if k not in ("scene", "frame", "row", "col", "pixels")]
    out, how = {}, {}
    for k in keys:
        if k in tallies[0]:
            num = sum(t[k][0] for t in tallies)
            den = sum(t[k][1] for t in tallies)
            out[k] = float(tallies[0][k][2] * num / den) if den else float("nan")
            how[k] = "pooled"
        else:
            vals = np.array([r.get(k, np.nan) for r in rows], np.float64)
            if protocol == "lfusd":  # today's behaviour: images without a value are left out
                out[k] = float(np.nanmean(vals)) if np.any(~np.isnan(vals)) else float("nan")
            else:
                out[k] = float(np.mean(vals))
            how[k] = "mean"
    out["pixels"] = int(sum(r.get("pixels", 0) for r in rows))
    return out, how


def _f64(x) -> np.ndarray:
    return np.asarray(x, np.float64)


def _same_shape(what: str, pred: np.ndarray, gt: np.ndarray) -> None:
    if pred.shape != gt.shape:
        raise LfusdError(f"{what}: prediction has shape {pred.shape} but the ground truth has {gt.shape}; predict at the ground truth's resolution")


def _pooled(num, den, scale=1.0) -> tuple[float, float, float]:
    return float(num), float(den), float(scale)


def _ratio(t: tuple[float, float, float]) -> float:
    return float(t[2] * t[0] / t[1]) if t[1] else float("nan")


def _rows_from(tally: Tally, extra: dict | None = None) -> dict:
    return {k: _ratio(v) for k, v in tally.items()} | (extra or {})


# ---- lfusd (native) ----------------------------------------------------------------------------


def _lfusd(task, pred, truth):
    if task == "disparity":
        m = np.isfinite(truth["depth"])
        res = metrics.disparity(pred, truth["disparity"], m)
        n = int((m & np.isfinite(truth["disparity"])).sum())
    elif task == "flow":
        res = metrics.optical_flow(pred, truth["flow"], truth["valid"])
        n = int((truth["valid"] & np.all(np.isfinite(truth["flow"]), -1)).sum())
    elif task == "sceneflow":
        res = metrics.scene_flow(pred["sceneflow"], truth["scene_flow"], truth["valid"])
        n = int((truth["valid"] & np.all(np.isfinite(truth["scene_flow"]), -1)).sum())
        if pred.get("disp") is not None:
            res.update(metrics.kitti_outliers(pred["disp"], truth["disparity"], pred["disp2"], truth["disparity2"], pred["flow"], truth["flow"], truth["valid"]))
    else:
        p = np.asarray(pred)
        res = metrics.view_synthesis(p.astype(np.float64) / 255.0 if p.dtype == np.uint8 else p, truth["rgb"])
        n = int(np.prod(np.shape(truth["rgb"])[:2]))
    return res | {"pixels": n}, {}


# ---- HCI 4D light-field benchmark --------------------------------------------------------------


def hci_border_mask(shape) -> np.ndarray:
    """BaseScene.get_boundary_mask: True except ``HCI_BORDER`` px on each side."""
    h, w = shape
    if h <= 2 * HCI_BORDER or w <= 2 * HCI_BORDER:
        raise LfusdError(f"images of {w}x{h} px have no pixel inside the HCI toolkit's {HCI_BORDER}-px border; render at least {2 * HCI_BORDER + 1}x{2 * HCI_BORDER + 1} px or use --protocol lfusd")
    m = np.zeros((h, w), bool)
    m[HCI_BORDER : h - HCI_BORDER, HCI_BORDER : w - HCI_BORDER] = True
    return m


def _hci(task, pred, truth):
    gt = _f64(truth["disparity"])
    p = _f64(pred)
    _same_shape("disparity", p, gt)
    border = hci_border_mask(gt.shape)
    with np.errstate(invalid="ignore"):
        diff = p - gt
        m_mse = border & np.isfinite(p) & np.isfinite(gt)
        mse = float(np.average(np.square(gt - p)[m_mse]) * 100) if m_mse.any() else float("nan")
        out = {"mse_x100": mse}
        for t in HCI_BADPIX:
            bad = np.abs(diff) > t  # NaN compares False: a NaN prediction is a good pixel
            out[f"badpix_{t}_pct"] = 100 * int(bad[border].sum()) / float(border.sum())
        d100 = np.abs(p - gt) * 100
        m_q = border & np.isfinite(d100) & np.isfinite(p)
        srt = np.sort(d100[m_q])
        out["q25_x100"] = float(srt[int(np.size(srt) * 25 / 100.0)]) if srt.size else float("nan")
    return out | {"pixels": int(border.sum())}, {}


# ---- KITTI 2015 ---------------------------------------------------------------------------------


def kitti_interpolate_background(values, valid) -> np.ndarray:
    """The devkit's ``interpolateBackground`` (io_disp.h, io_flow.h) on (H,W) or (H,W,C) values.

    Invalid entries must already hold the devkit's invalid value (disparity -1, flow 0): rows
    with no valid pixel between valid ones keep it, as in the devkit.
    """
    v = np.array(values, np.float64, copy=True)
    ok = np.asarray(valid, bool)
    h, w = ok.shape
    filled = np.zeros(h, bool)
    for r in range(h):
        idx = np.flatnonzero(ok[r])
        if idx.size == 0:
            continue
        gaps = np.flatnonzero(np.diff(idx) > 1)
        for g in gaps:  # a gap bounded by valid pixels a < b takes min(value a, value b) per component
            a, b = idx[g], idx[g + 1]
            v[r, a + 1 : b] = np.minimum(v[r, a], v[r, b])
        v[r, : idx[0]] = v[r, idx[0]]
        v[r, idx[-1] + 1 :] = v[r, idx[-1]]
        filled[r] = True
    rows = np.flatnonzero(filled)
    if rows.size:  # columns: extend the first valid row up and the last one down
        v[: rows[0]] = v[rows[0]]
        v[rows[-1] + 1 :] = v[rows[-1]]
    return v


def _kitti_pred_disp(p):
    p = _f64(p)
    ok = np.isfinite(p)
    return kitti_interpolate_background(np.where(ok, p, -1.0), ok), ok


def _kitti_pred_flow(p):
    p = _f64(p)
    if p.ndim != 3 or p.shape[-1] != 2:
        raise LfusdError(f"KITTI flow: expected an (H,W,2) prediction, got {p.shape}")
    ok = np.all(np.isfinite(p), axis=-1)
    return kitti_interpolate_background(np.where(ok[..., None], p, 0.0), ok), ok


def _kitti_disp_err(gt, est):
    with np.errstate(invalid="ignore", divide="ignore"):
        e = np.abs(gt - est)
        return (e > KITTI_ABS) & (e / np.abs(gt) > KITTI_REL)


def _kitti_flow_err(gt, est):
    with np.errstate(invalid="ignore", divide="ignore"):
        dist = np.sqrt(np.sum((gt - est) ** 2, axis=-1))
        mag = np.sqrt(np.sum(gt**2, axis=-1))
        return dist, (dist > KITTI_ABS) & (dist / mag > KITTI_REL)


def kitti_masks(truth: dict) -> dict:
    """KITTI ground truth of one image: values and occ / noc validity, from a KITTI folder as read,
    from a dataset as ``lfusd export kitti`` writes them (unrounded)."""
    if truth.get("kitti"):
        return truth
    depth = truth.get("depth")
    surface = np.isfinite(depth) if depth is not None else None
    out = {"kitti": False}
    if "flow" in truth:
        f = _f64(truth["flow"])
        occ = np.asarray(truth["valid"], bool) & np.all(np.isfinite(f), -1) & (surface if surface is not None else True)
        out |= {"flow": f, "flow_occ": occ, "flow_noc": occ & ~np.asarray(truth["occluded"], bool)}
    if "disparity" in truth:
        from ..exports.kitti import kitti_noc

        d0 = _f64(truth["disparity"])
        with np.errstate(invalid="ignore"):
            out |= {"disp0": d0, "disp0_occ": np.isfinite(d0) & (d0 > 0) & (surface if surface is not None else True)}
            # noc as `lfusd export kitti` writes it (one definition, the devkit readme's)
            if "disparity2" in truth:
                d1 = _f64(truth["disparity2"])
                ok1 = np.isfinite(d1) & (d1 > 0)
                out |= {"disp1": d1, "disp1_occ": out["flow_occ"] & ok1}
                out["disp0_noc"], out["disp1_noc"] = kitti_noc(d0, d1, np.nan_to_num(out["flow"]), out["disp0_occ"], out["disp1_occ"])
            else:
                out["disp0_noc"] = kitti_noc(d0, d0, np.zeros(d0.shape + (2,)), out["disp0_occ"], out["disp0_occ"])[0]
    return out


def _kitti_outliers(tally: Tally, metric: str, area: str, err, mask, fg) -> None:
    """The devkit's bg / fg / all outlier rates of ``metric`` over ``mask`` (``fg``: obj_map > 0)."""
    if fg is not None:
        tally[f"{metric}_bg_{area}_pct"] = _pooled(err[mask & ~fg].sum(), (mask & ~fg).sum(), 100)
        tally[f"{metric}_fg_{area}_pct"] = _pooled(err[mask & fg].sum(), (mask & fg).sum(), 100)
    tally[f"{metric}_all_{area}_pct"] = _pooled(err[mask].sum(), mask.sum(), 100)


def _kitti(task, pred, truth):
    k = kitti_masks(truth)
    fg = np.asarray(truth["obj_map"]) > 0 if truth.get("obj_map") is not None else None
    tally: Tally = {}
    extra = {}
    if task == "flow":
        gt = k["flow"]
        est, orig = _kitti_pred_flow(pred)
        _same_shape("KITTI flow", est, gt)
        dist, err = _kitti_flow_err(np.where(k["flow_occ"][..., None], gt, 0.0), est)
        occ, noc = k["flow_occ"], k["flow_noc"]
        _kitti_outliers(tally, "fl", "occ", err, occ, fg)
        _kitti_outliers(tally, "fl", "noc", err, noc, fg)
        tally["density_pct"] = _pooled((orig & occ).sum(), occ.sum(), 100)
        extra["epe_occ_px"] = float(dist[occ].mean()) if occ.any() else float("nan")  # RAFT: per-image mean
        n = int(occ.sum())
    elif task == "disparity":
        gt = k["disp0"]
        est, orig = _kitti_pred_disp(pred)
        _same_shape("KITTI disparity", est, gt)
        err = _kitti_disp_err(gt, est)
        occ = k["disp0_occ"]
        _kitti_outliers(tally, "d1", "occ", err, occ, fg)
        if k.get("disp0_noc") is not None:
            _kitti_outliers(tally, "d1", "noc", err, k["disp0_noc"], fg)
        tally["density_pct"] = _pooled((orig & occ).sum(), occ.sum(), 100)
        n = int(occ.sum())
    else:
        if pred.get("disp") is None:
            raise LfusdError("the KITTI scene-flow protocol needs disparity at t, disparity at t+1 and flow: put <stem>_disp, <stem>_disp2 and <stem>_flow beside the scene flow (or disp_0/, disp_1/, flow/ for a KITTI folder)")
        e0, _ = _kitti_pred_disp(pred["disp"])
        e1, _ = _kitti_pred_disp(pred["disp2"])
        ef, _ = _kitti_pred_flow(pred["flow"])
        for what, a, b in (("disp_0", e0, k["disp0"]), ("disp_1", e1, k["disp1"]), ("flow", ef, k["flow"])):
            _same_shape(f"KITTI {what}", a, b)
        err0 = _kitti_disp_err(k["disp0"], e0)
        err1 = _kitti_disp_err(k["disp1"], e1)
        _, errf = _kitti_flow_err(np.where(k["flow_occ"][..., None], k["flow"], 0.0), ef)
        for area in ("occ", "noc"):
            m0, m1, mf = k[f"disp0_{area}"], k[f"disp1_{area}"], k[f"flow_{area}"]
            if m0 is not None:
                _kitti_outliers(tally, "d1", area, err0, m0, fg)
            _kitti_outliers(tally, "d2", area, err1, m1, fg)
            _kitti_outliers(tally, "fl", area, errf, mf, fg)
            if m0 is not None:
                _kitti_outliers(tally, "sf", area, err0 | err1 | errf, m0 & m1 & mf, fg)
        n = int((k["disp0_occ"] & k["disp1_occ"] & k["flow_occ"]).sum())
    return _rows_from(tally, extra) | {"pixels": n}, tally


# ---- MPI Sintel (RAFT validate_sintel) ----------------------------------------------------------


def _sintel(task, pred, truth):
    gt = _f64(truth["flow"])
    p = _f64(pred)
    _same_shape("optical flow", p, gt)
    valid = np.asarray(truth["valid"], bool) & np.all(np.isfinite(gt), -1)
    occluded = np.asarray(truth["occluded"], bool)
    epe = np.sqrt(np.sum((p - gt) ** 2, axis=-1))
    e = epe[valid]
    with np.errstate(invalid="ignore"):
        tally: Tally = {
            "epe_px": _pooled(e.sum(), e.size),
            "epe_lt_1px_frac": _pooled((e < 1).sum(), e.size),
            "epe_lt_3px_frac": _pooled((e < 3).sum(), e.size),
            "epe_lt_5px_frac": _pooled((e < 5).sum(), e.size),
            "epe_matched_px": _pooled(epe[valid & ~occluded].sum(), (valid & ~occluded).sum()),
            "epe_unmatched_px": _pooled(epe[valid & occluded].sum(), (valid & occluded).sum()),
        }
    return _rows_from(tally) | {"pixels": int(valid.sum())}, tally


# ---- Spring ---------------------------------------------------------------------------------------


def _spring_no_nan(what, p):
    if np.isnan(p).any():
        raise LfusdError(f"{what} prediction holds NaN; the Spring benchmark refuses NaN submissions: predict every pixel")


def _f16(x) -> np.ndarray:
    """As Spring stores ground truth and submissions: float16."""
    return np.asarray(x).astype(np.float16)


def _spring_disp_epe(gt16, p16):
    # evaluation.py: np.abs(gt.astype(np.float32) - submission.astype(np.float32)), then float64
    return np.abs(gt16.astype(np.float32) - p16.astype(np.float32)).astype(np.float64)


def _spring_flow_epe(gt16, p16):
    # evaluation.py: (gt_flow - submission) in float16, then float64 and the norm
    return np.linalg.norm((gt16 - p16).astype(np.float64), axis=-1)


def _spring_d_out(epe, gt16):
    # evaluation.py: epe > 0.05 * np.abs(gt) with gt float16, so the threshold is float16 too
    return (epe > SPRING_ABS) & (epe > (np.float16(SPRING_REL) * np.abs(gt16)).astype(np.float64))


def _spring_f_out(epe, gt16):
    return (epe > SPRING_ABS) & (epe > SPRING_REL * np.linalg.norm(gt16.astype(np.float64), axis=-1))


def _spring(task, pred, truth):
    from ..exports.spring import spring_disparity

    tally: Tally = {}
    with np.errstate(invalid="ignore", over="ignore"):
        if task == "flow":
            p = _f64(pred)
            _spring_no_nan("flow", p)
            gt = np.where(np.asarray(truth["valid"], bool)[..., None], _f64(truth["flow"]), np.nan)
            _same_shape("optical flow", p, gt)
            epe = _spring_flow_epe(_f16(gt), _f16(p))
            n = int((~np.isnan(epe)).sum())
            tally["epe_px"] = _pooled(np.nansum(epe), n)
            tally["fl_pct"] = _pooled(_spring_f_out(epe, _f16(gt)).sum(), n, 100)
            tally["epe_gt_1px_pct"] = _pooled((epe > 1).sum(), n, 100)
        elif task == "disparity":
            p = np.asarray(pred)
            _spring_no_nan("disparity", _f64(p))
            gt = spring_disparity(truth["disparity"])  # the sky has no ground truth, as in the export
            _same_shape("disparity", _f64(p), _f64(gt))
            epe = _spring_disp_epe(_f16(gt), _f16(p))
            n = int((~np.isnan(epe)).sum())
            tally["abs_px"] = _pooled(np.nansum(epe), n)
            tally["d1_pct"] = _pooled(_spring_d_out(epe, _f16(gt)).sum(), n, 100)
            tally["epe_gt_1px_pct"] = _pooled((epe > 1).sum(), n, 100)
        else:
            if pred.get("disp") is None:
                raise LfusdError("the Spring scene-flow protocol needs disparity at t, disparity at t+1 and flow: put <stem>_disp, <stem>_disp2 and <stem>_flow beside the scene flow")
            valid = np.asarray(truth["valid"], bool)
            # the submission is stored as float16, then np.nan_to_num'd (evaluate_submission_sceneflow)
            d1p, d2p, fp = (np.nan_to_num(_f16(pred[k])) for k in ("disp", "disp2", "flow"))
            d1 = spring_disparity(truth["disparity"])  # the sky has no ground truth, as in the export
            g1 = _f16(d1)
            g2 = _f16(np.where(valid & np.isfinite(d1), _f64(truth["disparity2"]), np.nan))
            gf = _f16(np.where(valid[..., None], _f64(truth["flow"]), np.nan))
            for what, a, b in (("disp", d1p, g1), ("disp2", d2p, g2), ("flow", fp, gf)):
                _same_shape(f"scene flow {what}", a, b)
            e1, e2 = _spring_disp_epe(g1, d1p), _spring_disp_epe(g2, d2p)
            ef = _spring_flow_epe(gf, fp)
            o1, o2, of = _spring_d_out(e1, g1), _spring_d_out(e2, g2), _spring_f_out(ef, gf)
            n = int((~np.isnan(e1 + e2 + ef)).sum())
            tally["sf_pct"] = _pooled((o1 | o2 | of).sum(), n, 100)
            tally["sf_epe_gt_1px_pct"] = _pooled(((e1 > 1) | (e2 > 1) | (ef > 1)).sum(), n, 100)
    return _rows_from(tally) | {"pixels": n}, tally


# ---- BasicLFSR / DistgASR -----------------------------------------------------------------------


def _unit_y(x) -> np.ndarray:
    """Luma Y of RGB (uint8 scaled by 1/255), not clipped: neither BasicLFSR nor DistgASR clips."""
    x = np.asarray(x)
    return metrics.rgb_to_y(x.astype(np.float64) / 255.0 if x.dtype == np.uint8 else _f64(x))


def _basiclfsr(task, pred, truth):
    yp, yg = _unit_y(pred), _unit_y(truth["rgb"])
    _same_shape("view synthesis", yp, yg)
    n = metrics.SSIM_WINDOW**2
    out = {"psnr_db": metrics.psnr(yg, yp), "ssim_range2": metrics.ssim(yg, yp, data_range=2.0, cov_norm=n / (n - 1.0))}
    return out | {"pixels": int(yp.size)}, {}


def _distgasr(task, pred, truth):
    yp, yg = _unit_y(pred), _unit_y(truth["rgb"])
    _same_shape("view synthesis", yp, yg)
    b = DISTGASR_BORDER
    h, w = yg.shape
    if h - 2 * b < metrics.SSIM_WINDOW or w - 2 * b < metrics.SSIM_WINDOW:
        raise LfusdError(f"images of {w}x{h} px leave less than an SSIM window inside DistgASR's {b}-px border; "
                         f"render at least {2 * b + metrics.SSIM_WINDOW}x{2 * b + metrics.SSIM_WINDOW} px or use --protocol basiclfsr")
    yp, yg = yp[b:-b, b:-b], yg[b:-b, b:-b]
    peak = 1.0 if yg.min() >= 0 else 2.0  # skimage: the float dtype's range, halved for a non-negative truth
    out = {"psnr_db": metrics.psnr(yg, yp, data_range=peak), "ssim_range2": metrics.ssim(yg, yp, data_range=2.0)}
    return out | {"pixels": int(yp.size)}, {}


_SCORERS = {"lfusd": _lfusd, "hci": _hci, "kitti": _kitti, "sintel": _sintel, "spring": _spring, "basiclfsr": _basiclfsr, "distgasr": _distgasr}
assert set(_SCORERS) == set(PROTOCOLS)
