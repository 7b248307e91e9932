"""A stage of single n-gon faces for measuring how Blender triangulates them (issue 37 item 1).

Convex and concave faces of 5-8 corners (an L, a star, faces whose ear search reverses its sweep),
each its own mesh, every corner at its own height so that each diagonal gives the face another
surface (another depth); one row lies flat under a camera looking straight down, the other tilted.
:func:`fit_triangulations` tells, from a render's world positions, which triangulations of a face
agree with every pixel, independently of lfusd's rule."""

from __future__ import annotations

from functools import lru_cache
from itertools import product

import numpy as np

# Corner xy (a face's own frame, about the unit disc) and the height of each corner.
NGONS = {
    "pent_convex": [(1.0, 0.0), (0.31, 0.95), (-0.81, 0.59), (-0.81, -0.59), (0.31, -0.95)],
    "pent_concave": [(-1.0, -1.0), (1.0, -0.9), (0.9, 1.0), (0.0, 0.3), (-1.0, 0.95)],
    "hex_convex": [(1.0, 0.0), (0.5, 0.87), (-0.5, 0.87), (-1.0, 0.0), (-0.5, -0.87), (0.5, -0.87)],
    # reflex corners where the ear search lands: Blender's sweep reverses there
    "hex_sweep": [(0.44, 0.05), (0.56, 1.09), (-0.12, 0.81), (-0.83, 0.91), (-1.0, -0.27), (-0.14, -0.56)],
    "hept_sweep": [(0.51, 0.21), (0.08, 0.57), (-0.49, 0.53), (-0.87, -0.78), (-0.09, -0.78), (0.68, -1.01), (0.68, -0.3)],
    "L": [(-1.0, -1.0), (1.0, -1.0), (1.0, -0.1), (0.2, -0.1), (-0.05, 1.0), (-1.0, 1.0)],
    "star8": [((1.0 if k % 2 == 0 else 0.45) * np.cos(2 * np.pi * k / 8 + 0.2),
               (1.0 if k % 2 == 0 else 0.45) * np.sin(2 * np.pi * k / 8 + 0.2)) for k in range(8)],
    "arrow7": [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (0.45, -0.2), (0.0, 0.9), (-0.5, -0.15), (-1.0, 1.0)],
    "bent_pent": [(1.0, 0.0), (0.31, 0.95), (-0.81, 0.59), (-0.81, -0.59), (0.31, -0.95)],
}
HEIGHTS = {"bent_pent": [0.0, 0.7, 0.0, 0.7, 0.0]}  # folded: far out of plane
SPACING = 2.5
TILT = (35.0, 20.0)  # the tilted row's rotation about x, then z (degrees)


def corners(name: str) -> np.ndarray:
    """(n, 3) corners of face ``name`` in its own frame."""
    xy = np.asarray(NGONS[name], float)
    z = HEIGHTS.get(name)
    if z is None:
        z = np.random.default_rng(len(name) * 7 + len(xy)).uniform(0.0, 0.35, len(xy))
    return np.column_stack([xy, z])


def placements():
    """(prim name, face name, 4x4 local-to-world at frame 1, translation per frame) of every face."""
    out = []
    for row, tilted in enumerate((False, True)):
        for k, name in enumerate(NGONS):
            M = np.eye(4)
            if tilted:
                ax, az = np.radians(TILT)
                Rx = np.array([[1, 0, 0], [0, np.cos(ax), -np.sin(ax)], [0, np.sin(ax), np.cos(ax)]])
                Rz = np.array([[np.cos(az), -np.sin(az), 0], [np.sin(az), np.cos(az), 0], [0, 0, 1]])
                M[:3, :3] = Rz @ Rx
            c, r = k % 5, 2 * row + k // 5
            M[:3, 3] = ((c - 2.0) * SPACING, (1.5 - r) * SPACING, 0.0)
            out.append((f"{name}_{'tilted' if tilted else 'flat'}", name, M, np.array([0.04, 0.02 * (1 - 2 * row), 0.0])))
    return out


def build(path: str, frames: int = 1, width: int = 96, height: int = 96):
    """Author the stage at ``path`` (faces moving rigidly over ``frames``) with one camera
    looking straight down; returns the stage."""
    from pxr import Gf, UsdGeom

    from lfusd.author.labels import set_class_label
    from lfusd.author.rigs import add_rig
    from lfusd.author.stage import new_stage
    from lfusd.camera import RigSpec

    stage = new_stage(path, 1, frames)
    for prim, name, M, step in placements():
        m = UsdGeom.Mesh.Define(stage, f"/World/{prim}")
        P = corners(name)
        m.CreatePointsAttr([tuple(map(float, p)) for p in P])
        m.CreateFaceVertexCountsAttr([len(P)])
        m.CreateFaceVertexIndicesAttr(list(range(len(P))))
        m.CreateSubdivisionSchemeAttr("none")
        op = m.AddTransformOp()
        for f in range(1, frames + 1):
            A = M.copy()
            A[:3, 3] += step * (f - 1)
            op.Set(Gf.Matrix4d(A.T.tolist()), f)  # USD's row-vector convention
        set_class_label(m.GetPrim(), prim)
    floor = UsdGeom.Mesh.Define(stage, "/World/Floor")
    floor.CreatePointsAttr([(-9, -9, -1.5), (9, -9, -1.5), (9, 9, -1.5), (-9, 9, -1.5)])
    floor.CreateFaceVertexCountsAttr([4])
    floor.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    floor.CreateSubdivisionSchemeAttr("none")
    set_class_label(floor.GetPrim(), "floor")
    add_rig(stage, RigSpec(name="main", rows=1, cols=1, width=width, height=height, focal_length_mm=30.0, at=(0, 0, 14), look_at=(0, 0, 0)))
    stage.Save()
    return stage


@lru_cache(maxsize=None)
def all_triangulations(n: int) -> tuple[frozenset, ...]:
    """Every triangulation of an n-gon by its own corners (as sets of sorted corner triples)."""
    def tri(i: int, j: int):
        if j - i < 2:
            return [frozenset()]
        return [a | b | {(i, k, j)} for k in range(i + 1, j) for a, b in product(tri(i, k), tri(k, j))]
    return tuple(tri(0, n - 1))


def fit_triangulations(P: np.ndarray, local: np.ndarray, tol: float = 2e-4) -> list[frozenset]:
    """The triangulations of the face with corners ``P`` (n, 3; its own frame, xy the plane its
    corners' heights stand on) that put every rendered point ``local`` (m, 3; the same frame)
    within ``tol`` of their surface, its height over the xy of the point."""
    xy = local[:, :2]
    fits = []
    for T in all_triangulations(len(P)):
        best = np.full(len(local), np.inf)
        for a, b, c in T:
            A, B, C = P[a], P[b], P[c]
            M = np.array([[B[0] - A[0], C[0] - A[0]], [B[1] - A[1], C[1] - A[1]]])
            if abs(np.linalg.det(M)) < 1e-12:
                continue
            s, t = np.linalg.solve(M, (xy - A[:2]).T)
            inside = (s >= -1e-9) & (t >= -1e-9) & (s + t <= 1 + 1e-9)
            z = A[2] + s * (B[2] - A[2]) + t * (C[2] - A[2])
            best = np.where(inside, np.minimum(best, np.abs(z - local[:, 2])), best)
        if (best <= tol).all():
            fits.append(T)
    return fits


def random_faces(count: int, seed: int = 0) -> list[np.ndarray]:
    """``count`` simple faces of 5-12 corners (n, 3), most of them concave: corners at random
    radii round a centre (star-shaped, so simple), each at its own random height."""
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < count:
        n = int(rng.integers(5, 13))
        a = np.sort(rng.uniform(0, 2 * np.pi, n))
        if np.diff(np.r_[a, a[0] + 2 * np.pi]).min() < 0.25:
            continue
        r = rng.uniform(0.25, 1.0, n)
        out.append(np.column_stack([r * np.cos(a), r * np.sin(a), rng.uniform(0.0, 0.3, n)]))
    return out


def build_random(path: str, count: int = 48, seed: int = 0):
    """Author :func:`random_faces` as one mesh each, 1.2 m apart in rows of 8, every other one
    left-handed, under a 16x16 camera (the render is for Blender's triangles, not its pixels);
    returns the faces' world corners."""
    from pxr import UsdGeom

    from lfusd.author.labels import set_class_label
    from lfusd.author.rigs import add_rig
    from lfusd.author.stage import new_stage
    from lfusd.camera import RigSpec

    stage = new_stage(path, 1, 1)
    faces = []
    for k, P in enumerate(random_faces(count, seed)):
        W = P * (0.5, 0.5, 1.0) + ((k % 8 - 3.5) * 1.2, (k // 8 - 2.5) * 1.2, 0.0)
        m = UsdGeom.Mesh.Define(stage, f"/World/F{k:03d}")
        m.CreatePointsAttr([tuple(map(float, p)) for p in W])
        m.CreateFaceVertexCountsAttr([len(W)])
        m.CreateFaceVertexIndicesAttr(list(range(len(W))))
        m.CreateSubdivisionSchemeAttr("none")
        m.CreateOrientationAttr("leftHanded" if k % 2 else "rightHanded")
        set_class_label(m.GetPrim(), "face")
        faces.append(W)
    add_rig(stage, RigSpec(name="main", rows=1, cols=1, width=16, height=16, focal_length_mm=20.0, at=(0, 0, 12), look_at=(0, 0, 0)))
    stage.Save()
    return faces
