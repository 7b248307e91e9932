"""Keys in distorted pixel coordinates (lens distortion, issue 40 item 4; the model: lfusd.camera.Distortion).

A lens-distorted view is rendered as a wider pinhole (:func:`lfusd.camera.wide_intrinsics`: same
focal length, an image holding the undistorted ray of every distorted pixel) and brought into the
distorted image here:

- the image by interpolation at each distorted pixel's undistorted position in the wide image
  (:func:`resample_image`, bilinear: an image has no exact value between pixel centres);
- the geometry of each distorted pixel exactly, by casting its own ray (the lens's ray through the
  pixel centre) against the frame's triangles (:func:`cast_geometry`: depth, position, instance);
- the motion of each distorted pixel exactly, through the model at both ends:
  flow = distort(project(point at t+1, camera at t+1)) - distorted pixel (:func:`flow_distorted`).

Nothing is interpolated in the ground truth: a pixel whose label cannot be known is invalid.
"""

from __future__ import annotations

import numpy as np

from ..camera import FOLD_TOL_PX, Camera, Distortion, distorted_ray_directions, pixel_grid, project, project_distorted, undistort_pixels



def undistortion_map(K: np.ndarray, dist: Distortion, width: int, height: int, K_wide: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) float64 (H x W): where the ray of each distorted pixel centre lands in the wide pinhole image of ``K_wide``."""
    u, v = pixel_grid(height, width, np.float64)
    uu, vu = undistort_pixels(u, v, K, dist)
    K, Kw = np.asarray(K, np.float64), np.asarray(K_wide, np.float64)
    return (uu - K[0, 2]) / K[0, 0] * Kw[0, 0] + Kw[0, 2], (vu - K[1, 2]) / K[1, 1] * Kw[1, 1] + Kw[1, 2]


def resample_image(image: np.ndarray, map_u: np.ndarray, map_v: np.ndarray) -> np.ndarray:
    """The wide image bilinearly interpolated at (map_u, map_v) (:func:`undistortion_map`), per channel, float32.
    A position outside the wide image (impossible with wide_intrinsics' margin) raises ValueError."""
    h, w = image.shape[:2]
    if not (np.isfinite(map_u).all() and np.isfinite(map_v).all()
            and map_u.min() >= 0 and map_v.min() >= 0 and map_u.max() <= w - 1 and map_v.max() <= h - 1):
        raise ValueError("a distorted pixel's ray falls outside the wide image; render it with lfusd.camera.wide_intrinsics")
    # float64 weights (cv2.remap quantises positions to 1/32 px)
    u0 = np.minimum(np.floor(map_u).astype(np.int64), w - 2)
    v0 = np.minimum(np.floor(map_v).astype(np.int64), h - 2)
    a, b = map_u - u0, map_v - v0
    img = np.asarray(image, np.float64)
    if img.ndim == 3:
        a, b = a[..., None], b[..., None]
    out = ((1 - a) * (1 - b) * img[v0, u0] + a * (1 - b) * img[v0, u0 + 1]
           + (1 - a) * b * img[v0 + 1, u0] + a * b * img[v0 + 1, u0 + 1])
    return out.astype(np.float32)


def cast_geometry(vertices: np.ndarray, triangles: np.ndarray, instance: np.ndarray, cam: Camera, dist: Distortion,
                  width: int, height: int) -> dict[str, np.ndarray]:
    """The geometry keys of each distorted pixel, from its own ray cast against a frame's triangles
    (geometry.npz): ``depth`` (planar, inf where the ray leaves the scene), ``position`` (NaN there)
    and ``instance`` (the hit triangle's object index, 0 there)."""
    import open3d as o3d

    from .visibility import _scene

    u, v = pixel_grid(height, width, np.float64)
    dirs = distorted_ray_directions(u, v, cam, dist)  # camera-frame z = 1: the ray parameter is planar depth
    origin = cam.world_to_cam()[1]
    rays = np.concatenate([np.broadcast_to(origin, dirs.shape), dirs], axis=-1)
    hit = _scene(np.asarray(vertices, np.float32), triangles).cast_rays(o3d.core.Tensor(np.ascontiguousarray(rays, np.float32)))
    t = hit["t_hit"].numpy().astype(np.float64)
    ids = hit["primitive_ids"].numpy()
    found = np.isfinite(t)
    position = np.where(found[..., None], origin + dirs * np.where(found, t, 0.0)[..., None], np.nan)
    inst = np.zeros((height, width), np.int32)
    inst[found] = np.asarray(instance, np.int32)[ids[found]]
    return {"depth": np.where(found, t, np.inf).astype(np.float32), "position": position.astype(np.float32), "instance": inst}


def flow_distorted(point_next: np.ndarray, cam_next: Camera, dist_next: Distortion) -> tuple[np.ndarray, np.ndarray]:
    """(flow (H x W x 2), in_front (H x W)): where the surface point seen at each distorted pixel of frame t
    lies at t+1 (``point_next``, world, NaN where unknown) in the distorted image of ``cam_next``, minus the
    pixel; NaN flow where the point is unknown, behind the camera or beyond the lens's fold at t+1 (``in_front`` False)."""
    h, w = point_next.shape[:2]
    u, v = pixel_grid(h, w, np.float64)
    ud, vd, z = project_distorted(point_next, cam_next, dist_next)
    ok = np.isfinite(ud) & np.isfinite(vd) & (z > 0)
    # beyond the model's fold a far-off point would land inside the image: the lens images it there
    # only if undistorting its pixel gives its ray back
    K = np.asarray(cam_next.K, np.float64)
    with np.errstate(invalid="ignore"):
        uu, vu, _ = project(np.asarray(point_next, np.float64), Camera(K, cam_next.cam_to_world))  # the pinhole of K
        ub, vb = undistort_pixels(np.where(ok, ud, K[0, 2]), np.where(ok, vd, K[1, 2]), K, dist_next)
        ok &= (np.abs(ub - uu) <= FOLD_TOL_PX) & (np.abs(vb - vu) <= FOLD_TOL_PX)
    flow = np.stack([ud - u, vd - v], axis=-1)
    flow[~ok] = np.nan
    return flow.astype(np.float32), ok

