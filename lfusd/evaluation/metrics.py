"""Reference (NumPy) metrics for light-field disparity, optical flow, scene flow and view synthesis:
the definitions of lfusd's native protocol (``lfusd eval --protocol lfusd``).

Every rate is in percent and its key ends in ``_pct``; end-point errors carry their unit (``_px``,
``_m``). Pixels enter a metric only where the mask is true and the ground truth is finite; there is
no implicit border. This is NOT the HCI benchmark's convention: its toolkit scores every pixel but a
15-px border and never reads a mask; ``--protocol hci`` (:mod:`lfusd.evaluation.protocols`) does
that, and also the other benchmarks' masks, NaN policies, quantiles and pooling.

Definitions (the literature's; see the docstrings for the exact formulas):
- disparity (HCI 4D light-field benchmark, Honauer et al. 2016, over lfusd's mask): ``mse_x100``,
  ``badpix_<t>_pct`` (percent with |error| > t), ``q25_x100`` (100 x the 25th percentile of
  |error|, NumPy's linear interpolation; the HCI toolkit takes ``sorted[int(0.25 N)]`` instead).
  A non-finite prediction counts as an infinite error.
- optical flow: ``epe_px`` (mean end-point error), ``fl_all_pct`` (KITTI 2015: error > 3 px and
  > 5 % of the true magnitude), ``epe_gt_1px_pct`` (percent with error > 1 px; RAFT's Sintel "1px"
  is the opposite, the fraction with error < 1 px: ``--protocol sintel``).
- scene flow (3-D, metres): ``epe3d_m``, ``acc3d_strict_pct`` (error < 0.05 m or relative < 5 %),
  ``acc3d_relax_pct`` (< 0.1 m or < 10 %), ``outlier3d_pct`` (> 0.3 m or relative > 10 %),
  relative = error / (|gt| + 1e-4) (FlowNet3D / HPLFlowNet / FLOT).
- KITTI 2015 scene-flow outliers ``d1_pct``, ``d2_pct``, ``fl_pct``, ``sf_pct``: a pixel is an
  outlier when its error exceeds 3 px and 5 % of the true value; ``sf`` counts pixels that are an
  outlier in any.
- view synthesis: ``psnr_db`` and ``ssim`` on luma Y of MATLAB's ``rgb2ycbcr`` (BT.601, Y in
  [16/255, 235/255]) with peak 1. SSIM is Wang et al.'s reference ``ssim_index.m``: an 11x11
  Gaussian window of sigma 1.5 (normalised to sum 1), K1 = 0.01, K2 = 0.03, L = 1, population
  (not sample) statistics, averaged over the 'valid' windows only (no padding). The same value
  comes from ``skimage.metrics.structural_similarity(a, b, gaussian_weights=True, sigma=1.5,
  use_sample_covariance=False, data_range=1)`` (its reflect padding only touches the border it
  crops). BasicLFSR calls ``structural_similarity(a, b, gaussian_weights=True)`` on float Y:
  sample covariance (x 121/120) and, in scikit-image 0.19, data_range 2 (the float dtype's -1..1;
  newer releases raise); ``--protocol basiclfsr`` reproduces that value. DistgASR crops 22 px per
  side and passes ``sigma=1.5, use_sample_covariance=False`` (``--protocol distgasr``).
"""

from __future__ import annotations

import numpy as np

from ..errors import LfusdError

BADPIX_THRESHOLDS = (0.01, 0.03, 0.07)
SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1, SSIM_K2 = 0.01, 0.03
REL_EPS = 1e-4


def _check_shapes(what: str, pred: np.ndarray, gt: np.ndarray, trailing: int | None = None) -> None:
    if pred.shape != gt.shape:
        raise LfusdError(f"{what}: prediction has shape {pred.shape} but the ground truth has {gt.shape}; predict at the ground truth's resolution")
    if trailing is not None and (pred.ndim < 1 or pred.shape[-1] != trailing):
        raise LfusdError(f"{what}: expected arrays of shape (..., {trailing}), got {pred.shape}")


def _mask(what: str, gt: np.ndarray, mask, shape) -> np.ndarray:
    finite = np.isfinite(gt) if gt.ndim == len(shape) else np.all(np.isfinite(gt), axis=-1)
    if mask is None:
        return finite
    mask = np.asarray(mask)
    if mask.shape != tuple(shape):
        raise LfusdError(f"{what}: mask has shape {mask.shape} but the images are {tuple(shape)}; give one boolean per pixel")
    return finite & mask.astype(bool)


def _pct(x: np.ndarray) -> float:
    return float(100.0 * np.mean(x)) if x.size else float("nan")


def disparity(pred, gt, mask=None) -> dict[str, float]:
    """HCI disparity metrics of ``pred`` against ``gt`` (H,W) over ``mask``."""
    pred, gt = np.asarray(pred, np.float64), np.asarray(gt, np.float64)
    _check_shapes("disparity", pred, gt)
    m = _mask("disparity", gt, mask, gt.shape)
    err = np.abs(pred[m] - gt[m])
    err = np.where(np.isfinite(err), err, np.inf)  # a non-finite prediction is a bad pixel
    out = {"mse_x100": float(100.0 * np.mean(err**2)) if err.size else float("nan")}
    for t in BADPIX_THRESHOLDS:
        out[f"badpix_{t}_pct"] = _pct(err > t)
    out["q25_x100"] = float(100.0 * np.percentile(err, 25)) if err.size else float("nan")
    return out


def _epe(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    e = np.sqrt(np.sum((pred - gt) ** 2, axis=-1))
    return np.where(np.isfinite(e), e, np.inf)


def optical_flow(pred, gt, valid=None) -> dict[str, float]:
    """End-point error, KITTI Fl-all and the 1-px outlier rate of (H,W,2) flows over ``valid``."""
    pred, gt = np.asarray(pred, np.float64), np.asarray(gt, np.float64)
    _check_shapes("optical flow", pred, gt, 2)
    m = _mask("optical flow", gt, valid, gt.shape[:-1])
    e = _epe(pred[m], gt[m])
    mag = np.sqrt(np.sum(gt[m] ** 2, axis=-1))
    return {
        "epe_px": float(np.mean(e)) if e.size else float("nan"),
        "fl_all_pct": _pct((e > 3.0) & (e > 0.05 * mag)),
        "epe_gt_1px_pct": _pct(e > 1.0),
    }


def scene_flow(pred, gt, valid=None, kitti=None) -> dict[str, float]:
    """EPE3D, Acc3DS, Acc3DR and Outlier3D of (H,W,3) or (N,3) scene flows (metres) over ``valid``.

    With ``kitti=(d1_pred, d1_gt, d2_pred, d2_gt, flow_pred, flow_gt)`` (image-space disparities and
    flow of the same pixels) the KITTI ``d1_pct``, ``d2_pct``, ``fl_pct``, ``sf_pct`` outlier rates are added.
    """
    pred, gt = np.asarray(pred, np.float64), np.asarray(gt, np.float64)
    _check_shapes("scene flow", pred, gt, 3)
    m = _mask("scene flow", gt, valid, gt.shape[:-1])
    e = _epe(pred[m], gt[m])
    rel = e / (np.sqrt(np.sum(gt[m] ** 2, axis=-1)) + REL_EPS)
    return {
        "epe3d_m": float(np.mean(e)) if e.size else float("nan"),
        "acc3d_strict_pct": _pct((e < 0.05) | (rel < 0.05)),
        "acc3d_relax_pct": _pct((e < 0.1) | (rel < 0.1)),
        "outlier3d_pct": _pct((e > 0.3) | (rel > 0.1)),
    } | ({} if kitti is None else kitti_outliers(*kitti, valid))


def kitti_outliers(d1_pred, d1_gt, d2_pred, d2_gt, flow_pred, flow_gt, valid=None) -> dict[str, float]:
    """KITTI 2015 scene-flow outlier rates ``d1_pct``, ``d2_pct``, ``fl_pct``, ``sf_pct`` (percent, one image).

    ``d1``: disparity at t; ``d2``: disparity at t+1 of the point seen at t (d + disparity change);
    ``fl``: optical flow. Outlier: error > 3 px and > 5 % of the true value (|gt| for disparity, the
    flow magnitude for flow); ``sf``: outlier in any of the three. All over ``valid``.
    """
    arrs = [np.asarray(a, np.float64) for a in (d1_pred, d1_gt, d2_pred, d2_gt, flow_pred, flow_gt)]
    d1p, d1g, d2p, d2g, fp, fg = arrs
    _check_shapes("kitti d1", d1p, d1g)
    _check_shapes("kitti d2", d2p, d2g)
    _check_shapes("kitti fl", fp, fg, 2)
    if d1g.shape != fg.shape[:-1] or d2g.shape != d1g.shape:
        raise LfusdError(f"kitti scene flow: disparities {d1g.shape}, {d2g.shape} and flow {fg.shape} must cover the same pixels")
    m = _mask("kitti scene flow", d1g, valid, d1g.shape) & np.isfinite(d2g) & np.all(np.isfinite(fg), axis=-1)

    def out(p, g):
        e = np.abs(p - g)
        e = np.where(np.isfinite(e), e, np.inf)
        return (e > 3.0) & (e > 0.05 * np.abs(g))

    o1 = out(d1p[m], d1g[m])
    o2 = out(d2p[m], d2g[m])
    e = _epe(fp[m], fg[m])
    of = (e > 3.0) & (e > 0.05 * np.sqrt(np.sum(fg[m] ** 2, axis=-1)))
    return {"d1_pct": _pct(o1), "d2_pct": _pct(o2), "fl_pct": _pct(of), "sf_pct": _pct(o1 | o2 | of)}


def rgb_to_y(rgb) -> np.ndarray:
    """Luma Y of MATLAB's rgb2ycbcr for RGB in [0, 1] (BT.601 studio swing): Y in [16/255, 235/255]."""
    rgb = np.asarray(rgb, np.float64)
    return (16.0 + 65.481 * rgb[..., 0] + 128.553 * rgb[..., 1] + 24.966 * rgb[..., 2]) / 255.0


def gaussian_window(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> np.ndarray:
    """The normalised size x size Gaussian window of MATLAB's fspecial('gaussian', size, sigma)."""
    x = np.arange(size, dtype=np.float64) - (size - 1) / 2.0
    g = np.exp(-(x**2) / (2.0 * sigma**2))
    w = np.outer(g, g)
    return w / w.sum()


def _filter_valid(img: np.ndarray, w: np.ndarray) -> np.ndarray:
    """2-D correlation of (H,W) with window w, 'valid' region only."""
    k = w.shape[0]
    win = np.lib.stride_tricks.sliding_window_view(img, (k, k))
    return np.einsum("ijkl,kl->ij", win, w)


def ssim(a, b, data_range: float = 1.0, cov_norm: float = 1.0) -> float:
    """Mean SSIM of two (H,W) images (Wang et al.'s ssim_index.m; see the module docstring).

    ``cov_norm`` scales the (co)variances as scikit-image does: 1 is the population statistics of
    the reference; 121/120 is skimage's default ``use_sample_covariance=True``.
    """
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.shape != b.shape or a.ndim != 2:
        raise LfusdError(f"ssim: needs two images of one (H,W) shape, got {a.shape} and {b.shape}")
    if min(a.shape) < SSIM_WINDOW:
        raise LfusdError(f"ssim: images of {a.shape} are smaller than the {SSIM_WINDOW}x{SSIM_WINDOW} window; use larger images")
    w = gaussian_window()
    c1, c2 = (SSIM_K1 * data_range) ** 2, (SSIM_K2 * data_range) ** 2
    mu_a, mu_b = _filter_valid(a, w), _filter_valid(b, w)
    saa = cov_norm * (_filter_valid(a * a, w) - mu_a**2)
    sbb = cov_norm * (_filter_valid(b * b, w) - mu_b**2)
    sab = cov_norm * (_filter_valid(a * b, w) - mu_a * mu_b)
    s = ((2 * mu_a * mu_b + c1) * (2 * sab + c2)) / ((mu_a**2 + mu_b**2 + c1) * (saa + sbb + c2))
    return float(s.mean())


def psnr(a, b, data_range: float = 1.0) -> float:
    """10 log10(peak^2 / MSE); inf for identical images."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    mse = float(np.mean((a - b) ** 2))
    return float("inf") if mse == 0 else float(10.0 * np.log10(data_range**2 / mse))


def view_synthesis(pred, gt) -> dict[str, float]:
    """PSNR and SSIM on luma Y of (H,W,3) RGB images in [0, 1] (uint8 is scaled by 1/255)."""
    pred, gt = _unit_rgb(pred), _unit_rgb(gt)
    _check_shapes("view synthesis", pred, gt, 3)
    yp, yg = rgb_to_y(pred), rgb_to_y(gt)
    return {"psnr_db": psnr(yp, yg), "ssim": ssim(yp, yg)}


def _unit_rgb(x) -> np.ndarray:
    x = np.asarray(x)
    if x.dtype == np.uint8:
        return x.astype(np.float64) / 255.0
    return x.astype(np.float64)
