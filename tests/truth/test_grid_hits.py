"""verify's first hits of a view's full grid of rays (pixel centres, pixel corners), found per triangle
(lfusd.truth._grid_numba) instead of cast ray by ray: the same answer as Open3D's cast wherever the
ray is not within rounding of two surfaces, checked ray by ray in float64, and no ray passing
between two triangles that share an edge."""

from __future__ import annotations

import numpy as np
import pytest

from lfusd.camera import Camera
from lfusd.truth._grid_numba import grid_first_hits

EDGE = 1e-5  # a ray this close to a triangle's edge (barycentric) meets it within float32 rounding
DEPTH = 1e-5  # two surfaces this close in depth (relative) along a ray: a tie


def _camera(rng, W, H):
    K = np.array([[W * rng.uniform(0.8, 1.5), 0, W / 2 + rng.uniform(-3, 3)], [0, W * rng.uniform(0.8, 1.5), H / 2], [0, 0, 1.0]])
    a, b = rng.uniform(-0.4, 0.4, 2)
    Ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    Rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    c2w = np.eye(4)
    c2w[:3, :3] = Ry @ Rx
    c2w[:3, 3] = rng.uniform(-2, 2, 3)
    return K, c2w


def _scene(rng, cam: Camera, W, H):
    """Triangles shaped like a stage's and like its hard cases, in world coordinates: (V, T)."""
    A = cam._pixel_to_world(np.float64)
    O = np.asarray(cam.cam_to_world, np.float64)[:3, 3]
    at = lambda u, v, z: O + z * (A @ np.array([u, v, 1.0]))  # noqa: E731  (the point at camera depth z on the ray through (u, v))
    tris = []
    for _ in range(60):  # small and medium triangles in view
        u, v, z = rng.uniform(-5, W + 5), rng.uniform(-5, H + 5), rng.uniform(1, 20)
        s = rng.choice([0.02, 0.5, 4, 20])
        tris.append([at(u + rng.normal(0, s), v + rng.normal(0, s), z * rng.uniform(0.9, 1.1)) for _ in range(3)])
    # a closed box (shared edges), a floor crossing the camera's plane, one wholly behind it
    lo, hi = at(W * 0.3, H * 0.3, 6.0), at(W * 0.6, H * 0.7, 8.0)
    c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    for q in ((0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)):
        tris += [[c[q[0]], c[q[1]], c[q[2]]], [c[q[0]], c[q[2]], c[q[3]]]]
    down = -np.asarray(cam.cam_to_world, np.float64)[:3, 1]
    fwd = -np.asarray(cam.cam_to_world, np.float64)[:3, 2]
    fwd = fwd if (A @ np.array([W / 2, H / 2, 1.0])) @ fwd > 0 else -fwd
    side = np.cross(fwd, down)
    g = O + 1.5 * down
    tris += [[g - 30 * fwd - 30 * side, g + 60 * fwd - 30 * side, g + 60 * fwd + 30 * side],
             [g - 30 * fwd - 30 * side, g + 60 * fwd + 30 * side, g - 30 * fwd + 30 * side]]
    tris.append([O - 5 * fwd, O - 6 * fwd + side, O - 6 * fwd - down])
    # edge-on: a triangle in a plane through the centre
    p, q = A @ np.array([W * 0.2, H * 0.5, 1.0]), A @ np.array([W * 0.8, H * 0.5, 1.0])
    tris.append([O + 3 * p, O + 9 * p, O + 5 * q])
    V = np.array(tris, np.float64).reshape(-1, 3)
    return V, np.arange(len(V), dtype=np.int64).reshape(-1, 3)


def _on(V, T, k, O, d):
    """Triangle k against the ray O + t d in float64: (t, the least barycentric, |cos| to its normal)."""
    a, b, c = V[T[k]]
    e1, e2 = b - a, c - a
    n = np.cross(e1, e2)
    with np.errstate(divide="ignore", invalid="ignore"):  # a ray in the triangle's plane: no crossing (NaN)
        t = n @ (a - O) / (n @ d)
        w = O + t * d - a
        d00, d01, d11, d20, d21 = e1 @ e1, e1 @ e2, e2 @ e2, w @ e1, w @ e2
        den = d00 * d11 - d01 * d01
        b1, b2 = (d11 * d20 - d01 * d21) / den, (d00 * d21 - d01 * d20) / den
    return t, min(1 - b1 - b2, b1, b2), abs(n @ d) / (np.linalg.norm(n) * np.linalg.norm(d))


def _grid(V, T, cam, u0, v0, W, H):
    A = np.ascontiguousarray(cam._pixel_to_world(np.float64))
    O = np.ascontiguousarray(np.asarray(cam.cam_to_world, np.float64)[:3, 3])
    n = W * H
    depth, row, mesh, tri = np.empty(n), np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64)
    use = np.ones(len(T), bool)
    grid_first_hits(V, T, use, O, A, np.linalg.inv(A), float(u0), float(v0), W, H, depth, row,
                    np.zeros(len(T), np.int64), np.zeros(1, np.int64), mesh, tri)
    assert np.array_equal(mesh, np.where(row >= 0, 0, -1)) and np.array_equal(tri, row)
    return depth, row, A, O


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("corners", [False, True])
def test_grid_hits_are_open3ds_first_hits_but_where_two_surfaces_tie(seed, corners):
    """Every ray of the grid: the triangle Open3D's cast names, or, where the two differ, a tie that
    float32 rounding decides (the ray within EDGE of an edge of either triangle, or the two depths
    within DEPTH); a grid hit is on its triangle at the depth it reports."""
    import open3d as o3d

    rng = np.random.default_rng(seed)
    W, H = 64, 48
    K, c2w = _camera(rng, W, H)
    cam = Camera(K, c2w)
    V, T = _scene(rng, cam, W, H)
    u0, v0, w, h = (-0.5, -0.5, W + 1, H + 1) if corners else (0.0, 0.0, W, H)
    depth, row, A, O = _grid(V, T, cam, u0, v0, w, h)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(V.astype(np.float32)), o3d.core.Tensor(T.astype(np.uint32)))
    uu, vv = np.tile(np.arange(w) + u0, h), np.repeat(np.arange(h) + v0, w)
    d = (A @ np.stack([uu, vv, np.ones_like(uu)])).T
    rays = np.concatenate([np.broadcast_to(O, d.shape), d], 1).astype(np.float32)
    ans = scene.cast_rays(o3d.core.Tensor(rays))
    prim = np.where(np.isfinite(ans["t_hit"].numpy()), ans["primitive_ids"].numpy().astype(np.int64), -1)
    assert (row >= 0).sum() > 0.5 * row.size  # the scene fills most of the view
    differ = 0
    for i in range(row.size):
        if row[i] >= 0:  # on its triangle, at its depth
            t, least, _ = _on(V, T, row[i], O, d[i])
            assert least >= -1e-9 and abs(t - depth[i]) <= 1e-9 * t, (i, least, t, depth[i])
        if row[i] == prim[i]:
            continue
        differ += 1
        ours = _on(V, T, row[i], O, d[i]) if row[i] >= 0 else None
        theirs = _on(V, T, prim[i], O, d[i]) if prim[i] >= 0 else None
        at_edge = any(x is not None and (abs(x[1]) < EDGE or x[2] < EDGE) for x in (ours, theirs))
        same_depth = ours is not None and theirs is not None and abs(ours[0] - theirs[0]) <= DEPTH * ours[0]
        assert at_edge or same_depth, (i % w, i // w, row[i], prim[i], ours, theirs)
    assert differ <= 0.01 * row.size


def test_no_ray_passes_between_triangles_that_share_an_edge():
    """A tilted plane of triangles whose shared edges lie along grid rays (its vertices placed on the
    rays through every other sample, each square split along a diagonal through a sample): every ray
    hits it, none reaching the wall behind. A ray exactly on an edge is inside both triangles' tests
    or one of them, as the shared edge's volume is one float expression (lfusd.truth._grid_numba)."""
    rng = np.random.default_rng(7)
    W = H = 41
    K, c2w = _camera(rng, W, H)
    cam = Camera(K, c2w)
    A = cam._pixel_to_world(np.float64)
    O = np.asarray(c2w, np.float64)[:3, 3]
    n = 23  # vertices at samples -2, 0, 2, ..., 42 of each axis: beyond the grid
    idx = lambda i, j: i * n + j  # noqa: E731
    V = []
    for i in range(n):
        for j in range(n):
            u, v = 2.0 * j - 2, 2.0 * i - 2
            V.append(O + (5 + 0.05 * u + 0.03 * v) * (A @ np.array([u, v, 1.0])))  # a tilted plane
    T = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, e = idx(i, j), idx(i, j + 1), idx(i + 1, j + 1), idx(i + 1, j)
            T += [[a, b, c], [a, c, e]] if (i + j) % 2 else [[a, e, c], [a, c, b]]
    wall = len(V)
    V += [O + 20 * (A @ np.array(p)) for p in ([-50, -50, 1.0], [100, -50, 1.0], [-50, 100, 1.0], [100, 100, 1.0])]
    T += [[wall, wall + 1, wall + 3], [wall, wall + 3, wall + 2]]
    V, T = np.array(V), np.array(T, np.int64)
    for u0, v0, w, h in ((0.0, 0.0, W, H), (-0.5, -0.5, W + 1, H + 1)):
        depth, row, _, _ = _grid(V, T, cam, u0, v0, w, h)
        through = np.flatnonzero(row >= len(T) - 2)
        assert through.size == 0, [(k % w + u0, k // w + v0) for k in through[:10]]
        assert np.all(depth < 10)
