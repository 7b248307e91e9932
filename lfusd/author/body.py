"""The procedural human's skin: one closed, smooth surface made at authoring time.

A coarse control cage of quads (torso, neck and head as rings of 8 points; legs, feet, arms and
hands branched off it as rings of 4) is Catmull-Clark subdivided here, so the authored mesh is the
final polygon mesh that Cycles renders and verify ray-casts (the prim says subdivisionScheme
"none"). Cage vertices carry any per-point data (skin weights): subdivision averages it with the
points, so weights come out as smooth as the surface.
"""

from __future__ import annotations

import numpy as np

# A ring of 4 cage points at half-side r subdivides to a round tube of radius about 0.93 r.
_R4 = 1.0 / 0.93


def catmull_clark(data: np.ndarray, quads: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One Catmull-Clark step on a closed all-quad mesh.

    ``data`` (N, d): points and any per-point columns, averaged alike. Returns (new data, new
    quads, parent face of each new quad); each new quad starts at its parent's face point.
    """
    nf = len(quads)
    face_pts = data[quads].mean(axis=1)
    half = np.stack([quads, np.roll(quads, -1, axis=1)], axis=-1).reshape(-1, 2)  # edge k of face f: row 4f+k
    edges, inv = np.unique(np.sort(half, axis=1), axis=0, return_inverse=True)
    inv = inv.ravel()
    of_face = np.repeat(np.arange(nf), 4)
    around = np.zeros((len(edges), data.shape[1]))
    np.add.at(around, inv, face_pts[of_face])
    edge_pts = (data[edges[:, 0]] + data[edges[:, 1]] + around) / 4.0  # closed: every edge has two faces
    valence = np.bincount(edges.ravel(), minlength=len(data)).astype(float)[:, None]
    f_sum = np.zeros_like(data)
    np.add.at(f_sum, quads.ravel(), face_pts[of_face])
    mid = (data[edges[:, 0]] + data[edges[:, 1]]) / 2.0
    r_sum = np.zeros_like(data)
    np.add.at(r_sum, edges[:, 0], mid)
    np.add.at(r_sum, edges[:, 1], mid)
    vert_pts = (f_sum / valence + 2.0 * r_sum / valence + (valence - 3.0) * data) / valence
    n, ne = len(data), len(edges)
    e = (n + inv).reshape(nf, 4)
    f = n + ne + np.arange(nf)
    new = np.stack([np.repeat(f[:, None], 4, axis=1), np.roll(e, 1, axis=1), quads, e], axis=-1).reshape(-1, 4)
    return np.concatenate([vert_pts, edge_pts, face_pts]), new, of_face


def orient(quads: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Quads wound consistently (neighbours cross their shared edge in opposite directions) and
    outward (positive enclosed volume)."""
    quads = quads.copy()
    by_edge: dict[tuple[int, int], list[int]] = {}
    for f, q in enumerate(quads.tolist()):
        for k in range(4):
            a, b = q[k], q[(k + 1) % 4]
            by_edge.setdefault((min(a, b), max(a, b)), []).append(f)
    done = np.zeros(len(quads), bool)
    for seed in range(len(quads)):
        if done[seed]:
            continue
        done[seed] = True
        stack = [seed]
        while stack:
            f = stack.pop()
            q = quads[f].tolist()
            for k in range(4):
                a, b = q[k], q[(k + 1) % 4]
                for g in by_edge[(min(a, b), max(a, b))]:
                    if done[g]:
                        continue
                    r = quads[g].tolist()
                    if any(r[m] == a and r[(m + 1) % 4] == b for m in range(4)):
                        quads[g] = quads[g][::-1]
                    done[g] = True
                    stack.append(g)
    p = points[quads]
    vol = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])) + np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 2], p[:, 3]))
    return quads if vol.sum() > 0 else quads[:, ::-1]


class Cage:
    """Control points (with a part name each) and quads (with a part name each)."""

    def __init__(self):
        self.points: list[np.ndarray] = []
        self.point_part: list[str] = []
        self.quads: list[list[int]] = []
        self.quad_part: list[str] = []

    def ring(self, pts, part: str) -> list[int]:
        start = len(self.points)
        self.points += [np.asarray(p, float) for p in pts]
        self.point_part += [part] * len(pts)
        return list(range(start, start + len(pts)))

    def quad(self, q, part: str) -> None:
        self.quads.append([int(v) for v in q])
        self.quad_part.append(part)

    def loft(self, a: list[int], b: list[int], part: str, skip=()) -> None:
        """Quads between two rings of equal size (skipping the ``skip`` sides: openings for branches)."""
        k = len(a)
        for j in range(k):
            if j not in skip:
                self.quad([a[j], a[(j + 1) % k], b[(j + 1) % k], b[j]], part)

    def branch(self, loop: list[int], sides, frames, cap: str | None = None) -> None:
        """A limb grown out of a 4-point ``loop`` (an opening left in the body). ``sides`` (u, v):
        each loop point's side of u and of v, seen from the loop's centre, is kept by the rings:
        each frame (part, centre, u, v, (u-, u+), (v-, v+)) places one, ``cap`` (a part) closes the end."""
        p = np.array([self.points[i] for i in loop])
        su = np.sign((p - p.mean(axis=0)) @ np.asarray(sides[0], float))
        sv = np.sign((p - p.mean(axis=0)) @ np.asarray(sides[1], float))
        prev = loop
        for part, centre, u, v, (um, up), (vm, vp) in frames:
            u, v = np.asarray(u, float), np.asarray(v, float)
            pts = [np.asarray(centre, float) + (up if a > 0 else -um) * u + (vp if b > 0 else -vm) * v for a, b in zip(su, sv)]
            r = self.ring(pts, part)
            self.loft(prev, r, part)
            prev = r
        if cap:
            self.quad(prev, cap)

    def subdivide(self, data: np.ndarray | None = None, levels: int = 2):
        """(points, quads, face part names, per-point data) after ``levels`` Catmull-Clark steps."""
        pts = np.array(self.points)
        quads = orient(np.array(self.quads), pts)
        cols = pts if data is None else np.hstack([pts, data])
        part = np.array(self.quad_part)
        for _ in range(levels):
            cols, quads, parent = catmull_clark(cols, quads)
            part = part[parent]
        return cols[:, :3], quads, part, cols[:, 3:]
