"""Exact visibility of surface points: rays cast against a frame's triangles as Blender rendered them.

A point P seen at frame t is *visible* at frame t' (= t+1 or t-1) in a view when it projects
inside that view's image at t' (u' in [-0.5, W-0.5], v' in [-0.5, H-0.5], in front of the camera)
and the ray from the view's camera centre C' at t' towards P meets no surface before P: Open3D's
``RaycastingScene`` tests it against every rendered triangle at t' (``geometry.npz``, written by
the render worker from Blender's evaluated meshes) and finds no hit before ray parameter
``1 - VISIBLE_EPS`` (the parameter of P itself is 1). That is Embree's any-hit query
(``test_occlusions`` with tfar = 1 - VISIBLE_EPS), the same answer as "the first hit lies at or
beyond 1 - VISIBLE_EPS" without finding the first hit (measured: the same mask on 2 x 56,000 rays of
benchmarks/bench_flow.py's scene at 256x256; 120 against 139 ms of CPU per 1M rays).

Tie rule: a surface within ``VISIBLE_EPS`` (1e-4) of the distance in front of P does not hide
it. Float32 positions and triangles put P a few 1e-7 of the distance off its own surface, more on
surfaces seen at a grazing angle, and the verifier's independent geometry differs from Blender's by
as much: within that band the two surfaces cannot be told apart, and both verify and the
derivation call the point visible. docs/CONVENTIONS.md ("Occlusion") states the definition.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..camera import Camera

VISIBLE_EPS = 1e-4

_CACHE: dict[tuple, "Occluders"] = {}


class Occluders:
    """A frame's triangles (world space) in an Open3D ray-casting scene."""

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, instance: np.ndarray | None = None):
        import open3d as o3d

        self.vertices = np.ascontiguousarray(vertices, np.float32)
        self.triangles = np.ascontiguousarray(triangles, np.uint32)
        self.instance = instance
        self.scene = o3d.t.geometry.RaycastingScene()
        if len(self.triangles):
            self.scene.add_triangles(o3d.core.Tensor(self.vertices), o3d.core.Tensor(self.triangles))

    @classmethod
    def load(cls, path: str | Path) -> "Occluders":
        """Read ``geometry.npz`` (cached per process by file identity: the views of one chunk share
        one file through hard links, so their scene is built once)."""
        st = os.stat(path)
        key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
        if key not in _CACHE:
            with np.load(path) as z:
                occ = cls(z["vertices"], z["triangles"], z["instance"] if "instance" in z else None)
            if len(_CACHE) >= 4:  # frames t-1, t, t+1 of one view, and one more
                _CACHE.pop(next(iter(_CACHE)))
            _CACHE[key] = occ
        return _CACHE[key]

    @property
    def corners(self) -> np.ndarray:
        """(M, 3, 3) float32: each triangle's three vertices (built once)."""
        if getattr(self, "_corners", None) is None:
            self._corners = self.vertices[self.triangles.astype(np.int64)]
        return self._corners

    def cast(self, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t_hit, triangle index (-1 where none), barycentric (u, v) of the hit) per ray."""
        import open3d as o3d

        rays = np.ascontiguousarray(np.concatenate([origins, dirs], axis=-1), np.float32)
        ans = self.scene.cast_rays(o3d.core.Tensor(rays))
        t = ans["t_hit"].numpy()
        tri = np.where(np.isfinite(t), ans["primitive_ids"].numpy().astype(np.int64), -1)
        return t, tri, ans["primitive_uvs"].numpy()

    def first_hit(self, origins: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """Ray parameter of the first surface on the segment origin -> target (1 = at the target;
        inf when nothing is hit)."""
        import open3d as o3d

        if len(origins) == 0:
            return np.zeros(0, np.float32)
        rays = np.concatenate([origins, targets - origins], axis=-1).astype(np.float32)
        return self.scene.cast_rays(o3d.core.Tensor(np.ascontiguousarray(rays)))["t_hit"].numpy()


def visible(points: np.ndarray, valid: np.ndarray, camera: Camera, h: int, w: int, occluders: Occluders,
            eps: float = VISIBLE_EPS) -> np.ndarray:
    """Whether each world point (N,3) with ``valid`` (N,) is visible in ``camera`` at the occluders'
    frame (see the module docstring): it projects inside the image, in front of the camera, and no
    surface lies on the segment from the camera centre before ray parameter ``1 - eps`` (Embree's
    any-hit query, Open3D's ``test_occlusions``: the first hit is not needed, only whether one is
    that near)."""
    import open3d as o3d

    from ._motion_numba import segment_rays

    R, C = camera.world_to_cam()
    M = np.asarray(camera.K, np.float64) @ R
    points = np.ascontiguousarray(points, np.float32).reshape(-1, 3)
    rays, index = segment_rays(points, np.ascontiguousarray(valid).ravel(), M, np.ascontiguousarray(C, np.float64),
                               np.ascontiguousarray(R[2], np.float64), h, w)
    out = np.zeros(len(points), bool)
    if len(index) and len(occluders.triangles):
        # the rays of the points inside only, handed to Open3D without a copy
        hidden = occluders.scene.test_occlusions(o3d.core.Tensor.from_numpy(rays), tnear=0.0, tfar=1.0 - eps).numpy()
        out[index] = hidden == 0
    else:
        out[index] = True
    return out


MIXED_DEPTH_REL = 0.01  # corners whose depths differ by more than this see different surfaces
MIXED_FLOW_PX = 0.5  # ... or whose forward flows differ by more than this move differently
CORNERS = ((-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5))  # a pixel's corners, (du, dv) from its centre


def mixed_footprint(camera: Camera, h: int, w: int, here: Occluders, nxt: Occluders | None = None,
                    camera_next: Camera | None = None) -> np.ndarray:
    """(H, W) bool: the pixel's footprint holds more than one surface or motion (key ``mixed``).

    A ray through each pixel corner (u +- 1/2, v +- 1/2) is cast against the frame's rendered
    triangles (``here``), once per corner for the four pixels that share it ((H+1)(W+1) rays): a
    pixel's four corners differ when their hits differ in instance (or hit and miss), or in depth
    by more than ``MIXED_DEPTH_REL``; with the next frame's triangles (``nxt``, same triangles in
    the same order: same count) each hit is carried to t+1 on its triangle (same barycentric
    coordinates) and projected with ``camera_next``, and forward flows more than ``MIXED_FLOW_PX``
    apart differ too. The corners are the footprint's extreme points: a straight edge that crosses
    the footprint separates two of them, wherever it crosses."""
    import open3d as o3d

    from ._motion_numba import mixed_pixels, pixel_rays

    _, C = camera.world_to_cam()
    n = (h + 1) * (w + 1)
    if len(here.triangles):
        # the corner grid is the pixel grid of an (H+1) x (W+1) image shifted by half a pixel
        rays = pixel_rays(camera._pixel_to_world(np.float64), np.ascontiguousarray(C, np.float64), -0.5, -0.5, h + 1, w + 1)
        hits = here.scene.cast_rays(o3d.core.Tensor.from_numpy(rays))
        t, tri, uv = hits["t_hit"].numpy(), hits["primitive_ids"].numpy(), hits["primitive_uvs"].numpy()  # tri: not read where t is inf
    else:
        t, tri, uv = np.full(n, np.inf, np.float32), np.zeros(n, np.uint32), np.zeros((n, 2), np.float32)
    inst = np.ascontiguousarray(here.instance if here.instance is not None else np.zeros(len(here.triangles)), np.int32)
    carry = nxt is not None and camera_next is not None and len(nxt.triangles) == len(here.triangles) and len(here.triangles) > 0
    if carry:
        Rn, Cn = camera_next.world_to_cam()
        args = (nxt.vertices, np.ascontiguousarray(nxt.triangles, np.uint32), np.asarray(camera_next.K, np.float64) @ Rn,
                np.ascontiguousarray(Cn, np.float64))
    else:
        args = (np.zeros((1, 3), np.float32), np.zeros((1, 3), np.uint32), np.eye(3), np.zeros(3))
    return mixed_pixels(t, tri, uv, inst if inst.size else np.zeros(1, np.int32), carry, *args, h, w, MIXED_DEPTH_REL, MIXED_FLOW_PX)


# ---- stereo visibility of planar parallel rigs, from disparity alone (the KITTI export's noc masks) ----
VIS_REL = 1e-3  # relative disparity slack of the stereo visibility test (as lfusd.truth.motion.DEPTH_REL)
EDGE_REL = 0.5  # a relative disparity jump above this between neighbours is a depth edge (no slope across it)


def _one_sided_slopes(d: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """(towards lower index, towards higher index) differences of ``d`` along ``axis``; NaN across a
    depth edge (relative jump above EDGE_REL) or off the image."""
    a, b = (d[:, :-1], d[:, 1:]) if axis == 1 else (d[:-1], d[1:])
    g = np.where(np.abs(b - a) <= EDGE_REL * np.minimum(a, b), b - a, np.nan)
    lower, higher = np.full(d.shape, np.nan), np.full(d.shape, np.nan)
    if axis == 1:
        higher[:, :-1], lower[:, 1:] = g, g
    else:
        higher[:-1], lower[1:] = g, g
    return lower, higher


def visible_in_view(x, y, d_expected, disparity_other) -> np.ndarray:
    """Whether points seen elsewhere are visible in another view of a planar parallel rig.

    A point lands at (x, y) in the other view (sub-pixel) with disparity ``d_expected`` there
    (disparity = f_px*b/z, so depth and disparity are one test). It is visible when (x, y) lies
    inside the image and the pixel nearest (x, y) does not see a nearer surface: that pixel's
    disparity, extrapolated to (x, y) with its one-sided slopes (never across a depth edge; exact
    on planes), is the point's own (within :data:`VIS_REL`) or smaller (a surface behind the point,
    which then sits on a silhouette). A nearer surface there hides it. Decided within half a pixel of
    the other view's depth edges and creases.
    """
    D = np.nan_to_num(np.asarray(disparity_other, np.float64), nan=0.0, posinf=0.0)  # no surface: disparity 0
    h, w = D.shape
    x, y, de = (np.asarray(a, np.float64) for a in (x, y, d_expected))
    with np.errstate(invalid="ignore"):
        inside = (x >= -0.5) & (x <= w - 0.5) & (y >= -0.5) & (y <= h - 0.5) & (de > 0)
    x, y = np.where(inside, x, 0.0), np.where(inside, y, 0.0)
    xi = np.clip(np.rint(x), 0, w - 1).astype(np.int64)
    yi = np.clip(np.rint(y), 0, h - 1).astype(np.int64)
    dx, dy = x - xi, y - yi
    with np.errstate(invalid="ignore"):
        left, right = _one_sided_slopes(D, 1)
        up, down = _one_sided_slopes(D, 0)
    # the slope on the side of the point, else the other side's, else flat
    gx = np.where(dx >= 0, right[yi, xi], left[yi, xi])
    gx = np.nan_to_num(np.where(np.isnan(gx), np.where(dx >= 0, left[yi, xi], right[yi, xi]), gx))
    gy = np.where(dy >= 0, down[yi, xi], up[yi, xi])
    gy = np.nan_to_num(np.where(np.isnan(gy), np.where(dy >= 0, up[yi, xi], down[yi, xi]), gy))
    tol = VIS_REL * de
    seen = D[yi, xi] + dx * gx + dy * gy  # what the pixel's surface has at (x, y)
    return inside & (seen <= de + tol)  # the point's own surface, or one behind it


def stereo_visible(ds, frame: int, view, other, flow=None, disparity=None) -> np.ndarray:
    """(H,W) bool: which pixels of ``view`` show a point that ``other`` (same planar parallel rig)
    also sees, at ``frame``; with ``flow`` (H,W,2) and ``disparity`` (H,W), the point moved to
    view pixel (u, v) + flow with that disparity, tested against ``other`` at ``frame``."""
    d = np.asarray(ds.read(frame, view, "disparity") if disparity is None else disparity, np.float64)
    sx0, sy0 = ds.rig.offsets(tuple(view))
    sx1, sy1 = ds.rig.offsets(tuple(other))
    v, u = np.mgrid[0 : d.shape[0], 0 : d.shape[1]].astype(np.float64)
    if flow is not None:
        u, v = u + flow[..., 0], v + flow[..., 1]
    with np.errstate(invalid="ignore"):
        x, y = u - d * (sx1 - sx0), v - d * (sy1 - sy0)  # CONVENTIONS: u - d*sx, v - d*sy
    return visible_in_view(x, y, d, ds.read(frame, other, "disparity")) & np.isfinite(d)


def inside_image(x, y, width: int, height: int) -> np.ndarray:
    """Whether sub-pixel positions (x, y) fall on a pixel of a width x height image (its area,
    [-0.5, W - 0.5) x [-0.5, H - 0.5)); NaN is outside."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    with np.errstate(invalid="ignore"):
        return (x >= -0.5) & (x < width - 0.5) & (y >= -0.5) & (y < height - 0.5)
