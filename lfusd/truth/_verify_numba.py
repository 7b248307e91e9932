"""Compiled per-pixel arithmetic of :mod:`lfusd.truth.verify` (numba): the hit on its triangle in
float64 (ray-plane parameter, barycentric coordinates by the dot-product solve), the same point
carried to the other time and projected, and the mixed rule on corner rays: one pass per ray
instead of a dozen NumPy temporaries."""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def surface(o, d, mesh, tri, V, T, toff, depth, pos, normal, bary):  # pragma: no cover - compiled
    """Per ray i with mesh[i] >= 0: planar depth, hit point, unit normal facing the ray's origin and
    barycentric (b1, b2) on triangle tri[i] of mesh[i] (rows of T from toff[mesh]), in float64."""
    for i in range(mesh.size):
        m = mesh[i]
        if m < 0:
            continue
        k = toff[m] + tri[i]
        a, b, c = T[k, 0], T[k, 1], T[k, 2]
        e1x, e1y, e1z = V[b, 0] - V[a, 0], V[b, 1] - V[a, 1], V[b, 2] - V[a, 2]
        e2x, e2y, e2z = V[c, 0] - V[a, 0], V[c, 1] - V[a, 1], V[c, 2] - V[a, 2]
        nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
        ox, oy, oz = o[i, 0], o[i, 1], o[i, 2]
        dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
        dn = dx * nx + dy * ny + dz * nz
        t = ((V[a, 0] - ox) * nx + (V[a, 1] - oy) * ny + (V[a, 2] - oz) * nz) / dn
        px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
        wx, wy, wz = px - V[a, 0], py - V[a, 1], pz - V[a, 2]
        d00 = e1x * e1x + e1y * e1y + e1z * e1z
        d01 = e1x * e2x + e1y * e2y + e1z * e2z
        d11 = e2x * e2x + e2y * e2y + e2z * e2z
        d20 = wx * e1x + wy * e1y + wz * e1z
        d21 = wx * e2x + wy * e2y + wz * e2z
        den = d00 * d11 - d01 * d01
        depth[i] = t
        pos[i, 0], pos[i, 1], pos[i, 2] = px, py, pz
        bary[i, 0] = (d11 * d20 - d01 * d21) / den
        bary[i, 1] = (d00 * d21 - d01 * d20) / den
        ln = np.sqrt(nx * nx + ny * ny + nz * nz)
        s = -1.0 if dn > 0 else 1.0  # the side the camera sees
        normal[i, 0], normal[i, 1], normal[i, 2] = s * nx / ln, s * ny / ln, s * nz / ln


@njit(cache=True, error_model="numpy")
def carry(mesh, tri, bary, same, V1, T1, toff1, M, R2, C, pos1, valid, u1, v1, z1):  # pragma: no cover - compiled
    """Per ray whose mesh keeps its topology (same[mesh]): the point of the same barycentric
    coordinates on the same triangle at the other time, and its projection (u1, v1, planar depth
    z1) in the camera of centre C, M = K @ R and R2 its world-to-camera rotation's third row (as
    lfusd.camera.project: the centre subtracted first)."""
    for i in range(mesh.size):
        m = mesh[i]
        if m < 0 or not same[m]:
            continue
        k = toff1[m] + tri[i]
        b1, b2 = bary[i, 0], bary[i, 1]
        b0 = 1 - b1 - b2
        a, b, c = T1[k, 0], T1[k, 1], T1[k, 2]
        for j in range(3):
            pos1[i, j] = b0 * V1[a, j] + b1 * V1[b, j] + b2 * V1[c, j]
        valid[i] = True
        dx, dy, dz = pos1[i, 0] - C[0], pos1[i, 1] - C[1], pos1[i, 2] - C[2]
        x0 = dx * M[0, 0] + dy * M[0, 1] + dz * M[0, 2]
        x1 = dx * M[1, 0] + dy * M[1, 1] + dz * M[1, 2]
        x2 = dx * M[2, 0] + dy * M[2, 1] + dz * M[2, 2]
        u1[i], v1[i] = x0 / x2, x1 / x2
        z1[i] = dx * R2[0] + dy * R2[1] + dz * R2[2]

@njit(cache=True, error_model="numpy")
def mixed_decision(ident, depth, flow, use_flow, H, W, depth_rel, flow_px, out):  # pragma: no cover - compiled
    """verify._mixed_decision's rule per pixel (see there) on the (H+1) x (W+1) corner grid."""
    wc = W + 1
    for y in range(H):
        for x in range(W):
            c0 = y * wc + x
            cs = (c0, c0 + 1, c0 + wc, c0 + wc + 1)
            i0 = ident[c0]
            res = False
            for c in cs:
                if ident[c] != i0:
                    res = True
            if not res:
                lo, hi, fin = np.inf, -np.inf, True
                for c in cs:
                    z = depth[c]
                    if not np.isfinite(z):
                        fin = False
                    lo, hi = min(lo, z), max(hi, z)
                if fin and hi - lo > depth_rel * lo:
                    res = True
            if not res and use_flow and i0 >= 0:
                for a in range(4):
                    for b in range(a + 1, 4):
                        gx = flow[cs[a], 0] - flow[cs[b], 0]
                        gy = flow[cs[a], 1] - flow[cs[b], 1]
                        if np.sqrt(gx * gx + gy * gy) > flow_px:  # NaN (unknown motion) counts as none
                            res = True
            out[y * W + x] = res


@njit(cache=True, error_model="numpy")
def nearest_depth(V, T, M, C, R2, H, W, margin):  # pragma: no cover - compiled
    """(H, W): per pixel, the least camera depth of the triangles (rows of T into V) whose
    projection's bounding rectangle, grown by ``margin`` px, covers the pixel centre; inf where none
    does. A triangle reaching to or behind the camera covers every pixel at depth 0. M = K R, C the
    centre, R2 R's depth row: what may lie in front of a point seen through a pixel, conservatively."""
    out = np.full((H, W), np.inf)
    for f in range(T.shape[0]):
        umin, umax, vmin, vmax, zmin = np.inf, -np.inf, np.inf, -np.inf, np.inf
        behind = False
        for c in range(3):
            k = T[f, c]
            dx, dy, dz = V[k, 0] - C[0], V[k, 1] - C[1], V[k, 2] - C[2]
            z = R2[0] * dx + R2[1] * dy + R2[2] * dz
            if not z > 0:
                behind = True
                break
            hz = M[2, 0] * dx + M[2, 1] * dy + M[2, 2] * dz
            u = (M[0, 0] * dx + M[0, 1] * dy + M[0, 2] * dz) / hz
            v = (M[1, 0] * dx + M[1, 1] * dy + M[1, 2] * dz) / hz
            umin, umax, vmin, vmax, zmin = min(umin, u), max(umax, u), min(vmin, v), max(vmax, v), min(zmin, z)
        if behind:
            out[:, :] = 0.0
            return out
        j0 = max(int(np.ceil(max(umin - margin, -1.0))), 0)
        j1 = min(int(np.floor(min(umax + margin, W + 1.0))), W - 1)
        i0 = max(int(np.ceil(max(vmin - margin, -1.0))), 0)
        i1 = min(int(np.floor(min(vmax + margin, H + 1.0))), H - 1)
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                if zmin < out[i, j]:
                    out[i, j] = zmin
    return out


@njit(cache=True, error_model="numpy")
def object_sums(ok, obj, a, b, n_obj, sums, count, broken):  # pragma: no cover - compiled
    """Per object id (obj per pixel, pixels where ``ok``): the sum of a - b over its pixels per
    component (a, b: (N, C)), its pixel count, and whether any difference is not finite."""
    for i in range(ok.size):
        if not ok[i]:
            continue
        o = obj[i]
        if o < 0 or o >= n_obj:
            continue
        count[o] += 1
        for c in range(a.shape[1]):
            x = a[i, c] - b[i, c]
            if math.isfinite(x):
                sums[o, c] += x
            else:
                broken[o] = True


@njit(cache=True, error_model="numpy")
def label_stats(e, code, kind, n_labels, n_kinds, limit, rate, grouped):  # pragma: no cover - compiled
    """One pass over a key's per-pixel errors ``e`` (NaN: not compared) for verify's rows: per label
    (``code`` per pixel, 0 .. n_labels-1; row n_labels is every label together) the pixels compared,
    those over ``limit`` (over 0.5 when ``rate``), the first pixel of the greatest error and that
    error, the sum of the errors and the count per tie kind (``kind`` per pixel, 0 .. n_kinds-1).
    Unless ``rate``, ``grouped`` receives the compared errors ordered by label (raster order within
    one), a label's at its offset (the counts' running sum)."""
    rows = n_labels + 1
    count = np.zeros(rows, np.int64)
    over = np.zeros(rows, np.int64)
    worst = np.zeros(rows, np.int64)
    top = np.full(rows, -np.inf)
    total = np.zeros(rows)
    kinds = np.zeros((rows, n_kinds), np.int64)
    for i in range(e.size):
        x = e[i]
        if x != x:
            continue
        c = code[i]
        for r in (c, n_labels):
            count[r] += 1
            total[r] += x
            if (x > 0.5) if rate else (x > limit):
                over[r] += 1
            if count[r] == 1 or x > top[r]:
                top[r] = x
                worst[r] = i
            kinds[r, kind[i]] += 1
    if not rate:
        pos = np.zeros(n_labels, np.int64)
        for c in range(1, n_labels):
            pos[c] = pos[c - 1] + count[c - 1]
        for i in range(e.size):
            x = e[i]
            if x == x:
                grouped[pos[code[i]]] = x
                pos[code[i]] += 1
    return count, over, worst, top, total, kinds


@njit(cache=True, error_model="numpy")
def rays_through(u, v, A, C):  # pragma: no cover - compiled
    """The rays from the camera centre C through pixel coordinates (u, v): directions A (u, v, 1)
    (camera-frame z = 1, float64, (N, 3)) and the same rays as Open3D takes them ((N, 6) float32:
    origin, direction)."""
    n = u.size
    d = np.empty((n, 3))
    rays = np.empty((n, 6), np.float32)
    for i in range(n):
        for k in range(3):
            x = A[k, 0] * u[i] + A[k, 1] * v[i] + A[k, 2]
            d[i, k] = x
            rays[i, k] = C[k]
            rays[i, 3 + k] = x
    return d, rays
