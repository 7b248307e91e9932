"""The blur key's model (lfusd.truth.blur) against hand-computed image paths."""

from __future__ import annotations

import numpy as np

from lfusd.camera import Camera
from lfusd.data.passes import RawPasses
from lfusd.truth.blur import blur_extent

K = np.array([[100.0, 0, 8], [0, 100.0, 6], [0, 0, 1]])


def _passes(p0, nxt, prv, cam):
    h, w = 2, 3
    depth = np.full((h, w), np.inf, np.float32)
    depth[0, 0] = 1.0  # one surface pixel; the rest background
    grid = lambda p: np.broadcast_to(np.asarray(p, np.float64), (h, w, 3)).copy()  # noqa: E731
    return RawPasses(depth=depth, vector=np.zeros((h, w, 4), np.float32), camera=cam, position=grid(p0),
                     next_position=grid(nxt), prev_position=grid(prv))


class _Cam:
    def __init__(self, cam):
        self.camera = cam


def test_a_point_approaching_a_static_camera_blurs_along_its_projected_segment():
    cam = Camera(K, np.eye(4))
    p0, p1, pm = np.array([0.5, 0.2, 4.0]), np.array([0.9, 0.2, 2.0]), np.array([0.3, 0.1, 5.0])
    out = blur_extent(_passes(p0, p1, pm, cam), _Cam(cam), _Cam(cam), shutter=0.5)

    def uv(p):
        return K[:2, :2] @ (p[:2] / p[2]) + K[:2, 2]

    # by hand: a quarter frame on either side, along straight lines in the world and so in the image
    want = np.linalg.norm(uv(p0 + 0.25 * (p1 - p0)) - uv(p0)) + np.linalg.norm(uv(p0 + 0.25 * (pm - p0)) - uv(p0))
    assert abs(out[0, 0] - want) < 1e-4
    assert (out.ravel()[1:] == 0).all()  # background: no surface, no blur


def test_a_point_that_moves_with_the_camera_does_not_blur_and_an_unknown_neighbour_is_nan():
    move = np.array([0.2, -0.1, 0.05])
    c0, c1, cm = (np.eye(4) for _ in range(3))
    c1[:3, 3], cm[:3, 3] = move, -move
    p0 = np.array([0.1, 0.2, 3.0])
    cur = _passes(p0, p0 + move, p0 - move, Camera(K, c0))
    out = blur_extent(cur, _Cam(Camera(K, c1)), _Cam(Camera(K, cm)), shutter=1.0)
    assert abs(out[0, 0]) < 1e-6
    assert np.isnan(blur_extent(cur, None, _Cam(Camera(K, cm)), shutter=1.0)[0, 0])
