"""Compiled kernels of the classical baselines (numba, one thread): the plane sweep's cost volume
(lfusd.evaluation.baselines) and the ray flow's per-ray normal equations, cubic-spline sampling and
preconditioned conjugate gradients (lfusd.evaluation.rayflow).

Each kernel computes what the NumPy / PyTorch / SciPy expression it replaces computes, in float64:
the same samples (bilinear with the border clamped, scipy's cubic B-spline with mirrored indices),
the same sums, the same iteration (tests/evaluation/test_baselines_compiled.py compares them with
copies of the code they replaced).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def _axis_taps(n, shift):
    """Bilinear taps along one axis of ``n`` pixels sampled at x - shift, the coordinate clamped to
    [0, n-1] (grid_sample's border padding, align_corners): (lower index, upper index, weight of upper)."""
    i0 = np.empty(n, np.int64)
    i1 = np.empty(n, np.int64)
    a = np.empty(n, np.float64)
    top = max(n - 2, 0)
    for x in range(n):
        c = min(max(x - shift, 0.0), n - 1.0)
        k = min(int(math.floor(c)), top)
        i0[x] = k
        i1[x] = min(k + 1, n - 1)
        a[x] = c - k
    return i0, i1, a


@njit(cache=True, error_model="numpy")
def sweep_costs(imgs, rel, ds, window):
    """Cost volume (P,H,W) float64 of a plane sweep: for every candidate disparity ds[p], the variance
    over the V views (population variance, summed over channels) of (V,H,W,C) ``imgs`` warped to the
    reference by (x - d rel_x, y - d rel_y), averaged over the ``window`` x ``window`` box around each
    pixel clipped to the image (avg_pool2d with count_include_pad=False)."""
    nv, h, w, nc = imgs.shape
    npl = ds.shape[0]
    pad = window // 2
    out = np.empty((npl, h, w))
    raw = np.empty((h, w))
    integ = np.zeros((h + 1, w + 1))
    vals = np.empty((nv, nc))
    xi0 = np.empty((nv, w), np.int64)
    xi1 = np.empty((nv, w), np.int64)
    xa = np.empty((nv, w))
    yi0 = np.empty((nv, h), np.int64)
    yi1 = np.empty((nv, h), np.int64)
    yb = np.empty((nv, h))
    for p in range(npl):
        d = ds[p]
        for s in range(nv):
            xi0[s], xi1[s], xa[s] = _axis_taps(w, d * rel[s, 0])
            yi0[s], yi1[s], yb[s] = _axis_taps(h, d * rel[s, 1])
        for y in range(h):
            for x in range(w):
                for s in range(nv):
                    a = xa[s, x]
                    b = yb[s, y]
                    r0 = yi0[s, y]
                    r1 = yi1[s, y]
                    c0 = xi0[s, x]
                    c1 = xi1[s, x]
                    for c in range(nc):
                        vals[s, c] = (1 - b) * ((1 - a) * imgs[s, r0, c0, c] + a * imgs[s, r0, c1, c]) + b * ((1 - a) * imgs[s, r1, c0, c] + a * imgs[s, r1, c1, c])
                tot = 0.0
                for c in range(nc):
                    m = 0.0
                    for s in range(nv):
                        m += vals[s, c]
                    m /= nv
                    q = 0.0
                    for s in range(nv):
                        e = vals[s, c] - m
                        q += e * e
                    tot += q / nv
                raw[y, x] = tot
        # window sums from an integral image
        for y in range(h):
            acc = 0.0
            for x in range(w):
                acc += raw[y, x]
                integ[y + 1, x + 1] = integ[y, x + 1] + acc
        for y in range(h):
            ya, yz = max(y - pad, 0), min(y + pad + 1, h)
            for x in range(w):
                xa_, xz = max(x - pad, 0), min(x + pad + 1, w)
                ssum = integ[yz, xz] - integ[ya, xz] - integ[yz, xa_] + integ[ya, xa_]
                out[p, y, x] = ssum / ((yz - ya) * (xz - xa_))
    return out


# ---- ray flow ------------------------------------------------------------------------------------


@njit(cache=True, inline="always", error_model="numpy")
def _mirror(i, n):
    """scipy.ndimage's 'mirror' extension of an index (d c b | a b c d | c b a)."""
    if n == 1:
        return 0
    period = 2 * n - 2
    i = abs(i) % period
    return period - i if i >= n else i


@njit(cache=True, inline="always", error_model="numpy")
def _cubic_taps(x, n, idx, wt):
    """The four cubic B-spline taps (indices, weights) at coordinate x of an axis of ``n`` samples,
    as scipy.ndimage.map_coordinates(order=3, mode='mirror') takes them."""
    f = math.floor(x)
    t = x - f
    s = 1.0 - t
    wt[0] = s * s * s / 6.0
    wt[1] = (4.0 - 6.0 * t * t + 3.0 * t * t * t) / 6.0
    wt[2] = (4.0 - 6.0 * s * s + 3.0 * s * s * s) / 6.0
    wt[3] = t * t * t / 6.0
    k = int(f) - 1
    for j in range(4):
        idx[j] = _mirror(k + j, n)


@njit(cache=True, error_model="numpy")
def cubic_sample(coef, us, vs):
    """Cubic-spline samples (H',W',C) of the image whose B-spline coefficients are (H,W,C) ``coef``
    at pixel coordinates (us, vs), each clamped to the image (rayflow._sample_cubic)."""
    h, w, nc = coef.shape
    out = np.empty(us.shape + (nc,))
    ix = np.empty(4, np.int64)
    iy = np.empty(4, np.int64)
    wx = np.empty(4)
    wy = np.empty(4)
    for y in range(us.shape[0]):
        for x in range(us.shape[1]):
            _cubic_taps(min(max(us[y, x], 0.0), w - 1.0), w, ix, wx)
            _cubic_taps(min(max(vs[y, x], 0.0), h - 1.0), h, iy, wy)
            for c in range(nc):
                acc = 0.0
                for j in range(4):
                    row = 0.0
                    for i in range(4):
                        row += wx[i] * coef[iy[j], ix[i], c]
                    acc += wy[j] * row
                out[y, x, c] = acc
    return out


@njit(cache=True, error_model="numpy")
def ray_normal_equations(S1, G1, L0, in0, rel, X, Y, Z, V, fx, fy, cx, cy, robust):
    """Per pixel, the robustly weighted normal equations (A (H,W,3,3), b (H,W,3)) of the ray flow
    equation L_X V_X + L_Y V_Y + L_Z V_Z + L_t = 0 over the rays of every view s and channel, linearised
    at the current motion V (H,W,3) (rayflow._level_step: the moved point's ray lands at (us, vs) in view
    s at t+1; L_t is the spline sample ``S1`` there minus the reference ray ``L0`` at t; the angular
    gradients are the bilinear sample of the image gradients ``G1`` (d/du of each channel, then d/dv)
    times f/Z; Cauchy weight 1 / (1 + (L_t / robust)^2), zero where either ray leaves its image)."""
    nv, h, w, nc = S1.shape
    A = np.zeros((h, w, 3, 3))
    b = np.zeros((h, w, 3))
    ix = np.empty(4, np.int64)
    iy = np.empty(4, np.int64)
    wx = np.empty(4)
    wy = np.empty(4)
    top_u, top_v = max(w - 2, 0), max(h - 2, 0)
    for y in range(h):
        for x in range(w):
            zp = max(Z[y, x] + V[y, x, 2], 1e-3 * Z[y, x])
            px = X[y, x] + V[y, x, 0]
            py = Y[y, x] + V[y, x, 1]
            a00 = a01 = a02 = a11 = a12 = a22 = 0.0
            b0 = b1 = b2 = 0.0
            for s in range(nv):
                us = fx * (px - rel[s, 0]) / zp + cx
                vs = fy * (py - rel[s, 1]) / zp + cy
                inside = (us >= 0) and (us <= w - 1) and (vs >= 0) and (vs <= h - 1) and in0[s, y, x]
                uc = min(max(us, 0.0), w - 1.0)
                vc = min(max(vs, 0.0), h - 1.0)
                _cubic_taps(uc, w, ix, wx)
                _cubic_taps(vc, h, iy, wy)
                u0 = min(int(math.floor(uc)), top_u)
                v0 = min(int(math.floor(vc)), top_v)
                ga, gb = uc - u0, vc - v0
                u1, v1 = min(u0 + 1, w - 1), min(v0 + 1, h - 1)
                xs = (us - cx) / fx
                ys = (vs - cy) / fy
                for c in range(nc):
                    l1 = 0.0
                    for j in range(4):
                        row = 0.0
                        for i in range(4):
                            row += wx[i] * S1[s, iy[j], ix[i], c]
                        l1 += wy[j] * row
                    lt = l1 - L0[s, y, x, c]
                    gu = (1 - gb) * ((1 - ga) * G1[s, v0, u0, c] + ga * G1[s, v0, u1, c]) + gb * ((1 - ga) * G1[s, v1, u0, c] + ga * G1[s, v1, u1, c])
                    k = nc + c
                    gv = (1 - gb) * ((1 - ga) * G1[s, v0, u0, k] + ga * G1[s, v0, u1, k]) + gb * ((1 - ga) * G1[s, v1, u0, k] + ga * G1[s, v1, u1, k])
                    jx = fx / zp * gu
                    jy = fy / zp * gv
                    jz = -xs * jx - ys * jy
                    r = lt / robust
                    wgt = (1.0 if inside else 0.0) / (1.0 + r * r)
                    a00 += wgt * jx * jx
                    a01 += wgt * jx * jy
                    a02 += wgt * jx * jz
                    a11 += wgt * jy * jy
                    a12 += wgt * jy * jz
                    a22 += wgt * jz * jz
                    b0 += wgt * jx * lt
                    b1 += wgt * jy * lt
                    b2 += wgt * jz * lt
            A[y, x, 0, 0] = a00
            A[y, x, 0, 1] = A[y, x, 1, 0] = a01
            A[y, x, 0, 2] = A[y, x, 2, 0] = a02
            A[y, x, 1, 1] = a11
            A[y, x, 1, 2] = A[y, x, 2, 1] = a12
            A[y, x, 2, 2] = a22
            b[y, x, 0] = b0
            b[y, x, 1] = b1
            b[y, x, 2] = b2
    return A, b


@njit(cache=True, inline="always", error_model="numpy")
def _inv3(m, out):
    """out = m^-1 of a 3x3 matrix (the adjugate over the determinant)."""
    c00 = m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1]
    c01 = m[1, 2] * m[2, 0] - m[1, 0] * m[2, 2]
    c02 = m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0]
    det = m[0, 0] * c00 + m[0, 1] * c01 + m[0, 2] * c02
    out[0, 0] = c00 / det
    out[1, 0] = c01 / det
    out[2, 0] = c02 / det
    out[0, 1] = (m[0, 2] * m[2, 1] - m[0, 1] * m[2, 2]) / det
    out[1, 1] = (m[0, 0] * m[2, 2] - m[0, 2] * m[2, 0]) / det
    out[2, 1] = (m[0, 1] * m[2, 0] - m[0, 0] * m[2, 1]) / det
    out[0, 2] = (m[0, 1] * m[1, 2] - m[0, 2] * m[1, 1]) / det
    out[1, 2] = (m[0, 2] * m[1, 0] - m[0, 0] * m[1, 2]) / det
    out[2, 2] = (m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]) / det


@njit(cache=True, error_model="numpy")
def solve3(A, rhs, eps):
    """x (H,W,3) with (A + eps I) x = rhs per pixel, by Gaussian elimination with partial pivoting
    (LAPACK's gesv, which np.linalg.solve calls per matrix)."""
    h, w = rhs.shape[:2]
    out = np.empty((h, w, 3))
    m = np.empty((3, 4))
    for y in range(h):
        for x in range(w):
            for i in range(3):
                for j in range(3):
                    m[i, j] = A[y, x, i, j] + (eps[y, x] if i == j else 0.0)
                m[i, 3] = rhs[y, x, i]
            for col in range(3):
                piv = col
                for i in range(col + 1, 3):
                    if abs(m[i, col]) > abs(m[piv, col]):
                        piv = i
                if piv != col:
                    for j in range(4):
                        m[col, j], m[piv, j] = m[piv, j], m[col, j]
                for i in range(col + 1, 3):
                    f = m[i, col] / m[col, col]
                    for j in range(col, 4):
                        m[i, j] -= f * m[col, j]
            for i in range(2, -1, -1):
                acc = m[i, 3]
                for j in range(i + 1, 3):
                    acc -= m[i, j] * out[y, x, j]
                out[y, x, i] = acc / m[i, i]
    return out


@njit(cache=True, error_model="numpy")
def _smooth_apply(x, wr, wd, lam, out):
    """out += lam (L kron I3) x for the 4-neighbour graph Laplacian L with right / down edge weights."""
    h, w = wd.shape[0] + 1, wr.shape[1] + 1
    for y in range(h):
        for xx in range(w):
            p = y * w + xx
            for nb in range(4):
                if nb == 0:
                    if xx + 1 >= w:
                        continue
                    q, wt = p + 1, wr[y, xx]
                elif nb == 1:
                    if xx == 0:
                        continue
                    q, wt = p - 1, wr[y, xx - 1]
                elif nb == 2:
                    if y + 1 >= h:
                        continue
                    q, wt = p + w, wd[y, xx]
                else:
                    if y == 0:
                        continue
                    q, wt = p - w, wd[y - 1, xx]
                for k in range(3):
                    out[3 * p + k] += lam * wt * (x[3 * p + k] - x[3 * q + k])


@njit(cache=True, error_model="numpy")
def smooth_apply(x, wr, wd, lam):
    """lam (L kron I3) x (rayflow._smoothness's Laplacian, matrix-free)."""
    out = np.zeros_like(x)
    _smooth_apply(x, wr, wd, lam, out)
    return out


@njit(cache=True, error_model="numpy")
def _dot(a, b):
    acc = 0.0
    for i in range(a.shape[0]):
        acc += a[i] * b[i]
    return acc


@njit(cache=True, error_model="numpy")
def block_cg(A, wr, wd, lam, eps, rhs, rtol, maxiter):
    """Solve (blockdiag(A) + lam (L kron I3) + eps I) x = rhs by conjugate gradients preconditioned
    with each pixel's 3x3 diagonal block inverted, from x = 0, stopping when |r| < rtol |rhs| or after
    ``maxiter`` iterations: scipy.sparse.linalg.cg's iteration, matrix-free. A: (N,3,3), N = H W."""
    n = A.shape[0]
    h, w = wd.shape[0] + 1, wr.shape[1] + 1
    deg = np.zeros(n)
    for y in range(h):
        for xx in range(w):
            if xx + 1 < w:
                deg[y * w + xx] += wr[y, xx]
                deg[y * w + xx + 1] += wr[y, xx]
            if y + 1 < h:
                deg[y * w + xx] += wd[y, xx]
                deg[(y + 1) * w + xx] += wd[y, xx]
    pinv = np.empty((n, 3, 3))
    m = np.empty((3, 3))
    for i in range(n):
        for r in range(3):
            for c in range(3):
                m[r, c] = A[i, r, c] + ((lam * deg[i] + eps) if r == c else 0.0)
        _inv3(m, pinv[i])
    x = np.zeros(3 * n)
    r = rhs.copy()
    bnrm = math.sqrt(_dot(rhs, rhs))
    if bnrm == 0.0:
        return x
    atol = rtol * bnrm
    z = np.empty(3 * n)
    p = np.empty(3 * n)
    q = np.empty(3 * n)
    rho_prev = 1.0
    for it in range(maxiter):
        if math.sqrt(_dot(r, r)) < atol:
            break
        for i in range(n):
            for k in range(3):
                z[3 * i + k] = pinv[i, k, 0] * r[3 * i] + pinv[i, k, 1] * r[3 * i + 1] + pinv[i, k, 2] * r[3 * i + 2]
        rho = _dot(r, z)
        if it > 0:
            beta = rho / rho_prev
            for i in range(3 * n):
                p[i] = p[i] * beta + z[i]
        else:
            p[:] = z
        for i in range(n):
            for k in range(3):
                q[3 * i + k] = A[i, k, 0] * p[3 * i] + A[i, k, 1] * p[3 * i + 1] + A[i, k, 2] * p[3 * i + 2] + eps * p[3 * i + k]
        _smooth_apply(p, wr, wd, lam, q)
        alpha = rho / _dot(p, q)
        for i in range(3 * n):
            x[i] += alpha * p[i]
            r[i] -= alpha * q[i]
        rho_prev = rho
    return x
