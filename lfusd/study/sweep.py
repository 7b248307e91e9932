"""A plane sweep over cameras of any pose: the estimator the study scores arrangements with.

lfusd.evaluation.baselines.plane_sweep shifts views by their grid offsets, which is exact for
planar parallel rigs only; a study also compares spheres and converging axes. Here each
candidate plane is fronto-parallel to the reference camera at inverse depth q = 1/z, and a
reference pixel's ray point X = C_ref + z * D (D the ray with camera-frame z = 1) lands in view j
at the homogeneous pixel M_j (X - C_j) ~ q * M_j (C_ref - C_j) + M_j D, with M_j = K_j R_j^T;
q = 0 is the plane at infinity. The matching cost is the colour variance over the views that
see the point (box-filtered), the best plane is refined with a parabola through its neighbours'
costs (as in the evaluation baseline), and the colour is the mean of the views at that depth,
weighted by the inverse distance of each camera centre to the reference (unstructured lumigraph
blending's distance term: a camera at the reference's own place dominates).
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from ..camera import pixel_grid
from ..errors import LfusdError

NO_MATCH = 1.0  # cost where fewer than two views see the point: above any colour variance of [0, 1] RGB (at most 0.75)
MIN_DISTANCE = 1e-9  # metres: the blending weight of a camera at the reference's place


def _tensor(a, device) -> torch.Tensor:
    return torch.as_tensor(np.array(a, np.float64), device=device)  # a copy: inputs may be read-only


class Sweep:
    """Source views (images in [0, 1] (V,3,H,W), intrinsics (V,3,3), OpenCV cam_to_world (V,4,4)) seen from a reference camera."""

    def __init__(self, images, Ks, poses, K_ref, pose_ref, device="cpu"):
        self.device = torch.device(device)
        imgs = torch.as_tensor(np.asarray(images, np.float32), device=self.device)
        if imgs.ndim != 4 or imgs.shape[0] < 1:
            raise LfusdError(f"a sweep needs images of shape (V,3,H,W), got {tuple(imgs.shape)}")
        self.images = imgs
        v, _, h, w = imgs.shape
        self.h, self.w = h, w
        Ks, poses = _tensor(Ks, self.device).reshape(v, 3, 3), _tensor(poses, self.device).reshape(v, 4, 4)
        K_ref, pose_ref = _tensor(K_ref, self.device), _tensor(pose_ref, self.device)
        u, vv = pixel_grid(h, w, np.float64)
        pix = _tensor(np.stack([u.ravel(), vv.ravel(), np.ones(h * w)]), self.device)  # 3,HW
        D = pose_ref[:3, :3] @ torch.linalg.inv(K_ref) @ pix  # world rays, camera-frame z = 1
        M = Ks @ poses[:, :3, :3].transpose(1, 2)  # V,3,3
        self.a = (M @ (pose_ref[:3, 3] - poses[:, :3, 3])[:, :, None]).float()  # V,3,1
        self.B = (M @ D).float()  # V,3,HW
        dist = torch.linalg.norm(poses[:, :3, 3] - pose_ref[:3, 3], dim=1)
        self.weights = (1.0 / dist.clamp(min=MIN_DISTANCE)).float()  # V

    def _warp(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Views resampled at the reference pixels for inverse depths q: (P,HW) -> ((P,V,3,HW), seen (P,V,HW))."""
        p, (v, _, h, w) = q.shape[0], self.images.shape
        x = q[:, None, None, :] * self.a[None] + self.B[None]  # P,V,3,HW
        z = x[:, :, 2]
        front = z > 1e-9
        zs = torch.where(front, z, torch.ones_like(z))
        u, vv = x[:, :, 0] / zs, x[:, :, 1] / zs
        seen = front & (u >= 0) & (u <= w - 1) & (vv >= 0) & (vv <= h - 1)
        grid = torch.stack([2 * u / max(w - 1, 1) - 1, 2 * vv / max(h - 1, 1) - 1], -1).reshape(p * v, 1, h * w, 2)
        src = self.images[None].expand(p, v, 3, h, w).reshape(p * v, 3, h, w)
        out = F.grid_sample(src, grid, mode="bilinear", padding_mode="border", align_corners=True)
        return out.reshape(p, v, 3, h * w), seen

    def costs(self, planes: torch.Tensor, window: int = 5, chunk: int = 8) -> torch.Tensor:
        """(P,H,W) matching cost of each plane of inverse depth ``planes`` (P,)."""
        h, w = self.h, self.w
        out = torch.empty(planes.shape[0], h, w, device=self.device)
        for s in range(0, planes.shape[0], chunk):
            q = planes[s : s + chunk, None].expand(-1, h * w)
            col, seen = self._warp(q)
            m = seen[:, :, None].float()
            n = m.sum(1)  # P,1,HW
            mean = (col * m).sum(1) / n.clamp(min=1)
            var = ((col * col * m).sum(1) / n.clamp(min=1) - mean * mean).clamp(min=0).sum(1)  # P,HW
            var = torch.where(n[:, 0] >= 2, var, torch.full_like(var, NO_MATCH))
            out[s : s + chunk] = F.avg_pool2d(var.reshape(-1, 1, h, w), window, stride=1, padding=window // 2, count_include_pad=False)[:, 0]
        return out

    def depth(self, planes, window: int = 5) -> np.ndarray:
        """Inverse depth (H,W) at the reference: the best of ``planes`` (evenly spaced inverse depths), parabola-refined."""
        planes = torch.as_tensor(np.asarray(planes, np.float32), device=self.device)
        if planes.ndim != 1 or planes.shape[0] < 3:
            raise LfusdError("a sweep needs at least 3 planes")
        c = self.costs(planes, window)
        n = planes.shape[0]
        best = c.argmin(0)
        c0, c1, c2 = (c.gather(0, i.clamp(0, n - 1)[None])[0] for i in (best - 1, best, best + 1))
        denom = c0 - 2 * c1 + c2
        inner = (best > 0) & (best < n - 1) & (denom > 1e-12)
        delta = torch.where(inner, 0.5 * (c0 - c2) / denom.clamp(min=1e-12), torch.zeros_like(c1)).clamp(-0.5, 0.5)
        step = float(planes[1] - planes[0])
        return (planes[best] + delta * step).cpu().numpy().astype(np.float32)

    def colour(self, inv_depth) -> tuple[np.ndarray, np.ndarray]:
        """(colour (H,W,3) in [0, 1], seen (H,W) bool): the views at per-pixel inverse depth, blended by
        inverse camera distance; unseen pixels are 0."""
        q = torch.as_tensor(np.asarray(inv_depth, np.float32), device=self.device).reshape(1, -1)
        col, seen = self._warp(q)
        wgt = seen[0].float() * self.weights[:, None]  # V,HW
        total = wgt.sum(0)
        c = (col[0] * wgt[:, None]).sum(0) / total.clamp(min=1e-30)
        c = torch.where(total > 0, c, torch.zeros_like(c))
        return c.T.reshape(self.h, self.w, 3).clamp(0, 1).cpu().numpy(), (total > 0).reshape(self.h, self.w).cpu().numpy()


def plane_count(q_range: tuple[float, float], focal_px: float, reach_m: float, lo: int = 16, hi: int = 96) -> int:
    """Planes for an inverse-depth range: about one pixel of parallax per step at the farthest
    camera (``reach_m`` from the reference), within [lo, hi]."""
    span = (q_range[1] - q_range[0]) * focal_px * reach_m
    return int(np.clip(np.ceil(span) + 1, lo, hi))
