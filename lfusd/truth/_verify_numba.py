"""Compiled per-pixel arithmetic of :mod:`lfusd.truth.verify` (numba): the hit on its triangle in
float64 (ray-plane parameter, barycentric coordinates by the dot-product solve), the same point
carried to the other time and projected, and the mixed rule on corner rays: one pass per ray
instead of a dozen NumPy temporaries."""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def _hit(m, k0, ox, oy, oz, dx, dy, dz, V, T, toff):  # pragma: no cover - compiled
    """The ray from (ox, oy, oz) along (dx, dy, dz) on triangle k0 of mesh m (row toff[m] + k0 of T), in float64:
    (ray parameter t, hit point, barycentric b1, b2, unit normal facing the origin)."""
    k = toff[m] + k0
    a, b, c = T[k, 0], T[k, 1], T[k, 2]
    e1x, e1y, e1z = V[b, 0] - V[a, 0], V[b, 1] - V[a, 1], V[b, 2] - V[a, 2]
    e2x, e2y, e2z = V[c, 0] - V[a, 0], V[c, 1] - V[a, 1], V[c, 2] - V[a, 2]
    nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
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
    b1 = (d11 * d20 - d01 * d21) / den
    b2 = (d00 * d21 - d01 * d20) / den
    ln = np.sqrt(nx * nx + ny * ny + nz * nz)
    s = -1.0 if dn > 0 else 1.0  # the side the camera sees
    return t, px, py, pz, b1, b2, s * nx / ln, s * ny / ln, s * nz / ln


@njit(cache=True, error_model="numpy")
def _carry(m, k0, b1, b2, V1, T1, toff1, M, R2, C):  # pragma: no cover - compiled
    """The point of barycentric (b1, b2) on triangle k0 of mesh m at the other time, and its projection
    (u1, v1, planar depth z1) in the camera of centre C, M = K @ R, R2 its world-to-camera rotation's third
    row (as lfusd.camera.project: the centre subtracted first)."""
    k = toff1[m] + k0
    b0 = 1 - b1 - b2
    a, b, c = T1[k, 0], T1[k, 1], T1[k, 2]
    qx = b0 * V1[a, 0] + b1 * V1[b, 0] + b2 * V1[c, 0]
    qy = b0 * V1[a, 1] + b1 * V1[b, 1] + b2 * V1[c, 1]
    qz = b0 * V1[a, 2] + b1 * V1[b, 2] + b2 * V1[c, 2]
    dx, dy, dz = qx - C[0], qy - C[1], qz - C[2]
    x0 = dx * M[0, 0] + dy * M[0, 1] + dz * M[0, 2]
    x1 = dx * M[1, 0] + dy * M[1, 1] + dz * M[1, 2]
    x2 = dx * M[2, 0] + dy * M[2, 1] + dz * M[2, 2]
    return qx, qy, qz, x0 / x2, x1 / x2, dx * R2[0] + dy * R2[1] + dz * R2[2]


@njit(cache=True, error_model="numpy")
def resolve_hits(t, gid, prim, lut, mesh, tri):  # pragma: no cover - compiled
    """Open3D's cast answer (t_hit float32, geometry and primitive ids uint32) as verify's mesh index
    (``lut[gid]``; -1 where the ray hit nothing or the geometry is unknown) and triangle id per ray."""
    n_lut = lut.size
    for i in range(t.size):
        g = np.int64(gid[i])
        m = lut[g] if np.isfinite(t[i]) and g < n_lut else -1
        mesh[i] = m
        tri[i] = np.int64(prim[i])


@njit(cache=True, error_model="numpy")
def surface_from(o, d, u, v, A, mesh, tri, V, T, toff, depth, pos, normal, bary):  # pragma: no cover - compiled
    """Per ray i from the point o (3,) with mesh[i] >= 0: planar depth, hit point, unit normal facing the ray's origin and
    barycentric (b1, b2) on triangle tri[i] of mesh[i] (rows of T from toff[mesh]), in float64; a
    ray that hit nothing gets depth inf, NaN point and normal, barycentric 0. The ray's direction is
    d[i] (N, 3), or when d is empty the pinhole's A (u[i], v[i], 1) (:func:`rays_through`'s)."""
    given = d.shape[0] > 0
    for i in range(mesh.size):
        m = mesh[i]
        if m < 0:
            depth[i] = np.inf
            for j in range(3):
                pos[i, j] = np.nan
                normal[i, j] = np.nan
            bary[i, 0], bary[i, 1] = 0.0, 0.0
            continue
        if given:
            dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
        else:
            dx = A[0, 0] * u[i] + A[0, 1] * v[i] + A[0, 2]
            dy = A[1, 0] * u[i] + A[1, 1] * v[i] + A[1, 2]
            dz = A[2, 0] * u[i] + A[2, 1] * v[i] + A[2, 2]
        t, px, py, pz, b1, b2, nx, ny, nz = _hit(m, tri[i], o[0], o[1], o[2], dx, dy, dz, V, T, toff)
        depth[i] = t
        pos[i, 0], pos[i, 1], pos[i, 2] = px, py, pz
        bary[i, 0], bary[i, 1] = b1, b2
        normal[i, 0], normal[i, 1], normal[i, 2] = nx, ny, nz


@njit(cache=True, error_model="numpy")
def corner_motion(u, v, A, o, mesh, tri, V, T, toff, same, V1, T1, toff1, M, R2, C, carry, depth, flow):  # pragma: no cover - compiled
    """What the mixed rule reads at rays through (u, v) (pinhole directions A (u, v, 1) from o):
    :func:`surface_from`'s depth (inf where nothing is hit) and, with ``carry``, :func:`carry_motion`'s
    flow (NaN where the motion is not known), by the same arithmetic, without the other values."""
    for i in range(mesh.size):
        m = mesh[i]
        if carry:
            flow[i, 0], flow[i, 1] = np.nan, np.nan
        if m < 0:
            depth[i] = np.inf
            continue
        dx = A[0, 0] * u[i] + A[0, 1] * v[i] + A[0, 2]
        dy = A[1, 0] * u[i] + A[1, 1] * v[i] + A[1, 2]
        dz = A[2, 0] * u[i] + A[2, 1] * v[i] + A[2, 2]
        t, px, py, pz, b1, b2, nx, ny, nz = _hit(m, tri[i], o[0], o[1], o[2], dx, dy, dz, V, T, toff)
        depth[i] = t
        if carry and same[m]:
            qx, qy, qz, u1, v1, z1 = _carry(m, tri[i], b1, b2, V1, T1, toff1, M, R2, C)
            flow[i, 0], flow[i, 1] = u1 - u[i], v1 - v[i]


@njit(cache=True, error_model="numpy")
def mixed_decisions(ident, depth, flow, use_flow, H, W, depth_rel, flow_px, out, depth_rel2, flow_px2, out2):  # pragma: no cover - compiled
    """verify._mixed_decision's rule per pixel (see there) on the (H+1) x (W+1) corner grid, decided in the same pass with two sets
    of limits (depth_rel, flow_px into ``out``; depth_rel2, flow_px2 into ``out2``)."""
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
            res2 = res
            if not res:
                lo, hi, fin = np.inf, -np.inf, True
                for c in cs:
                    z = depth[c]
                    if not np.isfinite(z):
                        fin = False
                    lo, hi = min(lo, z), max(hi, z)
                if fin and hi - lo > depth_rel * lo:
                    res = True
                if fin and hi - lo > depth_rel2 * lo:
                    res2 = True
            if not (res and res2) and use_flow and i0 >= 0:
                for a in range(4):
                    for b in range(a + 1, 4):
                        gx = flow[cs[a], 0] - flow[cs[b], 0]
                        gy = flow[cs[a], 1] - flow[cs[b], 1]
                        g = np.sqrt(gx * gx + gy * gy)
                        if g > flow_px:  # NaN (unknown motion) counts as none
                            res = True
                        if g > flow_px2:
                            res2 = True
            out[y * W + x] = res
            out2[y * W + x] = res2


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


_SIGN = np.uint64(1) << np.uint64(63)


@njit(cache=True, error_model="numpy")
def _ordered(b):  # pragma: no cover - compiled
    """A float64's bits as an unsigned key in the float's order (negatives reversed below positives)."""
    return ~b if b & _SIGN else b | _SIGN


_ZERO = np.uint64(1) << np.uint64(63)  # the key of +0.0
N_BUCKETS = 2048
_LOW = 0x8000 + (1023 - 62) * 16  # top 16 bits of the key of 2^-62: 16 buckets a binade from there (to 2^65)


@njit(cache=True, error_model="numpy")
def _bucket(b):  # pragma: no cover - compiled
    """A float64's radix bucket (its bits ``b``), in the float's order: 0 negatives and -0.0, 1 exactly
    +0.0 (exact agreement, often most pixels: never gathered), 2 under 2^-62, then the top 16 bits of
    the key (sign, exponent, 4 bits of mantissa) up to 2^65, the last bucket anything larger (inf)."""
    k = _ordered(b)
    if k < _ZERO:
        return 0
    if k == _ZERO:
        return 1
    return 2 + min(max(np.int64(k >> np.uint64(48)) - _LOW, 0), N_BUCKETS - 3)


@njit(cache=True, error_model="numpy")
def label_stats(e, code, kind, n_labels, n_kinds, limit, rate, q):  # pragma: no cover - compiled
    """One pass over a key's per-pixel errors ``e`` (float64; NaN: not compared) for verify's rows: per
    label (``code`` per pixel, 0 .. n_labels-1; row n_labels is every label together) the pixels
    compared, those over ``limit`` (over 0.5 when ``rate``), the first pixel of the greatest error and
    that error, the sum of the errors, the count per tie kind (``kind`` per pixel, 0 .. n_kinds-1)
    and, unless ``rate``, the percentiles ``q`` of the compared errors (np.percentile's default, linear
    between the order statistics around (n - 1) q / 100, by the same arithmetic; NaN for a row
    without pixels). The order statistics by radix selection: the same pass histograms the errors'
    buckets (:func:`_bucket`, in float order) per label; a second pass gathers only the buckets that
    hold the ranks wanted, each then partitioned."""
    rows = n_labels + 1
    L = n_labels
    count = np.zeros(rows, np.int64)
    over = np.zeros(rows, np.int64)
    worst = np.zeros(rows, np.int64)
    top = np.full(rows, -np.inf)
    total = np.zeros(rows)
    kinds = np.zeros((rows, n_kinds), np.int64)
    nq = q.size
    pct = np.full((rows, nq), np.nan)
    nb = N_BUCKETS
    hist = np.zeros((0, nb), np.int64) if rate else np.zeros((rows, nb), np.int64)
    raw = e.view(np.uint64)
    everything = 0.0  # the sum over all labels, in pixel order
    bar = 0.5 if rate else limit
    # A label's figures are kept in locals while its pixels follow one another (labels come in runs
    # along image rows), written back when another label's pixel comes: the same sums in the same
    # order, without a store and load per pixel. Tie kinds other than 0 are counted as they come.
    cur = -1
    n_c, sum_c, over_c, top_c, worst_c = 0, 0.0, 0, -np.inf, 0
    for i in range(e.size):  # per label; the row of all labels from theirs below
        x = e[i]
        if x != x:
            continue
        c = code[i]
        if c != cur:
            if cur >= 0:
                count[cur], total[cur], over[cur], top[cur], worst[cur] = n_c, sum_c, over_c, top_c, worst_c
            cur = c
            n_c, sum_c, over_c, top_c, worst_c = count[c], total[c], over[c], top[c], worst[c]
        if not rate:
            hist[c, _bucket(raw[i])] += 1
        n_c += 1
        sum_c += x
        everything += x
        if x > bar:
            over_c += 1
        if n_c == 1 or x > top_c:
            top_c = x
            worst_c = i
        k = kind[i]
        if k != 0:
            kinds[c, k] += 1
    if cur >= 0:
        count[cur], total[cur], over[cur], top[cur], worst[cur] = n_c, sum_c, over_c, top_c, worst_c
    for c in range(L):
        others = 0
        for k in range(1, n_kinds):
            others += kinds[c, k]
        kinds[c, 0] = count[c] - others
    total[L] = everything
    for c in range(L):
        if count[c] == 0:
            continue
        count[L] += count[c]
        over[L] += over[c]
        for k in range(n_kinds):
            kinds[L, k] += kinds[c, k]
        # the first pixel of the greatest error of all: the earliest of the labels' that share it
        if count[L] == count[c] or top[c] > top[L] or (top[c] == top[L] and worst[c] < worst[L]):
            top[L], worst[L] = top[c], worst[c]
    if rate:
        return count, over, worst, top, total, kinds, pct
    for c in range(L):
        for b in range(nb):
            hist[L, b] += hist[c, b]
    # per row the ranks wanted (two per q), the bucket of each and where it starts
    nk = 2 * nq
    ks = np.zeros((rows, nk), np.int64)
    bk = np.full((rows, nk), -1, np.int64)
    start = np.zeros((rows, nk), np.int64)
    for r in range(rows):
        n = count[r]
        if n == 0:
            continue
        for j in range(nq):
            lo = np.int64(np.floor((n - 1) * (q[j] / 100)))
            ks[r, 2 * j], ks[r, 2 * j + 1] = lo, min(lo + 1, n - 1)
        b, below = 0, 0
        for s in np.argsort(ks[r]):  # one scan of the histogram, the ranks in ascending order
            while below + hist[r, b] <= ks[r, s]:
                below += hist[r, b]
                b += 1
            bk[r, s], start[r, s] = b, below
    # one buffer per (row, wanted bucket) but bucket 1 (+0.0 alone: its values are known); slot[r, b]
    slot = np.full((rows, nb), -1, np.int64)
    off = np.zeros(rows * nk + 1, np.int64)
    n_slots = 0
    for r in range(rows):
        for s in range(nk):
            b = bk[r, s]
            if b >= 0 and b != 1 and slot[r, b] < 0:
                slot[r, b] = n_slots
                off[n_slots + 1] = off[n_slots] + hist[r, b]
                n_slots += 1
    buf = np.empty(off[n_slots])
    fill = off[:n_slots].copy()
    if n_slots:
        for i in range(e.size):
            x = e[i]
            if x != x:
                continue
            b = _bucket(raw[i])
            k = slot[code[i], b]
            if k >= 0:
                buf[fill[k]] = x
                fill[k] += 1
            k = slot[L, b]
            if k >= 0:
                buf[fill[k]] = x
                fill[k] += 1
    val = np.zeros(nk)
    part = np.empty(0)
    for r in range(rows):
        n = count[r]
        if n == 0:
            continue
        for s in range(nk):
            b = bk[r, s]
            if b == 1:
                val[s] = 0.0
                continue
            k = slot[r, b]
            j = ks[r, s] - start[r, s]
            if s % 2 == 1 and bk[r, s - 1] == b and ks[r, s] == ks[r, s - 1] + 1:
                # the next rank in the same bucket: the least of what the last partition put above it
                val[s] = part[j:].min()
                continue
            part = np.partition(buf[off[k]:off[k + 1]], j)
            val[s] = part[j]
        for j in range(nq):
            vi = (n - 1) * (q[j] / 100)
            t = vi - ks[r, 2 * j]
            a, b2 = val[2 * j], val[2 * j + 1]
            diff = b2 - a  # inf - inf: NaN, as numpy's
            pct[r, j] = b2 - diff * (1 - t) if t >= 0.5 else a + diff * t  # numpy's _lerp
    return count, over, worst, top, total, kinds, pct


@njit(cache=True, error_model="numpy")
def rays_through(u, v, A, C):  # pragma: no cover - compiled
    """The rays from the camera centre C through pixel coordinates (u, v), directions A (u, v, 1)
    (camera-frame z = 1), as Open3D takes them ((N, 6) float32: origin, direction)."""
    n = u.size
    rays = np.empty((n, 6), np.float32)
    for i in range(n):
        for k in range(3):
            rays[i, k] = C[k]
            rays[i, 3 + k] = A[k, 0] * u[i] + A[k, 1] * v[i] + A[k, 2]
    return rays


@njit(cache=True, error_model="numpy")
def static_errors(d_ds, mesh, depth_tr, ids, inst_ds, sem_ds, classes, normal_ds, normal_tr, bg, len_tol,
                  e_depth, e_inst, e_sem, e_normal, fg_ds, both):  # pragma: no cover - compiled
    """verify._errors' static keys per pixel in one pass (NaN where not compared): relative depth
    where both the dataset (finite, under ``bg``) and the trace (mesh >= 0) see a surface; instance
    where either does (1: another id or only one sees a surface); semantic (the trace's instance's
    class, ``classes``) and the normal (1 - cos to the traced normal, 2 when its length is off by
    more than ``len_tol``) where both do. A key whose dataset array is empty is not written. Also
    writes fg_ds (the dataset sees a surface) and both."""
    has_inst, has_sem, has_norm = inst_ds.size > 0, sem_ds.size > 0, normal_ds.size > 0
    nc = classes.size
    bg_id = ids[ids.size - 1]
    for i in range(d_ds.size):
        d = np.float64(d_ds[i])
        m = mesh[i]
        ftr = m >= 0
        fds = np.isfinite(d) and d < bg
        b = fds and ftr
        fg_ds[i] = fds
        both[i] = b
        it = ids[m] if ftr else bg_id
        e_depth[i] = abs(d - depth_tr[i]) / depth_tr[i] if b else np.nan
        if has_inst:
            if fds or ftr:
                e_inst[i] = 1.0 if (inst_ds[i] != it or fds != ftr) else 0.0
            else:
                e_inst[i] = np.nan
        if has_sem:
            if b:
                e_sem[i] = 1.0 if sem_ds[i] != classes[min(max(it, 0), nc - 1)] else 0.0
            else:
                e_sem[i] = np.nan
        if has_norm:
            if b:
                nx, ny, nz = np.float64(normal_ds[i, 0]), np.float64(normal_ds[i, 1]), np.float64(normal_ds[i, 2])
                ln = np.sqrt(nx * nx + ny * ny + nz * nz)
                e = 1.0 - (nx * normal_tr[i, 0] + ny * normal_tr[i, 1] + nz * normal_tr[i, 2]) / ln
                e_normal[i] = e if abs(ln - 1.0) <= len_tol else 2.0
            else:
                e_normal[i] = np.nan


@njit(cache=True, error_model="numpy")
def motion_errors(both, tr_valid, valid_ds, flow_ds, flow_tr, sf_ds, sf_tr, sf_limit, sf_thr, mesh, ids, dc_ds, dc_tr,
                  occ_ds, occ_tr, hit, eps, e_valid, e_flow, e_sf, e_dc, e_occ):  # pragma: no cover - compiled
    """verify._errors' keys of one direction per pixel in one pass (NaN where not compared): the
    validity where both see a surface (1: the dataset's bit is not the trace's); flow, scene flow
    (scaled by ``sf_thr`` over the limit of the trace's object, ``sf_limit`` per instance id),
    disparity change and occlusion (0 where they agree or the visibility hit ``hit`` lies in the
    tie band [1 - 10 eps, 1 - eps/10]) where both see a surface, the trace knows the motion and the
    dataset calls it valid. A key whose dataset array is empty is not written. Returns whether the
    traced disparity change is finite at every pixel compared."""
    has_valid, has_flow, has_sf, has_dc, has_occ = valid_ds.size > 0, flow_ds.size > 0, sf_ds.size > 0, dc_ds.size > 0, occ_ds.size > 0
    lo, hi = 1 - 10 * eps, 1 - eps / 10
    finite = True
    for i in range(both.size):
        b = both[i]
        tv = tr_valid[i]
        ok = b and tv
        if has_valid:
            e_valid[i] = (1.0 if valid_ds[i] != tv else 0.0) if b else np.nan
            ok = ok and valid_ds[i]
        if has_flow:
            if ok:
                gx = np.float64(flow_ds[i, 0]) - flow_tr[i, 0]
                gy = np.float64(flow_ds[i, 1]) - flow_tr[i, 1]
                e_flow[i] = np.sqrt(gx * gx + gy * gy)
            else:
                e_flow[i] = np.nan
        if has_sf:
            if ok:
                gx = np.float64(sf_ds[i, 0]) - sf_tr[i, 0]
                gy = np.float64(sf_ds[i, 1]) - sf_tr[i, 1]
                gz = np.float64(sf_ds[i, 2]) - sf_tr[i, 2]
                e_sf[i] = np.sqrt(gx * gx + gy * gy + gz * gz) * sf_thr / sf_limit[max(ids[mesh[i]], 0)]
            else:
                e_sf[i] = np.nan
        if has_dc:
            if ok:
                x = dc_tr[i]
                if not np.isfinite(x):
                    finite = False
                e_dc[i] = abs(np.float64(dc_ds[i]) - x)
            else:
                e_dc[i] = np.nan
        if has_occ:
            if ok:
                h = hit[i]
                e_occ[i] = 0.0 if (occ_ds[i] == occ_tr[i] or (h >= lo and h <= hi)) else 1.0
            else:
                e_occ[i] = np.nan
    return finite


@njit(cache=True, error_model="numpy")
def over_any(E, limits, rate, out):  # pragma: no cover - compiled
    """Per pixel (columns of E, one row per key): whether some key's error exceeds its limit (over
    0.5 where ``rate``); NaN exceeds nothing."""
    for i in range(E.shape[1]):
        b = False
        for k in range(E.shape[0]):
            x = E[k, i]
            if (x > 0.5) if rate[k] else (x > limits[k]):
                b = True
                break
        out[i] = b


@njit(cache=True, error_model="numpy")
def carry_motion(mesh, tri, bary, same, V1, T1, toff1, M, R2, C, u, v, pos, depth, fb, static, toff0,
                 pos1, valid, u1, v1, z1, flow, sflow, dchange, still):  # pragma: no cover - compiled
    """:func:`_carry` at every ray (NaN, invalid where the motion is not known) and in the same pass
    what verify derives from it: flow (u1 - u, v1 - v), scene flow (pos1 - pos), disparity change
    (fb / z1 - fb / depth; fb = f * baseline, NaN without one) and, where ``static`` is not empty
    (per row of T at t, toff0 its mesh offsets), whether the first hit lies on a triangle that stands
    still."""
    use_static = static.size > 0
    for i in range(mesh.size):
        m = mesh[i]
        still[i] = use_static and m >= 0 and static[toff0[max(m, 0)] + tri[i]]
        if m < 0 or not same[m]:
            valid[i] = False
            for j in range(3):
                pos1[i, j] = np.nan
                sflow[i, j] = np.nan
            u1[i], v1[i], z1[i] = np.nan, np.nan, np.nan
            flow[i, 0], flow[i, 1] = np.nan, np.nan
            dchange[i] = np.nan
            continue
        q = _carry(m, tri[i], bary[i, 0], bary[i, 1], V1, T1, toff1, M, R2, C)
        for j in range(3):
            pos1[i, j] = q[j]
            sflow[i, j] = q[j] - pos[i, j]
        valid[i] = True
        u1[i], v1[i], z1[i] = q[3], q[4], q[5]
        flow[i, 0], flow[i, 1] = u1[i] - u[i], v1[i] - v[i]
        dchange[i] = fb / z1[i] - fb / depth[i]


@njit(cache=True, error_model="numpy")
def visibility_split(points, valid, u1, v1, z1, still, near, H, W, C):  # pragma: no cover - compiled
    """verify.visibility_of's partition of the points in one pass: inside (valid, projected inside
    the image, in front of the camera); the first-hit ray parameter where it is known without a
    cast (1: a point on a triangle that stands still, seen from the same centre, where ``near``
    (H, W: the least depth of what moved, :func:`nearest_depth`; empty: nothing moved) shows
    nothing nearer); the points to cast against the moving triangles only (the rest of the still
    ones) and against the whole scene (inside, not still), with their segments from C as Open3D
    takes them ((N, 6) float32). Returns (inside, t_hit, full index, full rays, moving index,
    moving rays)."""
    n = valid.size
    use_still, use_near = still.size > 0, near.size > 0
    inside = np.zeros(n, np.bool_)
    t_hit = np.full(n, np.nan)
    kind = np.zeros(n, np.int8)  # 1: cast against the whole scene, 2: against what moved
    nf, nm = 0, 0
    for i in range(n):
        if not (valid[i] and u1[i] >= -0.5 and u1[i] <= W - 0.5 and v1[i] >= -0.5 and v1[i] <= H - 0.5 and z1[i] > 0):
            continue
        inside[i] = True
        if use_still and still[i]:
            t_hit[i] = 1.0
            if use_near:
                r = min(max(np.rint(v1[i]), 0.0), H - 1.0)
                c = min(max(np.rint(u1[i]), 0.0), W - 1.0)
                if near[int(r), int(c)] < z1[i]:
                    kind[i] = 2
                    nm += 1
        else:
            kind[i] = 1
            nf += 1
    full_idx, full_rays = _segments(points, C, kind, 1, nf)
    moving_idx, moving_rays = _segments(points, C, kind, 2, nm)
    return inside, t_hit, full_idx, full_rays, moving_idx, moving_rays


@njit(cache=True, error_model="numpy")
def _segments(points, C, kind, which, count):  # pragma: no cover - compiled
    """The indices of the ``count`` points of ``kind`` ``which`` and their segments from C as Open3D
    takes them ((count, 6) float32: origin C, direction point - C)."""
    idx, rays = np.empty(count, np.int64), np.empty((count, 6), np.float32)
    a = 0
    for i in range(kind.size):
        if kind[i] == which:
            idx[a] = i
            for j in range(3):
                rays[a, j] = C[j]
                rays[a, 3 + j] = points[i, j] - C[j]
            a += 1
    return idx, rays
