"""Compiled part of :mod:`lfusd.truth.footprint` (numba): which triangle edges are discontinuities
as seen from a camera, and the conservative rasterisation of those edges into the pixels whose
squares they cross. Kept apart from the other kernels so that editing one file recompiles one."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

EPS32 = 2.0**-24  # float32 unit roundoff
MAX_GROW = 2.0  # px: the float bound of an edge's position is capped here (an edge within millimetres of the lens)


@njit(cache=True, error_model="numpy")
def _facing(V, T, C, ulps):  # pragma: no cover - compiled
    """Per triangle: the cosine between its normal and the direction from the camera centre C to its
    first vertex (its sign: which side the camera sees), and how far off that cosine may be from
    float32 rounding of coordinates (``ulps`` roundoffs of max(|vertex|, |C|) over the triangle's
    size; 0 when ``ulps`` is 0)."""
    m = T.shape[0]
    cos = np.empty(m)
    tol = np.zeros(m)
    cmag = math.sqrt(C[0] * C[0] + C[1] * C[1] + C[2] * C[2])
    for f in range(m):
        a, b, c = T[f, 0], T[f, 1], T[f, 2]
        e1x, e1y, e1z = V[b, 0] - V[a, 0], V[b, 1] - V[a, 1], V[b, 2] - V[a, 2]
        e2x, e2y, e2z = V[c, 0] - V[a, 0], V[c, 1] - V[a, 1], V[c, 2] - V[a, 2]
        nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
        px, py, pz = V[a, 0] - C[0], V[a, 1] - C[1], V[a, 2] - C[2]
        nn = math.sqrt(nx * nx + ny * ny + nz * nz)
        pn = math.sqrt(px * px + py * py + pz * pz)
        if nn == 0.0 or pn == 0.0:
            cos[f] = 0.0  # a degenerate triangle, or one through the camera: either side
            tol[f] = np.inf
            continue
        cos[f] = (nx * px + ny * py + nz * pz) / (nn * pn)
        if ulps > 0:
            vmag = max(math.sqrt(V[a, 0] ** 2 + V[a, 1] ** 2 + V[a, 2] ** 2), cmag)
            tol[f] = ulps * EPS32 * vmag * (1.0 / math.sqrt(nn) + 1.0 / pn)
    return cos, tol


@njit(cache=True, error_model="numpy")
def _clip(s0, s1, p, d, lo, hi):  # pragma: no cover - compiled
    """The part [s0, s1] of a segment p + s d (one coordinate) inside [lo, hi] (closed): (s0, s1),
    empty when s0 > s1."""
    if d == 0.0:
        if p < lo or p > hi:
            return 1.0, 0.0
        return s0, s1
    a, b = (lo - p) / d, (hi - p) / d
    if a > b:
        a, b = b, a
    return max(s0, a), min(s1, b)


@njit(cache=True, error_model="numpy")
def footprint_edges(V, T, inst, e0, e1, t1, t2, flip, M, C, R2, corner_depth, h, w, depth_rel, grow, ulps, strict,
                    fpx, znear, out):  # pragma: no cover - compiled
    """Set ``out[i, j]`` (h, w) where a discontinuity edge crosses pixel (i, j)'s square.

    Edges (from lfusd.truth.footprint.edge_table): vertex indices e0, e1 into V, the triangle on
    each side t1, t2 (t2 -1: a boundary edge, -2: three or more triangles), ``flip``: the two
    triangles wind the edge the same way (their normals disagree). An edge is a discontinuity when it
    is a boundary, non-manifold, between two instances (``inst`` per triangle), or a silhouette: the
    camera sees one of its triangles from the front and the other from the back. ``ulps`` > 0 makes
    the side of a triangle within float32 rounding of edge-on ambiguous (see :func:`_facing`):
    ``strict`` then counts such an edge as no silhouette, else as one.

    The edge, clipped to camera depth z >= ``znear``, is projected (M = K R, R2 = R's depth row, C
    the centre); a pixel's square (u in [j - 1/2, j + 1/2], v likewise, grown by ``grow`` px on
    every side) is crossed when the projected segment meets it (closed). The crossing counts when
    the edge's least depth inside the square is at most (1 + ``depth_rel``) times the greatest
    depth the rays through the pixel's four corners see (``corner_depth``: (h+1)(w+1) planar depths,
    inf for a miss): an edge behind all that the footprint shows is hidden. With ``ulps`` > 0 the
    squares are grown (``grow`` >= 0) or shrunk (``grow`` < 0) by at least that many float32
    roundoffs of the edge's coordinates (max(|end|, |C|)) seen at its depth in the square (``fpx``:
    focal length in px; at most MAX_GROW px): where the edge may lie after rounding."""
    cos, tol = _facing(V, T, C, ulps)
    wc = w + 1
    for k in range(e0.shape[0]):
        f1, f2 = t1[k], t2[k]
        disc = f2 < 0
        if not disc:
            disc = inst[f1] != inst[f2]
        if not disc:
            c1 = cos[f1]
            c2 = -cos[f2] if flip[k] else cos[f2]
            e = max(tol[f1], tol[f2])
            if strict:
                disc = (c1 > e and c2 < -e) or (c1 < -e and c2 > e)
            else:
                disc = not ((c1 > e and c2 > e) or (c1 < -e and c2 < -e))
        if not disc:
            continue
        a, b = e0[k], e1[k]
        pa = np.empty(3)
        pb = np.empty(3)
        for x in range(3):
            pa[x] = V[a, x] - C[x]
            pb[x] = V[b, x] - C[x]
        za = R2[0] * pa[0] + R2[1] * pa[1] + R2[2] * pa[2]
        zb = R2[0] * pb[0] + R2[1] * pb[1] + R2[2] * pb[2]
        if za < znear and zb < znear:
            continue
        if za < znear or zb < znear:  # clip at the near plane (depth is affine along the 3D segment)
            s = (znear - za) / (zb - za)
            q = pa if za < znear else pb
            for x in range(3):
                q[x] = pa[x] + s * (pb[x] - pa[x])
            if za < znear:
                za = znear
            else:
                zb = znear
        ha = M[2, 0] * pa[0] + M[2, 1] * pa[1] + M[2, 2] * pa[2]
        hb = M[2, 0] * pb[0] + M[2, 1] * pb[1] + M[2, 2] * pb[2]
        ua = (M[0, 0] * pa[0] + M[0, 1] * pa[1] + M[0, 2] * pa[2]) / ha
        va = (M[1, 0] * pa[0] + M[1, 1] * pa[1] + M[1, 2] * pa[2]) / ha
        ub = (M[0, 0] * pb[0] + M[0, 1] * pb[1] + M[0, 2] * pb[2]) / hb
        vb = (M[1, 0] * pb[0] + M[1, 1] * pb[1] + M[1, 2] * pb[2]) / hb
        if not (math.isfinite(ua) and math.isfinite(va) and math.isfinite(ub) and math.isfinite(vb)):
            continue
        du, dv = ub - ua, vb - va
        ia, ib = 1.0 / za, 1.0 / zb  # inverse depth is affine in the projected segment's parameter
        g = grow
        px_per_inv = 0.0  # px of rounding per unit of inverse depth
        if ulps > 0:
            mag = max(max(math.sqrt(V[a, 0] ** 2 + V[a, 1] ** 2 + V[a, 2] ** 2), math.sqrt(V[b, 0] ** 2 + V[b, 1] ** 2 + V[b, 2] ** 2)),
                      math.sqrt(C[0] * C[0] + C[1] * C[1] + C[2] * C[2]))
            px_per_inv = ulps * EPS32 * mag * fpx
            # the range searched: the bound at the edge's nearest point, at most MAX_GROW px
            g = min(max(abs(grow), px_per_inv * max(ia, ib)), MAX_GROW)
            if grow < 0:
                g = -g
        if g <= -0.5:
            continue
        j0 = int(math.ceil(max(min(ua, ub) - 0.5 - g, -1.0)))  # clamped first: a far end may be huge
        j1 = int(math.floor(min(max(ua, ub) + 0.5 + g, w + 1.0)))
        j0, j1 = max(j0, 0), min(j1, w - 1)
        for j in range(j0, j1 + 1):
            sa, sb = _clip(0.0, 1.0, ua, du, j - 0.5 - g, j + 0.5 + g)
            if sa > sb:
                continue
            vlo, vhi = min(va + sa * dv, va + sb * dv), max(va + sa * dv, va + sb * dv)
            i0 = max(int(math.ceil(max(vlo - 0.5 - g, -1.0))), 0)
            i1 = min(int(math.floor(min(vhi + 0.5 + g, h + 1.0))), h - 1)
            for i in range(i0, i1 + 1):
                if out[i, j]:
                    continue
                sc, sd = _clip(sa, sb, va, dv, i - 0.5 - g, i + 0.5 + g)
                if sc > sd:
                    continue
                inv = max(ia + sc * (ib - ia), ia + sd * (ib - ia))
                if px_per_inv > 0:  # the bound at the edge's depth here (its nearest point in the searched square)
                    gl = min(max(abs(grow), px_per_inv * inv), MAX_GROW)
                    if grow < 0:
                        gl = -gl
                    if gl != g:
                        if gl <= -0.5:
                            continue
                        sc, sd = _clip(0.0, 1.0, ua, du, j - 0.5 - gl, j + 0.5 + gl)
                        sc, sd = _clip(sc, sd, va, dv, i - 0.5 - gl, i + 0.5 + gl)
                        if sc > sd:
                            continue
                        inv = max(ia + sc * (ib - ia), ia + sd * (ib - ia))
                c = i * wc + j
                far = max(max(corner_depth[c], corner_depth[c + 1]), max(corner_depth[c + wc], corner_depth[c + wc + 1]))
                if not (far < np.inf) or 1.0 <= inv * far * (1.0 + depth_rel):
                    out[i, j] = True
