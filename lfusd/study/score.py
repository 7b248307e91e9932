"""A candidate's scores, from its rendered cameras and their exact ground truth.

Definitions (every score says over how many pixels it was taken):

- **disparity error** (``disp_err``, percent): the centre view's inverse depth is estimated with a
  plane sweep over all the candidate's views (:mod:`.sweep`) and compared with the truth as the
  relative disparity error |d_est / d_gt - 1| (baseline and focal length cancel, so candidates
  of any baseline compare), clipped at 100 % so that a few wild pixels do not swamp the mean;
  ``disp_bad`` is the percentage of pixels off by more than 10 %. Both overall and by depth band
  of the true depth.
- **redundancy** (``psnr``, ``ssim``, per view): every view is held out and reconstructed at its
  own pose from its grid neighbours (the up to 8 views around it) by a plane sweep from that pose;
  PSNR / SSIM on luma (lfusd.evaluation.metrics.view_synthesis). A view reconstructed well is
  redundant (the paper's signal); a view identical to its reconstruction counts as
  :data:`PSNR_CAP` dB. ``psnr_band``: PSNR of the pooled errors by depth band of the held-out view.
- **coverage**, **holes**, **outside** (percent, geometric, from the true depth): each surface
  pixel of each view is projected into every other view; it is *seen* there when it lands inside
  the image and no nearer surface covers it (its depth there is at most the largest true depth of
  the four pixels around the landing point: exact for planar patches, where the depth at a point
  lies between its corners'). ``coverage``: seen by at least one other view (so by >= 2 views);
  ``holes``: inside another view's image but occluded in all of them; ``outside``: inside none.
  The three add up to 100 %.
- **parallax** (px): the shift of the centre view's surface points into another view, less the
  shift of the point at infinity on the same ray (rotation alone moves nothing): the median to
  the nearest other camera (``parallax_nn``) and to the farthest (``parallax_far``).
- **scene flow** (``epe3d``, metres; dynamic stages, ``--task sceneflow``): the centre view's
  inverse depth at t and t+1 (plane sweeps) and OpenCV DIS optical flow give scene flow
  (lfusd.evaluation.baselines.scene_flow_from), scored against the truth over its valid pixels
  (lfusd.evaluation.metrics.scene_flow).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..camera import Camera, RigSpec, View, backproject, project
from ..errors import LfusdError
from ..evaluation import metrics
from .sweep import Sweep, plane_count

PSNR_CAP = 100.0  # dB: a reconstruction identical to the view (8-bit: 1 level everywhere is 48 dB)
BAD_REL = 0.10  # a disparity off by more than 10 % is a bad pixel
DEPTH_TOL = 1e-4  # relative slack of the occlusion test (float32 depth)
MARGIN = 0.1  # the sweep's inverse-depth range extends the true range by 10 % on each side


@dataclass
class Views:
    """The rendered cameras of one position at one frame, by camera id."""

    rgb: np.ndarray  # N,H,W,3 uint8
    depth: np.ndarray  # N,H,W float32, inf where no surface
    K: np.ndarray  # 3,3 (one lens for all)
    poses: np.ndarray  # N,4,4 OpenCV cam_to_world, metres
    index: dict[str, int]


@dataclass(frozen=True)
class Bands:
    """Depth bands: edges in metres, e.g. (1, 3, 10, 30) -> <1, 1-3, 3-10, 10-30, >=30 m."""

    edges: tuple[float, ...]

    @property
    def labels(self) -> list[str]:
        e = self.edges
        return [f"<{e[0]:g} m"] + [f"{a:g}-{b:g} m" for a, b in zip(e, e[1:])] + [f">={e[-1]:g} m"]

    def of(self, depth: np.ndarray) -> np.ndarray:
        """Band index per pixel (-1 where there is no surface)."""
        b = np.searchsorted(np.asarray(self.edges, np.float64), depth, side="right")
        return np.where(np.isfinite(depth), b, -1)


def neighbours(spec: RigSpec, view: View) -> list[View]:
    """The up to 8 views around ``view`` in the grid."""
    r, c = view
    return [(r + i, c + j) for i in (-1, 0, 1) for j in (-1, 0, 1) if (i or j) and 0 <= r + i < spec.rows and 0 <= c + j < spec.cols]


def _q_range(depth: np.ndarray) -> tuple[float, float]:
    """The inverse-depth range of a view's truth with a margin; 0 (infinity) included when it sees background."""
    z = depth[np.isfinite(depth)]
    if z.size == 0:
        raise LfusdError("a study view sees no surface at all; point the rig at the scene (--rig) or check the stage")
    lo = 0.0 if not np.all(np.isfinite(depth)) else 1.0 / float(z.max())
    hi = 1.0 / float(z.min())
    pad = MARGIN * (hi - lo)
    return max(0.0, lo - pad), hi + pad


def _planes(depth: np.ndarray, K: np.ndarray, reach: float, n_planes: int | None) -> np.ndarray:
    q = _q_range(depth)
    n = n_planes or plane_count(q, float(K[0, 0]), reach)
    return np.linspace(q[0], q[1], n)


def _unit(rgb: np.ndarray) -> np.ndarray:
    return np.asarray(rgb, np.float32).transpose(0, 3, 1, 2) / 255.0


def estimate_inverse_depth(views: Views, ref: int, sources: list[int], n_planes: int | None = None, window: int = 5, device="cpu") -> np.ndarray:
    """Inverse depth (H,W) of camera ``ref`` by a plane sweep over ``sources`` (which include it)."""
    poses = views.poses[sources]
    reach = float(np.max(np.linalg.norm(poses[:, :3, 3] - views.poses[ref, :3, 3], axis=1), initial=0.0))
    sw = Sweep(_unit(views.rgb[sources]), np.broadcast_to(views.K, (len(sources), 3, 3)), poses, views.K, views.poses[ref], device)
    return sw.depth(_planes(views.depth[ref], views.K, reach, n_planes), window)


def reconstruct(views: Views, target: int, sources: list[int], n_planes: int | None = None, window: int = 5, device="cpu") -> np.ndarray:
    """Camera ``target`` synthesised at its own pose from ``sources`` (which exclude it): (H,W,3) in [0, 1]."""
    poses = views.poses[sources]
    reach = float(np.max(np.linalg.norm(poses[:, :3, 3] - views.poses[target, :3, 3], axis=1), initial=0.0))
    sw = Sweep(_unit(views.rgb[sources]), np.broadcast_to(views.K, (len(sources), 3, 3)), poses, views.K, views.poses[target], device)
    q = sw.depth(_planes(views.depth[target], views.K, reach, n_planes), window)
    return sw.colour(q)[0]


def redundancy(views: Views, cams: list[int], groups: list[list[int]], bands: Bands, n_planes=None, device="cpu") -> dict:
    """Held-out reconstruction of each camera ``cams[i]`` from ``groups[i]``: per-view PSNR / SSIM
    (Y), and PSNR by depth band of the pooled squared errors."""
    psnr, ssim = [], []
    nb = len(bands.edges) + 1
    sq, cnt = np.zeros(nb), np.zeros(nb, np.int64)
    pixels = 0
    for i, src in zip(cams, groups):
        if not src:
            raise LfusdError("a held-out view needs at least one neighbour; use a grid of at least 1x2")
        pred = reconstruct(views, i, src, n_planes, device=device)
        m = metrics.view_synthesis(pred, views.rgb[i])
        psnr.append(min(m["psnr_db"], PSNR_CAP))
        ssim.append(m["ssim"])
        err = (metrics.rgb_to_y(pred) - metrics.rgb_to_y(views.rgb[i] / 255.0)) ** 2
        b = bands.of(views.depth[i])
        for k in range(nb):
            sel = b == k
            sq[k] += err[sel].sum()
            cnt[k] += sel.sum()
        pixels += err.size
    with np.errstate(divide="ignore", invalid="ignore"):
        band_psnr = [min(float(10 * np.log10(1.0 / (s / n))), PSNR_CAP) if n and s > 0 else (PSNR_CAP if n else None) for s, n in zip(sq, cnt)]
    return {"psnr_views": psnr, "ssim_views": ssim, "psnr": float(np.mean(psnr)), "ssim": float(np.mean(ssim)),
            "psnr_band": band_psnr, "n_views_px": int(pixels)}


def visibility(views: Views, cams: list[int]) -> dict:
    """Coverage, occlusion holes and outside (percent of surface pixels, averaged over views); see the module docstring."""
    K = views.K
    h, w = views.depth.shape[1:]
    cov, hol, out = [], [], []
    total = 0
    for a, i in enumerate(cams):
        z_i = views.depth[i]
        m = np.isfinite(z_i)
        if not m.any():
            cov.append(0.0), hol.append(0.0), out.append(100.0)
            continue
        v, u = np.nonzero(m)
        pts = backproject(u.astype(np.float64), v.astype(np.float64), z_i[m].astype(np.float64), Camera(K, views.poses[i]))
        inside_any = np.zeros(len(u), bool)
        seen_any = np.zeros(len(u), bool)
        for b, j in enumerate(cams):
            if b == a:
                continue
            pu, pv, pz = project(pts, Camera(K, views.poses[j]))
            inside = (pz > 0) & (pu >= 0) & (pu <= w - 1) & (pv >= 0) & (pv <= h - 1)
            if not inside.any():
                continue
            u0 = np.clip(np.floor(pu[inside]).astype(int), 0, max(w - 2, 0))
            v0 = np.clip(np.floor(pv[inside]).astype(int), 0, max(h - 2, 0))
            d = views.depth[j]
            corners = np.stack([d[v0, u0], d[v0, np.minimum(u0 + 1, w - 1)], d[np.minimum(v0 + 1, h - 1), u0], d[np.minimum(v0 + 1, h - 1), np.minimum(u0 + 1, w - 1)]])
            seen = pz[inside] <= corners.max(0) * (1 + DEPTH_TOL)
            inside_any |= inside
            idx = np.flatnonzero(inside)
            seen_any[idx[seen]] = True
        n = len(u)
        total += n
        cov.append(100.0 * seen_any.sum() / n)
        out.append(100.0 * (~inside_any).sum() / n)
        hol.append(100.0 * (inside_any & ~seen_any).sum() / n)
    return {"coverage": float(np.mean(cov)), "holes": float(np.mean(hol)), "outside": float(np.mean(out)),
            "coverage_views": cov, "n_visibility_px": int(total)}


def parallax(views: Views, centre: int, cams: list[int]) -> dict:
    """Median parallax (px) of the centre view's surface points into the nearest and the farthest other camera."""
    z = views.depth[centre]
    m = np.isfinite(z)
    v, u = np.nonzero(m)
    cam_c = Camera(views.K, views.poses[centre])
    pts = backproject(u.astype(np.float64), v.astype(np.float64), z[m].astype(np.float64), cam_c)
    ray = pts - views.poses[centre, :3, 3]
    dist = np.array([np.linalg.norm(views.poses[j, :3, 3] - views.poses[centre, :3, 3]) for j in cams])
    others = [k for k in range(len(cams)) if dist[k] > 0]
    if not others or not m.any():
        return {"parallax_nn": 0.0, "parallax_far": 0.0, "n_parallax_px": int(m.sum())}
    out = {}
    for key, k in (("parallax_nn", min(others, key=lambda k: dist[k])), ("parallax_far", max(others, key=lambda k: dist[k]))):
        cam = Camera(views.K, views.poses[cams[k]])
        pu, pv, pz = project(pts, cam)
        # the point at infinity on the same ray: its direction projected (translation dropped)
        R, _ = cam.world_to_cam()
        d = ray @ (views.K @ R).T
        with np.errstate(divide="ignore", invalid="ignore"):
            iu, iv = d[:, 0] / d[:, 2], d[:, 1] / d[:, 2]
        shift = np.hypot(pu - iu, pv - iv)
        ok = (pz > 0) & np.isfinite(shift)
        out[key] = float(np.median(shift[ok])) if ok.any() else float("nan")
    out["n_parallax_px"] = int(m.sum())
    return out


def disparity_error(q_est: np.ndarray, depth: np.ndarray, bands: Bands) -> dict:
    """Relative disparity error (percent, clipped at 100) and bad pixels (percent > 10 %), overall and by band."""
    m = np.isfinite(depth)
    rel = np.minimum(np.abs(q_est[m] * depth[m] - 1.0), 1.0)
    rel = np.where(np.isfinite(rel), rel, 1.0)
    b = bands.of(depth)[m]
    per = [float(100 * rel[b == k].mean()) if (b == k).any() else None for k in range(len(bands.edges) + 1)]
    bad = [float(100 * (rel[b == k] > BAD_REL).mean()) if (b == k).any() else None for k in range(len(bands.edges) + 1)]
    counts = [int((b == k).sum()) for k in range(len(bands.edges) + 1)]
    return {"disp_err": float(100 * rel.mean()), "disp_bad": float(100 * (rel > BAD_REL).mean()),
            "disp_err_band": per, "disp_bad_band": bad, "n_band_px": counts, "n_disp_px": int(m.sum())}


def scene_flow_error(q0: np.ndarray, q1: np.ndarray, rgb0, rgb1, K, pose0, pose1, gt, valid) -> dict:
    """EPE3D and outlier rates of scene flow from two inverse-depth maps of one camera and DIS flow."""
    from ..evaluation.baselines import dis_flow, scene_flow_from

    f = float(K[0, 0])
    flow = dis_flow(rgb0, rgb1)
    sf, _, ok = scene_flow_from(q0 * f, q1 * f, flow, K, pose0, pose1, 1.0)  # disparity f*b/z with b = 1
    sf = np.where(ok[..., None], sf, 0.0)  # no estimate = zero motion: every valid truth pixel counts
    r = metrics.scene_flow(sf, gt, valid)
    return {"epe3d": r["epe3d"], "outlier3d": r["outlier3d"], "n_sceneflow_px": int(np.asarray(valid, bool).sum())}


def score(spec: RigSpec, ids: tuple[str, ...], views: Views, bands: Bands, redundant: bool = True, n_planes=None, device="cpu") -> dict:
    """Every static score of one candidate at one frame (see the module docstring)."""
    cams = [views.index[c] for c in ids]
    order = {v: k for k, v in enumerate(spec.views)}
    centre = cams[order[spec.centre_view]]
    out = {"centre": centre}
    out["q_centre"] = estimate_inverse_depth(views, centre, sorted(set(cams)), n_planes, device=device)
    out |= disparity_error(out["q_centre"], views.depth[centre], bands)
    out |= visibility(views, cams)
    out |= parallax(views, centre, cams)
    if redundant:
        groups = [[cams[order[n]] for n in neighbours(spec, v)] for v in spec.views]
        out |= redundancy(views, cams, groups, bands, n_planes, device=device)
    return out


def finite_mean(values) -> float | None:
    vals = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(vals)) if vals else None
