"""Closed-form ray casting against planes and oriented boxes: the test oracle for rendered depth.

Independent of Blender and of lfusd's own geometry code: rays come from K and a pose, boxes
are unit cubes scaled and placed by a 4x4 matrix, the ground is the plane z = 0.
"""

from __future__ import annotations

import numpy as np


def pixel_rays(K: np.ndarray, cam_to_world: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(origin (3,), directions (H,W,3)) with camera-frame z = 1, so the ray parameter is depth."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    pix = np.stack([u, v, np.ones_like(u)], axis=-1)
    d_cam = pix @ np.linalg.inv(K).T
    return cam_to_world[:3, 3], d_cam @ cam_to_world[:3, :3].T


def hit_plane_z0(origin: np.ndarray, dirs: np.ndarray, half_extent: float) -> np.ndarray:
    """Ray parameter of the hit with the square z = 0, |x|,|y| <= half_extent (inf if none)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -origin[2] / dirs[..., 2]
    p = origin + t[..., None] * dirs
    ok = (t > 0) & (np.abs(p[..., 0]) <= half_extent) & (np.abs(p[..., 1]) <= half_extent)
    return np.where(ok, t, np.inf)


def hit_box(origin: np.ndarray, dirs: np.ndarray, box_to_world: np.ndarray, size: float) -> np.ndarray:
    """Ray parameter of the first hit with a cube of edge ``size`` placed by ``box_to_world``."""
    inv = np.linalg.inv(box_to_world)
    o = inv[:3, :3] @ origin + inv[:3, 3]
    d = dirs @ inv[:3, :3].T
    h = size / 2.0
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-h - o) / d
        t2 = (h - o) / d
    tmin = np.nanmax(np.minimum(t1, t2), axis=-1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=-1)
    ok = (tmax >= tmin) & (tmin > 0)
    return np.where(ok, tmin, np.inf)


def cast(K, cam_to_world, width, height, boxes: dict[str, tuple[np.ndarray, float]], ground_half: float | None):
    """(depth (H,W), hit name (H,W) of str) for a ground plane and named boxes."""
    origin, dirs = pixel_rays(K, cam_to_world, width, height)
    names = [""]
    ts = [np.full((height, width), np.inf)]
    if ground_half is not None:
        names.append("ground")
        ts.append(hit_plane_z0(origin, dirs, ground_half))
    for name, (m, size) in boxes.items():
        names.append(name)
        ts.append(hit_box(origin, dirs, m, size))
    stack = np.stack(ts)
    idx = np.argmin(stack, axis=0)
    depth = np.take_along_axis(stack, idx[None], 0)[0]
    idx[~np.isfinite(depth)] = 0
    return depth, np.array(names, dtype=object)[idx]


def project(K: np.ndarray, cam_to_world: np.ndarray, points: np.ndarray) -> np.ndarray:
    """World points (...,3) -> pixel coordinates (...,2) (u right, v down)."""
    w2c = np.linalg.inv(cam_to_world)
    pc = points @ w2c[:3, :3].T + w2c[:3, 3]
    uvw = pc @ K.T
    return uvw[..., :2] / uvw[..., 2:3]


def cast_uv(K, cam_to_world, uv: np.ndarray, boxes: dict[str, tuple[np.ndarray, float]], ground_half: float | None) -> np.ndarray:
    """Depth of the first surface along the rays through arbitrary pixel positions uv (N,2)."""
    pix = np.concatenate([uv, np.ones((len(uv), 1))], axis=1)
    dirs = (pix @ np.linalg.inv(K).T) @ cam_to_world[:3, :3].T
    origin = cam_to_world[:3, 3]
    ts = [np.full(len(uv), np.inf)]
    if ground_half is not None:
        ts.append(hit_plane_z0(origin, dirs, ground_half))
    ts += [hit_box(origin, dirs, m, size) for m, size in boxes.values()]
    return np.min(np.stack(ts), axis=0)
