"""The ``blur`` key (render-video --shutter): per pixel, the length in pixels of the image-space path
that the surface point seen there at frame t follows while the shutter is open (t - s/2 to t + s/2).

Model (docs/CONVENTIONS.md, "Camera effects"): between t and t+1 (and t-1) the point moves linearly
in the world from its position at t to its position then (the raw passes' position and
next_position / prev_position), and the camera's centre linearly and its rotation along the shortest
arc between its poses; the path is projected at SUBSTEPS times per half of the shutter and its
polyline length summed. For a static camera the projection of a straight path is straight, so the
sum is exact at any SUBSTEPS.
"""

from __future__ import annotations

import numpy as np

from ..camera import Camera, project
from ..data.passes import RawPasses
from ..keys import BACKGROUND_DEPTH

SUBSTEPS = 8


def _camera_at(a: Camera, b: Camera, s: float) -> Camera:
    """The camera a fraction ``s`` of the way from ``a`` to ``b`` (centre lerped, rotation slerped)."""
    ma, mb = np.asarray(a.cam_to_world, np.float64), np.asarray(b.cam_to_world, np.float64)
    if np.array_equal(ma, mb):
        return a
    from scipy.spatial.transform import Rotation, Slerp

    m = np.eye(4)
    m[:3, :3] = Slerp([0.0, 1.0], Rotation.from_matrix([ma[:3, :3], mb[:3, :3]]))(s).as_matrix()
    m[:3, 3] = (1 - s) * ma[:3, 3] + s * mb[:3, 3]
    return Camera(a.K, m, a.dist)


def blur_extent(cur: RawPasses, nxt, prv, shutter: float) -> np.ndarray:
    """The ``blur`` key (H,W) float32 of one view at t, from its raw passes and its neighbours' cameras
    (``nxt`` / ``prv``: anything with ``.camera``, or None where t+1 / t-1 is not in the dataset)."""
    depth = np.asarray(cur.depth)
    surface = np.isfinite(depth) & (depth < BACKGROUND_DEPTH)
    out = np.zeros(depth.shape, np.float64)
    p0 = np.asarray(cur.position, np.float64)[surface]
    for other, moved in ((nxt, cur.next_position), (prv, cur.prev_position)):
        if other is None or moved is None:
            out[surface] = np.nan
            continue
        p1 = np.asarray(moved, np.float64)[surface]
        u0, v0, _ = project(p0, cur.camera)
        length = np.zeros(len(p0))
        for k in range(1, SUBSTEPS + 1):
            s = 0.5 * shutter * k / SUBSTEPS
            u, v, _ = project(p0 + s * (p1 - p0), _camera_at(cur.camera, other.camera, s))
            length += np.hypot(u - u0, v - v0)
            u0, v0 = u, v
        out[surface] += length  # NaN where the point's position then is unknown
    return out.astype(np.float32)
