"""Classical baselines that give a new dataset a first results table without training.

- :func:`plane_sweep` / :func:`plane_sweep_disparity`: light-field disparity by sweeping fronto-
  parallel planes (a compiled kernel on the CPU, PyTorch on a GPU when present). For each
  candidate disparity d every view is warped
  to the reference position with the light-field relation of CONVENTIONS.md (a point at
  disparity d seen at (u, v) from offset s0 appears at u - d*(sx - sx0), v - d*(sy - sy0) in a
  view at offset s), the colour variance across views is box-filtered, the best d is taken per
  pixel and refined with a parabola through its neighbours' costs.
- :func:`dis_flow`: optical flow with OpenCV's DIS (Kroeger et al. 2016).
- :func:`scene_flow_from`: 3-D scene flow from disparity at t, disparity at t+1 and optical flow;
  :func:`scene_flow_from_change` the same from disparity at t, disparity change and optical flow.
- :func:`interpolate_views`: view synthesis (e.g. 2x2 -> 7x7) by a plane sweep at each virtual
  view over the input views, and :func:`blend_views`, angular bilinear blending.
- :func:`run_baselines`: all of them on a dataset with the lfusd.evaluation.metrics results.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from . import metrics
from ..errors import LfusdError


def default_device() -> torch.device:
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def _img_tensor(img, device) -> torch.Tensor:
    a = np.asarray(img)
    t = torch.from_numpy(np.array(a)).to(device=device, dtype=torch.float32)  # a copy: readers may hand out read-only arrays
    if a.dtype == np.uint8:
        t = t / 255.0
    if t.ndim == 2:
        t = t[..., None]
    return t.permute(2, 0, 1)


def _img_array(img) -> np.ndarray:
    """(H,W,C) float32 in [0, 1]: the values :func:`_img_tensor` gives (uint8 / 255 rounded to float32), without torch."""
    a = np.asarray(img)
    f = a.astype(np.float32) / np.float32(255) if a.dtype == np.uint8 else a.astype(np.float32)
    return f[..., None] if f.ndim == 2 else f


def check_window(window: int) -> None:
    """Refuse a cost window the sweep cannot centre on a pixel (even) or that holds no pixel."""
    if window < 1 or window % 2 == 0:
        raise LfusdError(f"a plane sweep's window must be an odd number of pixels, got {window}; use {max(window - 1, 1)} or {max(window + 1, 1)}")


def plane_sweep(images: dict, offsets: dict, ref_offset=(0.0, 0.0), d_range=(-4.0, 4.0), n_planes: int = 64, window: int = 5, device=None, chunk: int = 8):
    """Sweep planes of constant disparity from a reference position through a set of views.

    ``images``: {view: (H,W,3) uint8 or float}; ``offsets``: {view: (sx, sy)} in baselines;
    ``ref_offset``: the reference (possibly virtual) view's offset. Returns (disparity (H,W)
    float32, cost (H,W) float32: the aggregated cost at the chosen plane). On the CPU a compiled
    kernel builds the cost volume (lfusd.evaluation._baselines_numba, float64); on a GPU PyTorch
    does, ``chunk`` planes at a time (float32). Both take the same candidates, cost and refinement.
    """
    if len(images) < 2:
        raise LfusdError("a plane sweep needs at least two views")
    if n_planes < 3 or not d_range[1] > d_range[0]:
        raise LfusdError(f"a plane sweep needs d_min < d_max and at least 3 planes, got {d_range} and {n_planes}")
    check_window(window)
    device = torch.device(device) if device is not None else default_device()
    keys = list(images)
    ds = torch.linspace(float(d_range[0]), float(d_range[1]), n_planes)  # the candidates, whichever device
    rel = [[offsets[k][0] - ref_offset[0], offsets[k][1] - ref_offset[1]] for k in keys]
    if device.type == "cpu":
        from ._baselines_numba import sweep_costs

        imgs = np.stack([_img_array(images[k]) for k in keys])  # V,H,W,C
        costs = torch.from_numpy(sweep_costs(imgs, np.asarray(rel, np.float32).astype(np.float64), ds.numpy().astype(np.float64), window))
    else:
        costs = _sweep_costs_torch(torch.stack([_img_tensor(images[k], device) for k in keys]), torch.tensor(rel, dtype=torch.float32, device=device),
                                   ds.to(device), window, chunk)
    ds = ds.to(costs)
    best = costs.argmin(dim=0)
    # parabola through the costs at best-1, best, best+1
    i0 = (best - 1).clamp(min=0)
    i2 = (best + 1).clamp(max=n_planes - 1)
    c0, c1, c2 = (costs.gather(0, i[None])[0] for i in (i0, best, i2))
    denom = c0 - 2 * c1 + c2
    delta = torch.where((denom > 1e-12) & (best > 0) & (best < n_planes - 1), 0.5 * (c0 - c2) / denom.clamp(min=1e-12), torch.zeros_like(c1))
    step = (d_range[1] - d_range[0]) / (n_planes - 1)
    disp = ds[best] + delta.clamp(-0.5, 0.5) * step
    return disp.cpu().numpy().astype(np.float32), c1.cpu().numpy().astype(np.float32)


def _sweep_costs_torch(imgs: torch.Tensor, rel: torch.Tensor, ds: torch.Tensor, window: int, chunk: int) -> torch.Tensor:
    """The cost volume (P,H,W) of :func:`plane_sweep` with PyTorch (a GPU): (V,C,H,W) views warped by grid_sample."""
    v, c, h, w = imgs.shape
    device = imgs.device
    n_planes = ds.shape[0]
    yy, xx = torch.meshgrid(torch.arange(h, device=device, dtype=torch.float32), torch.arange(w, device=device, dtype=torch.float32), indexing="ij")
    costs = torch.empty(n_planes, h, w, device=device)
    pad = window // 2

    def warp(dvals):
        # (P,) disparities -> (P,V,C,H,W) views resampled at the reference pixels
        p = dvals.shape[0]
        u = xx[None, None] - dvals[:, None, None, None] * rel[None, :, 0, None, None]
        vv = yy[None, None] - dvals[:, None, None, None] * rel[None, :, 1, None, None]
        grid = torch.stack([2 * u / max(w - 1, 1) - 1, 2 * vv / max(h - 1, 1) - 1], -1).reshape(p * v, h, w, 2)
        src = imgs[None].expand(p, v, c, h, w).reshape(p * v, c, h, w)
        out = F.grid_sample(src, grid, mode="bilinear", padding_mode="border", align_corners=True)
        return out.reshape(p, v, c, h, w)

    for s in range(0, n_planes, chunk):
        wv = warp(ds[s : s + chunk])
        var = wv.var(dim=1, unbiased=False).sum(dim=1)  # P,H,W
        costs[s : s + chunk] = F.avg_pool2d(var[:, None], window, stride=1, padding=pad, count_include_pad=False)[:, 0]
    return costs


def _warp_map(imgs: torch.Tensor, rel: torch.Tensor, disp: torch.Tensor) -> torch.Tensor:
    """Warp (V,C,H,W) views to the reference with a per-pixel disparity map (H,W) -> (V,C,H,W)."""
    v, c, h, w = imgs.shape
    yy, xx = torch.meshgrid(torch.arange(h, device=imgs.device, dtype=torch.float32), torch.arange(w, device=imgs.device, dtype=torch.float32), indexing="ij")
    u = xx[None] - disp[None] * rel[:, 0, None, None]
    vv = yy[None] - disp[None] * rel[:, 1, None, None]
    grid = torch.stack([2 * u / max(w - 1, 1) - 1, 2 * vv / max(h - 1, 1) - 1], -1)
    return F.grid_sample(imgs, grid, mode="bilinear", padding_mode="border", align_corners=True)


def plane_sweep_disparity(images: dict, offsets: dict, ref_offset=(0.0, 0.0), d_range=(-4.0, 4.0), n_planes: int = 64, window: int = 5, device=None):
    """Disparity (H,W) float32 at the reference position (see :func:`plane_sweep`)."""
    disp, _ = plane_sweep(images, offsets, ref_offset, d_range, n_planes, window, device)
    return disp


def render_at(images: dict, offsets: dict, ref_offset, disparity, device=None) -> np.ndarray:
    """Mean of the views warped to ``ref_offset`` with a per-pixel disparity: (H,W,3) float32 in [0, 1]."""
    device = torch.device(device) if device is not None else default_device()
    keys = list(images)
    imgs = torch.stack([_img_tensor(images[k], device) for k in keys])
    rel = torch.tensor([[offsets[k][0] - ref_offset[0], offsets[k][1] - ref_offset[1]] for k in keys], dtype=torch.float32, device=device)
    d = torch.as_tensor(np.asarray(disparity, np.float32), device=device)
    return _warp_map(imgs, rel, d).mean(dim=0).permute(1, 2, 0).clamp(0, 1).cpu().numpy()


def interpolate_views(images: dict, offsets: dict, target_offsets: dict, d_range, n_planes: int = 48, window: int = 7, device=None) -> dict:
    """Synthesise views at ``target_offsets`` {view: (sx, sy)} from ``images`` by a plane sweep at each."""
    out = {}
    for view, off in target_offsets.items():
        disp = plane_sweep_disparity(images, offsets, off, d_range, n_planes, window, device)
        out[view] = render_at(images, offsets, off, disp, device)
    return out


def blend_views(images: dict, offsets: dict, target_offsets: dict) -> dict:
    """Angular bilinear blending of four corner views (no geometry): the weakest sensible baseline."""
    keys = list(images)
    if len(keys) != 4:
        raise LfusdError(f"blending needs the four corner views, got {len(keys)}")
    xs = sorted({offsets[k][0] for k in keys})
    ys = sorted({offsets[k][1] for k in keys})
    if len(xs) != 2 or len(ys) != 2:
        raise LfusdError("blending needs four views on the corners of a rectangle")
    imgs = {k: np.asarray(images[k], np.float64) / (255.0 if np.asarray(images[k]).dtype == np.uint8 else 1.0) for k in keys}
    out = {}
    for view, (sx, sy) in target_offsets.items():
        ax = (sx - xs[0]) / (xs[1] - xs[0])
        ay = (sy - ys[0]) / (ys[1] - ys[0])
        acc = 0
        for k in keys:
            wx = ax if offsets[k][0] == xs[1] else 1 - ax
            wy = ay if offsets[k][1] == ys[1] else 1 - ay
            acc = acc + wx * wy * imgs[k]
        out[view] = acc.astype(np.float32)
    return out


def dis_flow(img1, img2, preset: str = "medium") -> np.ndarray:
    """Forward optical flow (H,W,2) (du, dv) from img1 to img2 with OpenCV's DIS."""
    import cv2

    presets = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST, "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST, "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}
    if preset not in presets:
        raise LfusdError(f"unknown DIS preset {preset!r}; use one of {', '.join(presets)}")

    def grey(a):
        a = np.asarray(a)
        if a.dtype != np.uint8:
            a = np.clip(np.round(a * 255), 0, 255).astype(np.uint8)
        return cv2.cvtColor(a, cv2.COLOR_RGB2GRAY) if a.ndim == 3 else a

    g1, g2 = grey(img1), grey(img2)
    if g1.shape != g2.shape:
        raise LfusdError(f"optical flow needs two images of one size, got {g1.shape} and {g2.shape}")
    dis = cv2.DISOpticalFlow_create(presets[preset])
    return dis.calc(g1, g2, None).astype(np.float32)


def _bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sample (H,W) at float pixel coordinates; returns (values, inside)."""
    h, w = img.shape
    inside = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    uc, vc = np.clip(u, 0, w - 1), np.clip(v, 0, h - 1)
    u0, v0 = np.minimum(np.floor(uc).astype(int), w - 2 if w > 1 else 0), np.minimum(np.floor(vc).astype(int), h - 2 if h > 1 else 0)
    a, b = uc - u0, vc - v0
    u1, v1 = np.minimum(u0 + 1, w - 1), np.minimum(v0 + 1, h - 1)
    val = (1 - a) * (1 - b) * img[v0, u0] + a * (1 - b) * img[v0, u1] + (1 - a) * b * img[v1, u0] + a * b * img[v1, u1]
    return val, inside


def backproject(disp: np.ndarray, u: np.ndarray, v: np.ndarray, K: np.ndarray, baseline: float, cam_to_world: np.ndarray) -> np.ndarray:
    """World points (...,3) of pixels (u, v) with disparity ``disp`` (z = f_px * b / d)."""
    f, cx, cy = K[0, 0], K[0, 2], K[1, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        z = f * baseline / disp
    p = np.stack([(u - cx) / f * z, (v - cy) / K[1, 1] * z, z], -1)
    return p @ cam_to_world[:3, :3].T + cam_to_world[:3, 3]


def scene_flow_from(disp0, disp1, flow, K, cam_to_world0, cam_to_world1, baseline: float):
    """Scene flow (H,W,3, world frame, metres), disparity change (H,W) and validity from two disparity
    maps of one view (at t and t+1) and its forward optical flow.
    """
    disp0, disp1, flow = (np.asarray(a, np.float64) for a in (disp0, disp1, flow))
    if disp0.shape != disp1.shape or flow.shape != disp0.shape + (2,):
        raise LfusdError(f"scene flow needs disparities and flow of one size, got {disp0.shape}, {disp1.shape}, {flow.shape}")
    h, w = disp0.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    d1, inside = _bilinear(disp1, u + flow[..., 0], v + flow[..., 1])
    sf, valid = scene_flow_from_change(disp0, d1 - disp0, flow, K, cam_to_world0, cam_to_world1, baseline)
    valid &= inside
    sf = np.where(valid[..., None], sf, np.nan)
    return sf.astype(np.float32), np.where(valid, d1 - disp0, np.nan).astype(np.float32), valid


def scene_flow_from_change(disp0, dchange, flow, K, cam_to_world0, cam_to_world1, baseline: float):
    """Scene flow (H,W,3, world frame, metres) and validity of one view from its disparity at t,
    the disparity change of each pixel's point (t -> t+1, lfusd's ``disparity_change``) and its
    forward optical flow: the point seen at (u, v) with disparity d is at (u, v) + flow with
    disparity d + dchange at t+1; both are back-projected (z = f_px * b / d) and subtracted."""
    disp0, dchange, flow = (np.asarray(a, np.float64) for a in (disp0, dchange, flow))
    if disp0.shape != dchange.shape or flow.shape != disp0.shape + (2,):
        raise LfusdError(f"scene flow needs disparity, disparity change and flow of one size, got {disp0.shape}, {dchange.shape}, {flow.shape}")
    K = np.asarray(K, np.float64)
    h, w = disp0.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    d1 = disp0 + dchange
    with np.errstate(invalid="ignore"):  # no surface (disparity 0): infinite points, masked below
        x0 = backproject(disp0, u, v, K, baseline, np.asarray(cam_to_world0, np.float64))
        x1 = backproject(d1, u + flow[..., 0], v + flow[..., 1], K, baseline, np.asarray(cam_to_world1, np.float64))
        sf = x1 - x0
    valid = (disp0 > 0) & (d1 > 0) & np.all(np.isfinite(flow), -1)
    return np.where(valid[..., None], sf, np.nan).astype(np.float32), valid


# ---- a first results table for a dataset -------------------------------------------------------


def _range(ds, frame, margin: float = 0.1):
    """The centre view's true disparity range with a margin (HCI gives disp_min/disp_max likewise)."""
    d = ds.read(frame, tuple(ds.rig.centre_view), "disparity")
    d = d[np.isfinite(d)]
    lo, hi = float(d.min()), float(d.max())
    pad = margin * max(hi - lo, 0.5)
    return lo - pad, hi + pad


def _subgrid(ds, n: int):
    rows, cols = ds.rig.rows, ds.rig.cols
    m = min(n, rows, cols)
    r0, c0 = (rows - m) // 2, (cols - m) // 2
    grid = [(r, c) for r in range(r0, r0 + m) for c in range(c0, c0 + m)]
    corners = [(r0, c0), (r0, c0 + m - 1), (r0 + m - 1, c0), (r0 + m - 1, c0 + m - 1)]
    return grid, corners, m


def run_baselines(ds, frames=None, views="all", n_planes: int = 64, asr: int = 7, window: int = 9, device=None, log=None) -> dict:
    """Run every baseline on a dataset and evaluate it; returns {task: metrics averaged over frames}.

    ``views`` for the disparity sweep: 'all' or 'cross' (the centre row and column, cheaper).
    ``asr``: the n of the 2x2 -> n x n view-synthesis task, on the central n x n views.
    ``window``: side of the box window that aggregates the disparity sweep's matching cost.
    """
    from ..data.folder import require_pinhole
    from ..data.torch import select_views

    require_pinhole(ds, "the baselines (a plane sweep shifting views by disparity, scene flow composed with K)")
    device = torch.device(device) if device is not None else default_device()
    say = log or (lambda *_: None)
    frames = list(ds.frames if frames is None else frames)
    centre = tuple(ds.rig.centre_view)
    sweep_views = select_views(ds.rig, views)
    offsets = {tuple(v): ds.rig.offsets(tuple(v)) for v in ds.views}
    k = np.asarray(ds.intrinsics(centre), np.float64)
    rows: dict[str, list[dict]] = {"disparity": [], "flow": [], "sceneflow": [], "views": [], "views_blend": []}
    est_disp = {}
    for t in frames:
        rng = _range(ds, t)
        imgs = {v: ds.read(t, v, "rgb") for v in sweep_views}
        est_disp[t] = plane_sweep_disparity(imgs, offsets, offsets[centre], rng, n_planes, window, device=device)
        gt = ds.read(t, centre, "disparity")
        rows["disparity"].append(metrics.disparity(est_disp[t], gt, np.isfinite(ds.read(t, centre, "depth"))))
        say(f"frame {t}: disparity {rows['disparity'][-1]}")
        grid, corners, m = _subgrid(ds, asr)
        if m >= 3:
            inp = {v: ds.read(t, v, "rgb") for v in corners}
            targets = {v: offsets[v] for v in grid if v not in corners}
            synth = interpolate_views(inp, offsets, targets, rng, n_planes=max(16, n_planes // 2), device=device)
            blend = blend_views(inp, offsets, targets)
            for v in targets:
                g = ds.read(t, v, "rgb")
                rows["views"].append(metrics.view_synthesis(synth[v], g))
                rows["views_blend"].append(metrics.view_synthesis(blend[v], g))
    for t in frames:
        if t + 1 not in frames:
            continue
        try:
            ds.read(t, centre, "flow_fwd")
        except LfusdError:  # a static render has no motion ground truth
            say(f"frame {t}: no motion ground truth; skipping flow and scene flow")
            continue
        flow = dis_flow(ds.read(t, centre, "rgb"), ds.read(t + 1, centre, "rgb"))
        valid = np.asarray(ds.read(t, centre, "valid_fwd"), bool)
        gt_flow = ds.read(t, centre, "flow_fwd")
        rows["flow"].append(metrics.optical_flow(flow, gt_flow, valid))
        sf, dchange, ok = scene_flow_from(est_disp[t], est_disp[t + 1], flow, k, ds.cam_to_world(t, centre), ds.cam_to_world(t + 1, centre), ds.rig.baseline)
        sf = np.where(ok[..., None], sf, 0.0)  # every valid ground-truth pixel counts; no estimate = zero motion
        dchange = np.where(ok, dchange, 0.0)
        r = metrics.scene_flow(sf, ds.read(t, centre, "scene_flow"), valid)
        d_gt = ds.read(t, centre, "disparity")
        d2_gt = d_gt + ds.read(t, centre, "disparity_change")
        r.update(metrics.kitti_outliers(est_disp[t], d_gt, est_disp[t] + dchange, d2_gt, flow, gt_flow, valid))
        rows["sceneflow"].append(r)
        say(f"frame {t}: flow {rows['flow'][-1]} scene flow {r}")
    return {task: {key: float(np.nanmean([r[key] for r in rs])) for key in rs[0]} | {"n": len(rs)} for task, rs in rows.items() if rs}


def format_table(results: dict, title: str = "") -> str:
    """A plain-text table in the style of the literature's results tables."""
    cols = {
        "disparity": [("MSEx100", "mse_x100"), ("BadPix0.01", "badpix_0.01_pct"), ("BadPix0.03", "badpix_0.03_pct"), ("BadPix0.07", "badpix_0.07_pct"), ("Q25", "q25_x100")],
        "flow": [("EPE", "epe_px"), ("Fl-all%", "fl_all_pct"), (">1px%", "epe_gt_1px_pct")],
        "sceneflow": [("EPE3D", "epe3d_m"), ("Acc3DS%", "acc3d_strict_pct"), ("Acc3DR%", "acc3d_relax_pct"), ("Outl3D%", "outlier3d_pct"), ("D1%", "d1_pct"), ("D2%", "d2_pct"), ("Fl%", "fl_pct"), ("SF%", "sf_pct")],
        "views": [("PSNR", "psnr_db"), ("SSIM", "ssim")],
        "views_blend": [("PSNR", "psnr_db"), ("SSIM", "ssim")],
    }
    names = {
        "disparity": "Disparity, plane sweep (centre view)",
        "flow": "Optical flow, OpenCV DIS (centre view)",
        "sceneflow": "Scene flow, plane sweep + DIS",
        "views": "2x2 -> NxN views, plane sweep at each view (Y)",
        "views_blend": "2x2 -> NxN views, angular blending (Y)",
    }
    lines = [title] if title else []
    for task, spec in cols.items():
        if task not in results:
            continue
        r = results[task]
        lines.append(f"{names[task]}  [n={r['n']}]")
        lines.append("  " + "  ".join(f"{h:>10}" for h, _ in spec))
        lines.append("  " + "  ".join(f"{r[k]:>10.4f}" if k == "ssim" else f"{r[k]:>10.3f}" for _, k in spec))
    return "\n".join(lines)
