"""The edge part of the ``mixed`` key: pixels whose square a discontinuity of the triangles crosses.

A pixel's four corner rays (lfusd.truth.visibility.mixed_footprint) miss whatever passes between
them: a 4 mm wire seen from 5 m is a tenth of a pixel wide. This module finds such structure from
the triangles themselves, exactly, for the derivation (Blender's rendered triangles) and for verify
(the stage's triangles traced with pxr) alike:

- A *discontinuity edge* is a triangle edge, after welding vertices with the same float32
  coordinates, that borders one triangle only (a boundary), three or more (non-manifold), two
  triangles of different instances, or two triangles of which the camera sees one from the front
  and the other from the back (a silhouette: where a surface turns away and what lies behind shows).
- It *crosses* pixel (i, j) when its projection (clipped in front of the camera) meets the closed
  square u in [j - 1/2, j + 1/2], v in [i - 1/2, i + 1/2] (conservative rasterisation of segments),
- at a depth that is not behind the pixel: the edge's least depth inside the square is at most
  (1 + MIXED_DEPTH_REL) times the greatest depth the pixel's four corner rays see (any miss: no
  bound). An edge hidden behind everything the footprint shows does not count.

docs/CONVENTIONS.md ("mixed") states the definition; the compiled work is
:func:`lfusd.truth._footprint_numba.footprint_edges`.
"""

from __future__ import annotations

import numpy as np

from ..camera import Camera

ZNEAR = 1e-6  # m: edges are clipped to camera depth at least this (in front of the camera)


def weld(vertices: np.ndarray) -> np.ndarray:
    """Per vertex, one id shared by every vertex with the same float32 coordinates (-0 is 0)."""
    v = np.ascontiguousarray(vertices, np.float32) + np.float32(0.0)  # -0.0 + 0.0 = +0.0
    if not len(v):
        return np.zeros(0, np.int64)
    bits = v.view(np.uint32).reshape(-1, 3)
    order = np.lexsort((bits[:, 2], bits[:, 1], bits[:, 0]))
    s = bits[order]
    new = np.r_[True, (s[1:] != s[:-1]).any(axis=1)]
    out = np.empty(len(v), np.int64)
    out[order] = np.cumsum(new) - 1
    return out


def edge_table(vertices: np.ndarray, triangles: np.ndarray) -> dict[str, np.ndarray]:
    """Every edge of the welded triangles once: its two vertex indices (``e0``, ``e1``, into
    ``vertices``), the triangle on each side (``t1``; ``t2`` -1 for a boundary, -2 for three or
    more) and ``flip``: both triangles run along the edge the same way (inconsistent winding, so
    their normals' sides disagree). Depends on the triangles only: built once per frame."""
    tri = np.asarray(triangles, np.int64).reshape(-1, 3)
    wid = weld(vertices)
    w3 = wid[tri] if len(tri) else np.zeros((0, 3), np.int64)
    # a triangle with two vertices welded into one has no area and hides nothing: its edges are left out
    tri = np.where(((w3[:, 0] != w3[:, 1]) & (w3[:, 1] != w3[:, 2]) & (w3[:, 2] != w3[:, 0]))[:, None], tri, -1)
    a = tri[:, [0, 1, 2]].ravel()
    b = tri[:, [1, 2, 0]].ravel()
    wa, wb = np.where(a >= 0, wid[a], -1), np.where(b >= 0, wid[b], -1)
    keep = np.flatnonzero(wa != wb)  # (both -1 on a triangle left out)  # edges of zero length after welding bound nothing
    lo, hi = np.minimum(wa[keep], wb[keep]), np.maximum(wa[keep], wb[keep])
    key = lo * (int(wid.max(initial=0)) + 1) + hi
    order = np.argsort(key, kind="stable")
    ks = key[order]
    start = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]]) if len(ks) else np.zeros(0, np.int64)
    count = np.diff(np.r_[start, len(ks)])
    first = keep[order[start]]
    second = keep[order[np.minimum(start + 1, max(len(ks) - 1, 0))]]
    t2 = np.where(count == 2, second // 3, np.where(count == 1, -1, -2))
    return {"e0": a[first], "e1": b[first], "t1": first // 3, "t2": t2.astype(np.int64),
            "flip": (count == 2) & (wa[second] == wa[first])}


def crossed_by_edges(vertices: np.ndarray, triangles: np.ndarray, instance: np.ndarray, table: dict, camera: Camera,
                     corner_depth: np.ndarray, h: int, w: int, depth_rel: float, grow: float = 0.0, ulps: float = 0.0,
                     strict: bool = False, fpx: float = 0.0) -> np.ndarray:
    """(h, w) bool: pixels whose square a discontinuity edge crosses (the module docstring).
    ``corner_depth``: planar depth of the first hit through each pixel corner ((h+1)(w+1), row-major,
    corner (i, j) at (j - 1/2, i - 1/2); inf where none). ``grow`` (px), ``ulps`` and ``strict`` give
    verify its bands: squares grown (or shrunk, negative) and the side of nearly edge-on triangles
    taken as ambiguous (see lfusd.truth._footprint_numba.footprint_edges), with ``ulps`` also growing
    (or shrinking) each edge's squares by that many float32 roundoffs of its coordinates seen at its
    depth (``fpx``: the focal length in px); the derivation uses none."""
    from ._footprint_numba import footprint_edges

    out = np.zeros((h, w), bool)
    if not len(table["e0"]):
        return out
    R, C = camera.world_to_cam()
    footprint_edges(np.ascontiguousarray(vertices, np.float64), np.ascontiguousarray(triangles, np.int64),
                    np.ascontiguousarray(instance, np.int64), table["e0"], table["e1"], table["t1"], table["t2"], table["flip"],
                    np.asarray(camera.K, np.float64) @ R, np.ascontiguousarray(C, np.float64), np.ascontiguousarray(R[2], np.float64),
                    np.ascontiguousarray(corner_depth, np.float64).ravel(), h, w, float(depth_rel), float(grow), float(ulps),
                    bool(strict), float(fpx), ZNEAR, out)
    return out
