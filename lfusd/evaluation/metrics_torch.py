"""Batched PyTorch versions of lfusd.evaluation.metrics (same keys and definitions), on the inputs' device.

Each function takes a batch (leading dimension B) and returns ``{key: tensor of shape (B,)}``;
computation is in float64 so that results agree with the NumPy reference to about 1e-12.
Inputs may be NumPy arrays or tensors; ``device=None`` keeps a tensor's device (CUDA when given
CUDA tensors). A batch item whose mask is empty gives NaN, like the reference.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from ..errors import LfusdError
from .metrics import BADPIX_THRESHOLDS, REL_EPS, SSIM_K1, SSIM_K2, SSIM_SIGMA, SSIM_WINDOW


def _t(x, device=None) -> torch.Tensor:
    t = x if isinstance(x, torch.Tensor) else torch.as_tensor(x)
    return t.to(device=device if device is not None else t.device, dtype=torch.float64)


def _check(what: str, pred: torch.Tensor, gt: torch.Tensor, trailing: int | None, ndim: int) -> None:
    if pred.shape != gt.shape:
        raise LfusdError(f"{what}: prediction has shape {tuple(pred.shape)} but the ground truth has {tuple(gt.shape)}; predict at the ground truth's resolution")
    if gt.ndim != ndim or (trailing is not None and gt.shape[-1] != trailing):
        raise LfusdError(f"{what}: expected a batch of {ndim} dimensions" + (f" ending in {trailing}" if trailing else "") + f", got {tuple(gt.shape)}")


def _mask(what: str, gt: torch.Tensor, mask, shape, vector: bool) -> torch.Tensor:
    finite = torch.isfinite(gt).all(dim=-1) if vector else torch.isfinite(gt)
    if mask is None:
        return finite
    m = mask if isinstance(mask, torch.Tensor) else torch.as_tensor(mask)
    if tuple(m.shape) != tuple(shape):
        raise LfusdError(f"{what}: mask has shape {tuple(m.shape)} but the images are {tuple(shape)}; give one boolean per pixel")
    return finite & m.to(device=gt.device, dtype=torch.bool)


def _masked_mean(x: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
    b = x.shape[0]
    x, m = x.reshape(b, -1), m.reshape(b, -1)
    n = m.sum(dim=1)
    s = torch.where(m, x, torch.zeros((), dtype=x.dtype, device=x.device)).sum(dim=1)
    return torch.where(n > 0, s / n.clamp(min=1), torch.full_like(s, float("nan")))


def _masked_pct(cond: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
    return 100.0 * _masked_mean(cond.to(torch.float64), m)


def _masked_quantile(x: torch.Tensor, m: torch.Tensor, q: float) -> torch.Tensor:
    """Per-item quantile with NumPy's default linear interpolation over the masked values."""
    b = x.shape[0]
    x, m = x.reshape(b, -1), m.reshape(b, -1)
    inf = torch.full((), float("inf"), dtype=x.dtype, device=x.device)
    srt, _ = torch.sort(torch.where(m, x, inf), dim=1)  # masked-out values sort last
    n = m.sum(dim=1)
    pos = q * (n - 1).clamp(min=0).to(torch.float64)
    lo = pos.floor().long()
    hi = torch.minimum(lo + 1, (n - 1).clamp(min=0))
    vlo = srt.gather(1, lo[:, None])[:, 0]
    vhi = srt.gather(1, hi[:, None])[:, 0]
    frac = pos - lo.to(torch.float64)
    # NumPy: lo + frac * (hi - lo), but an inf end (a non-finite error) stays inf
    val = torch.where(frac > 0, vlo + frac * (vhi - vlo), vlo)
    return torch.where(n > 0, val, torch.full_like(val, float("nan")))


def _finite_or_inf(e: torch.Tensor) -> torch.Tensor:
    return torch.where(torch.isfinite(e), e, torch.full_like(e, float("inf")))


def disparity(pred, gt, mask=None, device=None) -> dict[str, torch.Tensor]:
    """HCI disparity metrics of a batch (B,H,W); see lfusd.evaluation.metrics.disparity."""
    pred, gt = _t(pred, device), _t(gt, device)
    pred = pred.to(gt.device)
    _check("disparity", pred, gt, None, 3)
    m = _mask("disparity", gt, mask, gt.shape, vector=False)
    err = _finite_or_inf((pred - gt).abs())
    err = torch.where(m, err, torch.zeros_like(err))
    out = {"mse_x100": 100.0 * _masked_mean(err**2, m)}
    for t in BADPIX_THRESHOLDS:
        out[f"badpix_{t}_pct"] = _masked_pct(err > t, m)
    out["q25_x100"] = 100.0 * _masked_quantile(err, m, 0.25)
    return out


def _epe(pred: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    return _finite_or_inf(torch.sqrt(((pred - gt) ** 2).sum(dim=-1)))


def optical_flow(pred, gt, valid=None, device=None) -> dict[str, torch.Tensor]:
    """epe_px, fl_all_pct and epe_gt_1px_pct of a batch of flows (B,H,W,2); see lfusd.evaluation.metrics.optical_flow."""
    pred, gt = _t(pred, device), _t(gt, device)
    pred = pred.to(gt.device)
    _check("optical flow", pred, gt, 2, 4)
    m = _mask("optical flow", gt, valid, gt.shape[:-1], vector=True)
    e = torch.where(m, _epe(pred, gt), torch.zeros((), dtype=torch.float64, device=gt.device))
    mag = torch.sqrt((gt**2).sum(dim=-1))
    return {
        "epe_px": _masked_mean(e, m),
        "fl_all_pct": _masked_pct((e > 3.0) & (e > 0.05 * mag), m),
        "epe_gt_1px_pct": _masked_pct(e > 1.0, m),
    }


def scene_flow(pred, gt, valid=None, device=None, kitti=None) -> dict[str, torch.Tensor]:
    """EPE3D, Acc3DS/R and Outlier3D of a batch (B,...,3), plus KITTI d1/d2/fl/sf with ``kitti``
    (a 6-tuple of batches); see lfusd.evaluation.metrics.scene_flow."""
    pred, gt = _t(pred, device), _t(gt, device)
    pred = pred.to(gt.device)
    if gt.ndim not in (3, 4):
        raise LfusdError(f"scene flow: expected a batch (B,H,W,3) or (B,N,3), got {tuple(gt.shape)}")
    _check("scene flow", pred, gt, 3, gt.ndim)
    m = _mask("scene flow", gt, valid, gt.shape[:-1], vector=True)
    e = torch.where(m, _epe(pred, gt), torch.zeros((), dtype=torch.float64, device=gt.device))
    rel = e / (torch.sqrt((gt**2).sum(dim=-1)) + REL_EPS)
    return {
        "epe3d_m": _masked_mean(e, m),
        "acc3d_strict_pct": _masked_pct((e < 0.05) | (rel < 0.05), m),
        "acc3d_relax_pct": _masked_pct((e < 0.1) | (rel < 0.1), m),
        "outlier3d_pct": _masked_pct((e > 0.3) | (rel > 0.1), m),
    } | ({} if kitti is None else kitti_outliers(*kitti, valid, device=device))


def kitti_outliers(d1_pred, d1_gt, d2_pred, d2_gt, flow_pred, flow_gt, valid=None, device=None) -> dict[str, torch.Tensor]:
    """KITTI d1_pct, d2_pct, fl_pct, sf_pct of a batch; see lfusd.evaluation.metrics.kitti_outliers."""
    d1p, d1g, d2p, d2g, fp, fg = (_t(a, device) for a in (d1_pred, d1_gt, d2_pred, d2_gt, flow_pred, flow_gt))
    dev = d1g.device
    d1p, d2p, d2g, fp, fg = (a.to(dev) for a in (d1p, d2p, d2g, fp, fg))
    _check("kitti d1", d1p, d1g, None, 3)
    _check("kitti d2", d2p, d2g, None, 3)
    _check("kitti fl", fp, fg, 2, 4)
    if d1g.shape != fg.shape[:-1] or d2g.shape != d1g.shape:
        raise LfusdError(f"kitti scene flow: disparities {tuple(d1g.shape)}, {tuple(d2g.shape)} and flow {tuple(fg.shape)} must cover the same pixels")
    m = _mask("kitti scene flow", d1g, valid, d1g.shape, vector=False) & torch.isfinite(d2g) & torch.isfinite(fg).all(dim=-1)

    def out(p, g):
        e = _finite_or_inf((p - g).abs())
        return (e > 3.0) & (e > 0.05 * g.abs())

    o1, o2 = out(d1p, d1g), out(d2p, d2g)
    e = _epe(fp, fg)
    of = (e > 3.0) & (e > 0.05 * torch.sqrt((fg**2).sum(dim=-1)))
    return {"d1_pct": _masked_pct(o1, m), "d2_pct": _masked_pct(o2, m), "fl_pct": _masked_pct(of, m), "sf_pct": _masked_pct(o1 | o2 | of, m)}


def rgb_to_y(rgb: torch.Tensor) -> torch.Tensor:
    """MATLAB rgb2ycbcr luma of RGB in [0, 1] on the last axis."""
    return (16.0 + 65.481 * rgb[..., 0] + 128.553 * rgb[..., 1] + 24.966 * rgb[..., 2]) / 255.0


def _gauss(device) -> torch.Tensor:
    x = torch.arange(SSIM_WINDOW, dtype=torch.float64, device=device) - (SSIM_WINDOW - 1) / 2.0
    g = torch.exp(-(x**2) / (2.0 * SSIM_SIGMA**2))
    w = torch.outer(g, g)
    return (w / w.sum())[None, None]


def ssim(a, b, data_range: float = 1.0, device=None) -> torch.Tensor:
    """Mean SSIM per item of a batch of (B,H,W) images (valid windows; see lfusd.evaluation.metrics)."""
    a, b = _t(a, device), _t(b, device)
    b = b.to(a.device)
    if a.shape != b.shape or a.ndim != 3:
        raise LfusdError(f"ssim: needs two (B,H,W) batches of one shape, got {tuple(a.shape)} and {tuple(b.shape)}")
    if min(a.shape[1:]) < SSIM_WINDOW:
        raise LfusdError(f"ssim: images of {tuple(a.shape[1:])} are smaller than the {SSIM_WINDOW}x{SSIM_WINDOW} window; use larger images")
    w = _gauss(a.device)
    a, b = a[:, None], b[:, None]
    c1, c2 = (SSIM_K1 * data_range) ** 2, (SSIM_K2 * data_range) ** 2
    mu_a, mu_b = F.conv2d(a, w), F.conv2d(b, w)
    saa = F.conv2d(a * a, w) - mu_a**2
    sbb = F.conv2d(b * b, w) - mu_b**2
    sab = F.conv2d(a * b, w) - mu_a * mu_b
    s = ((2 * mu_a * mu_b + c1) * (2 * sab + c2)) / ((mu_a**2 + mu_b**2 + c1) * (saa + sbb + c2))
    return s.flatten(1).mean(dim=1)


def psnr(a, b, data_range: float = 1.0, device=None) -> torch.Tensor:
    """PSNR per item of a batch (B,...)."""
    a, b = _t(a, device), _t(b, device)
    b = b.to(a.device)
    mse = ((a - b) ** 2).flatten(1).mean(dim=1)
    return 10.0 * torch.log10(data_range**2 / mse)  # inf where identical


def view_synthesis(pred, gt, device=None) -> dict[str, torch.Tensor]:
    """PSNR and SSIM on luma Y of a batch of RGB images (B,H,W,3) in [0, 1] (uint8 scaled by 1/255)."""
    def unit(x):
        t = x if isinstance(x, torch.Tensor) else torch.as_tensor(x)
        scale = 255.0 if t.dtype == torch.uint8 else 1.0
        return _t(t, device) / scale

    pred, gt = unit(pred), unit(gt)
    pred = pred.to(gt.device)
    _check("view synthesis", pred, gt, 3, 4)
    yp, yg = rgb_to_y(pred), rgb_to_y(gt)
    return {"psnr_db": psnr(yp, yg), "ssim": ssim(yp, yg)}
