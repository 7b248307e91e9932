"""Compiled derivation of :mod:`lfusd.truth.motion` (numba): one fused pass per pixel and direction.

Mirrors the NumPy reference (``lfusd.truth.motion._direction`` / ``_visibility_numpy``) test by test,
plus a fast path that is provably equivalent (see ``_point``); tests compare the two backends.

Kept apart so that ``lfusd.truth.motion`` imports without numba (it then uses the NumPy reference).
"""

from __future__ import annotations

import math
import os
from typing import NamedTuple

import numpy as np
from numba import config, njit, prange

if "NUMBA_THREADING_LAYER_PRIORITY" not in os.environ and "NUMBA_THREADING_LAYER" not in os.environ:
    # Some wheels beside us (open3d, bpy) bring an old TBB that numba refuses with a warning:
    # prefer OpenMP, then numba's own work queue.
    config.THREADING_LAYER_PRIORITY = ["omp", "workqueue", "tbb"]


@njit(cache=True, inline="always", error_model="numpy")
def _smooth(inst, inv, y0, x0, y1, x1, edge_rel):
    # Neighbours on one surface: same instance and no large inverse-depth jump.
    if inst[y0, x0] != inst[y1, x1]:
        return False
    a, b = inv[y0, x0], inv[y1, x1]
    return abs(b - a) <= edge_rel * min(a, b)


@njit(cache=True, inline="always", error_model="numpy")
def _slopes(img, c, inst, inv, yk, xk, axis, edge_rel):
    """Lower/upper one-sided slope of img[..., c] at (yk, xk) along axis (1 = x, 0 = y)."""
    h, w = inv.shape
    has_b = False
    has_f = False
    db = 0.0
    df = 0.0
    if axis == 1:
        if xk - 1 >= 0 and _smooth(inst, inv, yk, xk - 1, yk, xk, edge_rel):
            has_b = True
            db = img[yk, xk, c] - img[yk, xk - 1, c]
        if xk + 1 < w and _smooth(inst, inv, yk, xk, yk, xk + 1, edge_rel):
            has_f = True
            df = img[yk, xk + 1, c] - img[yk, xk, c]
    else:
        if yk - 1 >= 0 and _smooth(inst, inv, yk - 1, xk, yk, xk, edge_rel):
            has_b = True
            db = img[yk, xk, c] - img[yk - 1, xk, c]
        if yk + 1 < h and _smooth(inst, inv, yk, xk, yk + 1, xk, edge_rel):
            has_f = True
            df = img[yk + 1, xk, c] - img[yk, xk, c]
    if has_b and not has_f:
        df = db
    elif has_f and not has_b:
        db = df
    return min(db, df), max(db, df)


@njit(cache=True, inline="always", error_model="numpy")
def _extrapolate(img, c, inst, inv, yk, xk, dx, dy, edge_rel):
    v = img[yk, xk, c]
    lo = v
    hi = v
    glo, ghi = _slopes(img, c, inst, inv, yk, xk, 1, edge_rel)
    a, b = glo * dx, ghi * dx
    lo += min(a, b)
    hi += max(a, b)
    glo, ghi = _slopes(img, c, inst, inv, yk, xk, 0, edge_rel)
    a, b = glo * dy, ghi * dy
    lo += min(a, b)
    hi += max(a, b)
    return lo, hi


@njit(cache=True, inline="always", error_model="numpy")
def _point(xj, yj, flu, flv, ze, ex, me, inst_other, inv_other, inv3, back, fb_abs, fb_rel, depth_rel, edge_rel):
    """Occlusion tests of one point at (xj, yj) in the other frame: (visible, vector_ok, inv_pt)."""
    h, w = inv_other.shape
    inside = xj >= -0.5 and xj <= w - 0.5 and yj >= -0.5 and yj <= h - 0.5 and not (ze <= 0)
    xc = min(max(xj, -1.0), float(w))
    yc = min(max(yj, -1.0), float(h))
    x0 = min(max(int(math.floor(xc)), 0), max(w - 2, 0))
    y0 = min(max(int(math.floor(yc)), 0), max(h - 2, 0))
    inv_exp = 1.0 / ze if ex else math.nan
    slack = fb_abs + fb_rel * math.sqrt(flu * flu + flv * flv)
    # Fast path, exactly equivalent: with all four corners on the point's instance and the
    # point inside the cell, the bilinear interpolation lies within the envelopes, so a bilinear
    # value that passes a test means every corner passes it (all four agree).
    ax = xc - x0
    ay = yc - y0
    if ax >= 0 and ax <= 1 and ay >= 0 and ay <= 1:
        if inst_other[y0, x0] == me and inst_other[y0, x0 + 1] == me and inst_other[y0 + 1, x0] == me and inst_other[y0 + 1, x0 + 1] == me:
            w00, w01, w10, w11 = (1 - ax) * (1 - ay), ax * (1 - ay), (1 - ax) * ay, ax * ay
            bu = w00 * back[y0, x0, 0] + w01 * back[y0, x0 + 1, 0] + w10 * back[y0 + 1, x0, 0] + w11 * back[y0 + 1, x0 + 1, 0]
            bv = w00 * back[y0, x0, 1] + w01 * back[y0, x0 + 1, 1] + w10 * back[y0 + 1, x0, 1] + w11 * back[y0 + 1, x0 + 1, 1]
            ok = abs(bu + flu) <= slack and abs(bv + flv) <= slack
            if ok and ex:
                bi = w00 * inv_other[y0, x0] + w01 * inv_other[y0, x0 + 1] + w10 * inv_other[y0 + 1, x0] + w11 * inv_other[y0 + 1, x0 + 1]
                ok = abs(bi - inv_exp) <= depth_rel * inv_exp
            if ok:
                if ex:
                    return inside, False, inv_exp
                all_lo = math.inf
                all_hi = -math.inf
                for k in range(4):
                    xk = x0 + (k & 1)
                    yk = y0 + (k >> 1)
                    elo, ehi = _extrapolate(inv3, 0, inst_other, inv_other, yk, xk, xc - xk, yc - yk, edge_rel)
                    all_lo = min(all_lo, elo)
                    all_hi = max(all_hi, ehi)
                inv_vec = 0.5 * (all_lo + all_hi)
                return inside, inside and (all_hi - all_lo) <= depth_rel * inv_vec, inv_vec
    # Envelopes over the same-instance corners (inverse depth, backward flow u and v).
    e0lo = e1lo = e2lo = math.inf
    e0hi = e1hi = e2hi = -math.inf
    best_d = math.inf
    near_same = False
    near_inv = 0.0
    for k in range(4):
        xk = x0 + (k & 1)
        yk = y0 + (k >> 1)
        same = inst_other[yk, xk] == me
        d2 = (xc - xk) ** 2 + (yc - yk) ** 2
        if d2 < best_d:
            best_d = d2
            near_same = same
            near_inv = inv_other[yk, xk]
        if same:
            vi = inv_other[yk, xk]
            e0lo, e0hi = min(e0lo, vi), max(e0hi, vi)
            b0, b1 = back[yk, xk, 0], back[yk, xk, 1]
            e1lo, e1hi = min(e1lo, b0), max(e1hi, b0)
            e2lo, e2hi = min(e2lo, b1), max(e2hi, b1)
    n_agree = 0
    all_lo = math.inf
    all_hi = -math.inf
    for k in range(4):
        xk = x0 + (k & 1)
        yk = y0 + (k >> 1)
        dx = xc - xk
        dy = yc - yk
        elo, ehi = _extrapolate(inv3, 0, inst_other, inv_other, yk, xk, dx, dy, edge_rel)
        all_lo = min(all_lo, elo)
        all_hi = max(all_hi, ehi)
        if inst_other[yk, xk] != me:
            continue
        lo, hi = _extrapolate(back, 0, inst_other, inv_other, yk, xk, dx, dy, edge_rel)
        ok = -flu >= min(lo, e1lo) - slack and -flu <= max(hi, e1hi) + slack
        lo, hi = _extrapolate(back, 1, inst_other, inv_other, yk, xk, dx, dy, edge_rel)
        ok = ok and -flv >= min(lo, e2lo) - slack and -flv <= max(hi, e2hi) + slack
        if ex:
            tol = depth_rel * inv_exp
            ok = ok and inv_exp >= min(elo, e0lo) - tol and inv_exp <= max(ehi, e0hi) + tol
        if ok:
            n_agree += 1
    inv_vec = 0.5 * (all_lo + all_hi)
    ip = inv_exp if ex else inv_vec
    behind = near_inv < ip * (1 - depth_rel)
    vis = inside and (near_same or behind) and n_agree > 0
    sharp = n_agree == 4 and (all_hi - all_lo) <= depth_rel * inv_vec
    return vis, (not ex) and vis and sharp, ip


@njit(cache=True, parallel=True, error_model="numpy")
def inverse_depth_and_back(depth_o, vec_o, forward, bg):
    """Other frame: inverse depth (0 on background) and its vector pass pointing back to frame t."""
    h, w = depth_o.shape
    inv = np.zeros((h, w), np.float32)
    back = np.empty((h, w, 2), np.float32)
    for i in prange(h):
        for j in range(w):
            d = depth_o[i, j]
            if d > 0 and d < bg:
                inv[i, j] = 1.0 / d
            if forward:  # other = t+1: its backward flow (X, -Y)
                back[i, j, 0] = vec_o[i, j, 0]
                back[i, j, 1] = -vec_o[i, j, 1]
            else:  # other = t-1: its forward flow (-Z, W)
                back[i, j, 0] = -vec_o[i, j, 2]
                back[i, j, 1] = vec_o[i, j, 3]
    return inv, back


class Here(NamedTuple):
    """Frame t of the view: its raw passes (``position`` of shape (1, 1, 3) when absent)."""

    depth: np.ndarray  # (H,W) float32
    vector: np.ndarray  # (H,W,4) float32, Blender's raw vector pass
    position: np.ndarray  # (H,W,3) float32
    instance: np.ndarray  # (H,W) int32


class Other(NamedTuple):
    """What the kernel reads of the other frame (t+1 or t-1) for frame t's pixels."""

    position: np.ndarray  # (H,W,3) float32: frame t's AOV of the point's position there ((1,1,3) when absent)
    instance: np.ndarray  # (H,W) int32 of the other frame
    inv_depth: np.ndarray  # (H,W) float32 of the other frame (inverse_depth_and_back)
    back: np.ndarray  # (H,W,2) float32: the other frame's flow pointing back to t


class Cameras(NamedTuple):
    """A_* maps (u, v, 1) * z to a world offset from the camera centre C_*; M_o = K R_o (world
    offset -> homogeneous pixel) and R2_o its depth row, of the other frame's camera."""

    A_cur: np.ndarray
    C_cur: np.ndarray
    M_cur: np.ndarray
    M_o: np.ndarray
    R2_o: np.ndarray
    C_o: np.ndarray
    A_o: np.ndarray


class Settings(NamedTuple):
    """Switches and thresholds of one direction (see lfusd.truth.motion)."""

    has_pos: bool  # Here.position holds the position pass
    has_opos: bool  # Other.position holds the AOV (the exact route)
    forward: bool  # t+1 (else t-1)
    image_occlusion: bool  # run the image-space occlusion test (not needed where exact occlusion replaces it)
    fb: float  # f_px * baseline
    bg: float  # background depth
    fb_abs: float
    fb_rel: float
    depth_rel: float
    edge_rel: float


class Out(NamedTuple):
    """The arrays one direction writes (scene_flow and dchange only when forward)."""

    flow: np.ndarray
    scene_flow: np.ndarray
    dchange: np.ndarray
    valid: np.ndarray
    occl: np.ndarray


@njit(cache=True, parallel=True, error_model="numpy")
def direction(here, other, cams, s, out):
    """Fused per-pixel derivation of one direction (see lfusd.truth.motion's module docstring):
    :class:`Here`, :class:`Other`, :class:`Cameras`, :class:`Settings`, :class:`Out`.

    Writes flow (H,W,2), and valid / occl masks; when forward also scene_flow and dchange. With
    ``image_occlusion`` off, exact-route pixels skip the image-space test (occl stays False: the
    caller replaces it with ray-cast visibility)."""
    depth, vec, pos, inst = here
    opos, inst_o, inv_o, back_o = other
    A_cur, C_cur, M_cur, M_o, R2_o, C_o, A_o = cams
    has_pos, has_opos, forward, image_occlusion, fb, bg, fb_abs, fb_rel, depth_rel, edge_rel = s
    flow, scene_flow, dchange, valid, occl = out
    h, w = depth.shape
    inv3 = inv_o.reshape(inv_o.shape[0], inv_o.shape[1], 1)
    for i in prange(h):
        for j in range(w):
            z0 = depth[i, j]
            if not (z0 > 0 and z0 < bg):
                continue
            # Flow: the exact route where the other-frame position AOV is finite, else the vector pass.
            px = py = pz = 0.0
            ex = False
            ze = math.nan
            if forward:
                fu, fv = -vec[i, j, 2], vec[i, j, 3]
            else:
                fu, fv = vec[i, j, 0], -vec[i, j, 1]
            if has_opos:
                px, py, pz = opos[i, j, 0], opos[i, j, 1], opos[i, j, 2]
                if not (math.isfinite(px) and math.isfinite(py) and math.isfinite(pz)):
                    # Unknown (the mesh changed its topology): flagged invalid, never guessed.
                    flow[i, j, 0] = 0.0
                    flow[i, j, 1] = 0.0
                    valid[i, j] = False
                    occl[i, j] = False
                    continue
                ex = True
                dx, dy, dz = px - C_o[0], py - C_o[1], pz - C_o[2]
                hx = M_o[0, 0] * dx + M_o[0, 1] * dy + M_o[0, 2] * dz
                hy = M_o[1, 0] * dx + M_o[1, 1] * dy + M_o[1, 2] * dz
                hz = M_o[2, 0] * dx + M_o[2, 1] * dy + M_o[2, 2] * dz
                # From the point that was sampled (the position pass), not the pixel centre: on a
                # sliver triangle Blender's sample lands off the pixel's ray; a static point gets 0.
                u0, v0 = float(j), float(i)
                if has_pos and math.isfinite(pos[i, j, 0]) and math.isfinite(pos[i, j, 1]) and math.isfinite(pos[i, j, 2]):
                    ex0, ey0, ez0 = pos[i, j, 0] - C_cur[0], pos[i, j, 1] - C_cur[1], pos[i, j, 2] - C_cur[2]
                    gz = M_cur[2, 0] * ex0 + M_cur[2, 1] * ey0 + M_cur[2, 2] * ez0
                    u0 = (M_cur[0, 0] * ex0 + M_cur[0, 1] * ey0 + M_cur[0, 2] * ez0) / gz
                    v0 = (M_cur[1, 0] * ex0 + M_cur[1, 1] * ey0 + M_cur[1, 2] * ez0) / gz
                fu, fv = hx / hz - u0, hy / hz - v0
                ze = R2_o[0] * dx + R2_o[1] * dy + R2_o[2] * dz
            flow[i, j, 0] = fu
            flow[i, j, 1] = fv
            xj, yj = j + fu, i + fv
            if ex and not image_occlusion:
                vis, vok, ip = False, False, 1.0 / ze  # occlusion comes from the caller's ray casts
                occl[i, j] = False
            else:
                vis, vok, ip = _point(xj, yj, fu, fv, ze, ex, inst[i, j], inst_o, inv_o, inv3, back_o,
                                      fb_abs, fb_rel, depth_rel, edge_rel)
                occl[i, j] = not vis
            if not forward:
                valid[i, j] = True
                continue
            known = ex or vok
            valid[i, j] = known
            if not known:
                continue
            # Position at t: the position pass where finite, else the depth back-projected.
            if has_pos and math.isfinite(pos[i, j, 0]) and math.isfinite(pos[i, j, 1]) and math.isfinite(pos[i, j, 2]):
                p0x, p0y, p0z = pos[i, j, 0], pos[i, j, 1], pos[i, j, 2]
            else:
                p0x = C_cur[0] + (A_cur[0, 0] * j + A_cur[0, 1] * i + A_cur[0, 2]) * z0
                p0y = C_cur[1] + (A_cur[1, 0] * j + A_cur[1, 1] * i + A_cur[1, 2]) * z0
                p0z = C_cur[2] + (A_cur[2, 0] * j + A_cur[2, 1] * i + A_cur[2, 2]) * z0
            if ex:
                z1 = ze
            else:
                z1 = 1.0 / ip
                px = C_o[0] + (A_o[0, 0] * xj + A_o[0, 1] * yj + A_o[0, 2]) * z1
                py = C_o[1] + (A_o[1, 0] * xj + A_o[1, 1] * yj + A_o[1, 2]) * z1
                pz = C_o[2] + (A_o[2, 0] * xj + A_o[2, 1] * yj + A_o[2, 2]) * z1
            scene_flow[i, j, 0] = px - p0x
            scene_flow[i, j, 1] = py - p0y
            scene_flow[i, j, 2] = pz - p0z
            dchange[i, j] = fb / z1 - fb / z0


def kernels_cached() -> bool:
    """Whether numba's on-disk cache holds the kernels of this source (else their first call
    compiles them, which takes minutes): every entry point's cache index exists and was written
    for the source as it is now (numba reads an index of an edited source as empty)."""
    try:
        return all(bool(k._cache._cache_file._load_index())
                   for k in (direction, inverse_depth_and_back, segment_rays, pixel_rays, mixed_pixels))
    except AttributeError:  # another numba's internals: say nothing rather than guess
        return True


# --- Exact occlusion and the mixed footprint (lfusd.truth.visibility): rays built and hits compared
# here, one pass per pixel, instead of a dozen full-image NumPy temporaries.

@njit(cache=True, inline="always", error_model="numpy")
def _segment_end(points, k, M, C, R2, h, w):
    """Point k seen from C: (inside the h x w image and in front, its offset from C (float64),
    its pixel position u, v and camera depth z). M = K R, R2 = R's depth row."""
    dx = np.float64(points[k, 0]) - C[0]
    dy = np.float64(points[k, 1]) - C[1]
    dz = np.float64(points[k, 2]) - C[2]
    hz = M[2, 0] * dx + M[2, 1] * dy + M[2, 2] * dz
    u = (M[0, 0] * dx + M[0, 1] * dy + M[0, 2] * dz) / hz
    v = (M[1, 0] * dx + M[1, 1] * dy + M[1, 2] * dz) / hz
    z = R2[0] * dx + R2[1] * dy + R2[2] * dz
    inside = math.isfinite(u) and math.isfinite(v) and z > 0 and u >= -0.5 and u <= w - 0.5 and v >= -0.5 and v <= h - 0.5
    return inside, dx, dy, dz, u, v, z


@njit(cache=True, error_model="numpy")
def segment_rays(points, valid, M, C, R2, h, w):
    """Rays (m, 6) float32 from the camera centre ``C`` to each point (N, 3) with ``valid`` that
    projects inside the h x w image in front of the camera (M = K R, R2 = R's depth row, float64),
    one after the other, and the index of each ray's point (m,): the rays Embree needs, in one pass,
    without a mask and a compacting copy. A ray's parameter is 1 at its point."""
    n = points.shape[0]
    rays = np.empty((n, 6), np.float32)
    index = np.empty(n, np.int64)
    m = 0
    for k in range(n):
        if not valid[k]:
            continue
        inside, dx, dy, dz, u, v, z = _segment_end(points, k, M, C, R2, h, w)
        if inside:
            rays[m, 0], rays[m, 1], rays[m, 2] = C[0], C[1], C[2]
            rays[m, 3], rays[m, 4], rays[m, 5] = dx, dy, dz
            index[m] = k
            m += 1
    return rays[:m], index[:m]


@njit(cache=True, error_model="numpy")
def pixel_rays(A, C, du, dv, h, w):
    """Rays (H*W, 6) float32 from the camera centre ``C`` through (u + du, v + dv) of every pixel,
    directions A (u, v, 1) scaled to camera-frame z = 1 (a ray parameter is planar depth)."""
    rays = np.empty((h * w, 6), np.float32)
    for i in prange(h):
        for j in range(w):
            k = i * w + j
            x, y = j + du, i + dv
            rays[k, 0], rays[k, 1], rays[k, 2] = C[0], C[1], C[2]
            rays[k, 3] = A[0, 0] * x + A[0, 1] * y + A[0, 2]
            rays[k, 4] = A[1, 0] * x + A[1, 1] * y + A[1, 2]
            rays[k, 5] = A[2, 0] * x + A[2, 1] * y + A[2, 2]
    return rays


@njit(cache=True, inline="always", error_model="numpy")
def _carried_flow(t, tri, uv, k, i, j, du, dv, vn, tn, M, C):
    """Forward flow (u, v) of the hit of one sub-pixel ray carried to t+1 on its triangle (same
    barycentric coordinates), projected with M = K R, C of the camera at t+1; NaN for a miss."""
    if not math.isfinite(t[k]):
        return math.nan, math.nan
    f = tri[k]
    a, b, c = tn[f, 0], tn[f, 1], tn[f, 2]
    b1, b2 = np.float64(uv[k, 0]), np.float64(uv[k, 1])
    px = vn[a, 0] + b1 * (vn[b, 0] - vn[a, 0]) + b2 * (vn[c, 0] - vn[a, 0]) - C[0]
    py = vn[a, 1] + b1 * (vn[b, 1] - vn[a, 1]) + b2 * (vn[c, 1] - vn[a, 1]) - C[1]
    pz = vn[a, 2] + b1 * (vn[b, 2] - vn[a, 2]) + b2 * (vn[c, 2] - vn[a, 2]) - C[2]
    hz = M[2, 0] * px + M[2, 1] * py + M[2, 2] * pz
    return (M[0, 0] * px + M[0, 1] * py + M[0, 2] * pz) / hz - (j + du), (M[1, 0] * px + M[1, 1] * py + M[1, 2] * pz) / hz - (i + dv)


@njit(cache=True, error_model="numpy")
def mixed_pixels(t, tri, uv, tri_instance, carry, vertices_next, triangles_next, M_next, C_next, h, w, depth_rel, flow_px):
    """The mixed mask (H, W) from the hits of the rays through the pixel corners: t, tri, uv over the
    (H+1) x (W+1) corner grid ((H+1)(W+1),), (.,), (., 2), as Open3D's cast_rays gives them (t inf
    where missed); corner (i, j) lies at (u, v) = (j - 1/2, i - 1/2). A pixel's four corners differ
    in instance (tri_instance per triangle; -1 for a miss), in depth by more than ``depth_rel``, or
    (``carry``) in forward flow by more than ``flow_px``, each hit carried to t+1
    (:func:`_carried_flow`). Each corner is carried once and serves its four pixels. One thread: the
    derivation runs in processes of its own, and a loop this light costs more CPU in parallel."""
    wc = w + 1
    nc = t.shape[0]
    ident = np.empty(nc, np.int64)
    fu = np.full(nc, np.nan)
    fv = np.full(nc, np.nan)
    for k in range(nc):
        hit = math.isfinite(t[k])
        ident[k] = tri_instance[tri[k]] if hit else -1
        if carry and hit:
            fu[k], fv[k] = _carried_flow(t, tri, uv, k, k // wc, k % wc, -0.5, -0.5, vertices_next, triangles_next, M_next, C_next)
    mixed = np.zeros((h, w), np.bool_)
    limit = flow_px * flow_px
    for i in range(h):
        for j in range(w):
            a = i * wc + j
            corners = (a, a + 1, a + wc, a + wc + 1)
            i0 = ident[a]
            if ident[a + 1] != i0 or ident[a + wc] != i0 or ident[a + wc + 1] != i0:
                mixed[i, j] = True
                continue
            lo = min(min(t[a], t[a + 1]), min(t[a + wc], t[a + wc + 1]))
            hi = max(max(t[a], t[a + 1]), max(t[a + wc], t[a + wc + 1]))
            if math.isfinite(lo) and hi - lo > depth_rel * lo:
                mixed[i, j] = True
                continue
            if not carry or i0 == -1:
                continue
            for x in range(4):
                for y in range(x + 1, 4):
                    du, dv = fu[corners[x]] - fu[corners[y]], fv[corners[x]] - fv[corners[y]]
                    if du * du + dv * dv > limit:  # False when either is NaN
                        mixed[i, j] = True
    return mixed


@njit(cache=True, error_model="numpy")
def depth_map(vertices, triangles, M, C, R2, h, w, margin_px, depth_rel):
    """(h, w) float32: per pixel, the least camera depth (times 1 - ``depth_rel``) of the triangles
    whose projection's bounding rectangle, grown by ``margin_px``, covers the pixel; inf where none
    does (a conservative z-buffer of the nearest surface). A triangle wholly behind the camera
    covers nothing; one that reaches behind it covers every pixel at depth 0. M = K R, C the
    centre, R2 R's depth row (float64)."""
    zmap = np.full((h, w), np.inf, np.float32)
    for f in range(triangles.shape[0]):
        umin, vmin, umax, vmax, zmin = np.inf, np.inf, -np.inf, -np.inf, np.inf
        behind = 0
        for c in range(3):
            q = triangles[f, c]
            x = np.float64(vertices[q, 0]) - C[0]
            y = np.float64(vertices[q, 1]) - C[1]
            z = np.float64(vertices[q, 2]) - C[2]
            hz = M[2, 0] * x + M[2, 1] * y + M[2, 2] * z
            zc = R2[0] * x + R2[1] * y + R2[2] * z
            if not (hz > 0 and zc > 0):
                behind += 1
                continue
            u = (M[0, 0] * x + M[0, 1] * y + M[0, 2] * z) / hz
            v = (M[1, 0] * x + M[1, 1] * y + M[1, 2] * z) / hz
            umin, umax, vmin, vmax = min(umin, u), max(umax, u), min(vmin, v), max(vmax, v)
            zmin = min(zmin, zc)
        if behind == 3:
            continue
        if behind > 0 or not (math.isfinite(umin) and math.isfinite(umax) and math.isfinite(vmin) and math.isfinite(vmax)):
            umin, vmin, umax, vmax, zmin = -np.inf, -np.inf, np.inf, np.inf, 0.0
        # np.floor keeps a float: math.floor's int of an infinite bound is undefined
        j0 = max(0.0, np.floor(umin - margin_px))
        j1 = min(w - 1.0, np.ceil(umax + margin_px))
        i0 = max(0.0, np.floor(vmin - margin_px))
        i1 = min(h - 1.0, np.ceil(vmax + margin_px))
        if j0 > j1 or i0 > i1:
            continue
        zz = np.float32(zmin * (1.0 - depth_rel))
        for i in range(int(i0), int(i1) + 1):
            for j in range(int(j0), int(j1) + 1):
                if zz < zmap[i, j]:
                    zmap[i, j] = zz
    return zmap


@njit(cache=True, error_model="numpy")
def segment_parts(points, bits, valid, M, C, R2, h, w, ends, filled, held, zmap, static):
    """:func:`segment_rays` for a scene in two parts (lfusd.truth.visibility.Parts), in one pass.

    For each valid point (N, 3) float32 that projects inside the h x w image in front of the
    camera: its index (m,), and whether the static part hides it where a memo holds the answer
    (``ends``: uint32 bits of the end point each pixel's answer ``held`` was cast for, where
    ``filled``; ``bits`` are ``points`` as uint32), else False: hidden (m,). Then the rays the
    parts still need: to the static part (``static``) those not known, to the dynamic part those
    whose end lies at or beyond the least depth ``zmap`` (:func:`depth_map`; (0, 0) for no dynamic
    part) has at their pixel; each as rays (k, 6) float32 and their positions in ``index`` (k,).
    The memo's slots of the static rays take their end points (and :func:`remember_answers` their
    answers, once cast)."""
    n = points.shape[0]
    index = np.empty(n, np.int64)
    hidden = np.zeros(n, np.bool_)
    s_rays = np.empty((n, 6), np.float32)
    s_pos = np.empty(n, np.int64)
    d_rays = np.empty((n, 6), np.float32)
    d_pos = np.empty(n, np.int64)
    dynamic = zmap.shape[0] > 0
    m = 0
    ns = 0
    nd = 0
    for k in range(n):
        if not valid[k]:
            continue
        inside, dx, dy, dz, u, v, z = _segment_end(points, k, M, C, R2, h, w)
        if not inside:
            continue
        index[m] = k
        if static:
            if filled[k] and bits[k, 0] == ends[k, 0] and bits[k, 1] == ends[k, 1] and bits[k, 2] == ends[k, 2]:
                hidden[m] = held[k]
            else:
                # the memo's slot now holds this end point; its answer comes after the cast
                ends[k, 0], ends[k, 1], ends[k, 2] = bits[k, 0], bits[k, 1], bits[k, 2]
                filled[k] = True
                s_rays[ns, 0], s_rays[ns, 1], s_rays[ns, 2] = C[0], C[1], C[2]
                s_rays[ns, 3], s_rays[ns, 4], s_rays[ns, 5] = dx, dy, dz
                s_pos[ns] = m
                ns += 1
        if dynamic:
            i = int(min(max(np.floor(v + 0.5), 0.0), h - 1.0))
            j = int(min(max(np.floor(u + 0.5), 0.0), w - 1.0))
            if z >= zmap[i, j]:
                d_rays[nd, 0], d_rays[nd, 1], d_rays[nd, 2] = C[0], C[1], C[2]
                d_rays[nd, 3], d_rays[nd, 4], d_rays[nd, 5] = dx, dy, dz
                d_pos[nd] = m
                nd += 1
        m += 1
    return index[:m], hidden[:m], s_rays[:ns], s_pos[:ns], d_rays[:nd], d_pos[:nd]


@njit(cache=True, error_model="numpy")
def remember_answers(index, s_pos, fresh, hidden, held):
    """The static part's answers ``fresh`` for the rays at ``s_pos`` (of :func:`segment_parts`):
    into ``hidden`` (per ray) and the memo's ``held`` (per pixel)."""
    for r in range(s_pos.shape[0]):
        hidden[s_pos[r]] = fresh[r]
        held[index[s_pos[r]]] = fresh[r]


@njit(cache=True, error_model="numpy")
def remember_visible(index, hidden, bits, ends, filled, held):
    """Fill a memo from a cast against the whole scene: a segment nothing hides is hidden by no
    static triangle either, so its pixel's slot takes its end point and the answer False; a hidden
    one's slot stays empty (which part hid it is not known)."""
    for r in range(index.shape[0]):
        if not hidden[r]:
            k = index[r]
            ends[k, 0], ends[k, 1], ends[k, 2] = bits[k, 0], bits[k, 1], bits[k, 2]
            filled[k] = True
            held[k] = False


@njit(cache=True, error_model="numpy")
def corner_rays(A, C, corners, w):
    """The rays of :func:`pixel_rays` (du = dv = -1/2, a grid ``w`` wide) for the listed corners
    only (k = i * w + j), bit for bit the same."""
    m = corners.shape[0]
    rays = np.empty((m, 6), np.float32)
    for r in range(m):
        i, j = divmod(corners[r], w)
        x, y = j + -0.5, i + -0.5
        rays[r, 0], rays[r, 1], rays[r, 2] = C[0], C[1], C[2]
        rays[r, 3] = A[0, 0] * x + A[0, 1] * y + A[0, 2]
        rays[r, 4] = A[1, 0] * x + A[1, 1] * y + A[1, 2]
        rays[r, 5] = A[2, 0] * x + A[2, 1] * y + A[2, 2]
    return rays
