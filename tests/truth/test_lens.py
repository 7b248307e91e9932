"""Lens distortion (issue 40 item 4): lfusd.camera's Brown-Conrady model and the keys in distorted
pixels (lfusd.truth.lens) against OpenCV's projectPoints, closed-form geometry and analytic images."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from lfusd.camera import (Camera, Distortion, RigSpec, check_distortion, distort_pixels, distorted_ray_directions, look_at_pose,
                          pixel_grid, project_distorted, undistort_pixels, view_distortion, wide_intrinsics)
from lfusd.errors import LfusdError
from lfusd.truth.lens import cast_geometry, flow_distorted, resample_image, undistortion_map

W, H = 48, 36
MODELS = {
    "barrel": Distortion(k1=-0.28, k2=0.09, k3=-0.01),
    "pincushion": Distortion(k1=0.22, k2=0.05),
    "tangential": Distortion(k1=-0.1, p1=0.004, p2=-0.006),
    "all": Distortion(k1=-0.2, k2=0.03, p1=-0.003, p2=0.002, k3=0.004),
}


def _camera(eye=(0.3, -4.0, 1.2), target=(0.0, 0.0, 1.0)) -> Camera:
    K = RigSpec(width=W, height=H).intrinsics()
    return Camera(K, look_at_pose(np.array(eye, float), np.array(target, float)))


def _opencv(points: np.ndarray, cam: Camera, dist: Distortion) -> np.ndarray:
    R, C = cam.world_to_cam()
    rvec, _ = cv2.Rodrigues(R)
    uv, _ = cv2.projectPoints(points.reshape(-1, 1, 3).astype(np.float64), rvec, -R @ C, np.asarray(cam.K, np.float64), dist.coeffs)
    return uv.reshape(*points.shape[:-1], 2)


@pytest.mark.parametrize("name", MODELS)
def test_project_distorted_matches_opencv(name):
    dist, cam = MODELS[name], _camera()
    rng = np.random.default_rng(1)
    # points whose undistorted pixels span the image and a little beyond
    u, v = rng.uniform(-4, W + 3, 400), rng.uniform(-4, H + 3, 400)
    points = cam.cam_to_world[:3, 3] + distorted_ray_directions(u, v, Camera(cam.K, cam.cam_to_world), Distortion()) * rng.uniform(1, 20, 400)[:, None]
    ud, vd, z = project_distorted(points, cam, dist)
    ref = _opencv(points, cam, dist)
    assert np.abs(np.stack([ud, vd], -1) - ref).max() < 0.01
    assert (z > 0).all()


@pytest.mark.parametrize("name", MODELS)
def test_undistort_inverts_the_model_and_agrees_with_opencv(name):
    dist, K = MODELS[name], RigSpec(width=W, height=H).intrinsics()
    u, v = pixel_grid(H, W, np.float64)
    uu, vu = undistort_pixels(u, v, K, dist)
    ub, vb = distort_pixels(uu, vu, K, dist)
    assert np.abs(ub - u).max() < 1e-6 and np.abs(vb - v).max() < 1e-6
    pts = np.stack([u, v], -1).reshape(-1, 1, 2)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    ref = cv2.undistortPointsIter(pts, K, dist.coeffs, None, K, crit).reshape(H, W, 2)
    assert np.abs(np.stack([uu, vu], -1) - ref).max() < 0.01


def test_rays_of_distorted_pixels_project_back_through_opencv():
    dist, cam = MODELS["all"], _camera()
    u, v = pixel_grid(H, W, np.float64)
    points = cam.cam_to_world[:3, 3] + distorted_ray_directions(u, v, cam, dist) * 3.0
    assert np.abs(_opencv(points, cam, dist) - np.stack([u, v], -1)).max() < 0.01


def test_a_model_that_folds_over_the_image_is_refused():
    K = RigSpec(width=W, height=H).intrinsics()
    for name in MODELS:
        check_distortion(MODELS[name], K, W, H)
    with pytest.raises(LfusdError, match="folds over the image"):
        check_distortion(Distortion(k1=-2.5), K, W, H)
    with pytest.raises(LfusdError, match="unknown coefficient"):
        Distortion.from_dict({"k4": 0.1})
    with pytest.raises(LfusdError, match="finite"):
        Distortion(k1=float("nan"))
    assert Distortion.from_dict(MODELS["all"].to_dict()) == MODELS["all"]


@pytest.mark.parametrize("name", MODELS)
def test_wide_pinhole_holds_every_distorted_pixel(name):
    dist, K = MODELS[name], RigSpec(width=W, height=H).intrinsics()
    Kw, ww, hw = wide_intrinsics(K, dist, W, H, margin=2.0)
    assert Kw[0, 0] == K[0, 0] and Kw[0, 2] == (ww - 1) / 2 and Kw[1, 2] == (hw - 1) / 2  # centred, same focal length
    assert ww >= W and hw >= H and (ww - W) % 2 == 0 and (hw - H) % 2 == 0  # K's pixel lattice
    mu, mv = undistortion_map(K, dist, W, H, Kw)
    assert mu.min() >= 1.5 and mv.min() >= 1.5 and mu.max() <= ww - 2.5 and mv.max() <= hw - 2.5
    if name == "barrel":
        assert ww > W and hw > H  # a barrel lens sees more than its pinhole


def test_resampled_image_equals_the_analytic_image_at_each_distorted_ray():
    # a wide image linear in the normalised coordinates: bilinear interpolation reproduces it exactly,
    # so the distorted image must equal it at every distorted pixel's undistorted ray
    dist, K = MODELS["all"], RigSpec(width=W, height=H).intrinsics()
    Kw, ww, hw = wide_intrinsics(K, dist, W, H)
    f = lambda x, y: np.stack([0.5 + 0.7 * x, 0.5 - 0.4 * y, 0.2 + 0.3 * x + 0.3 * y], -1)  # noqa: E731
    uw, vw = pixel_grid(hw, ww, np.float64)
    wide = f((uw - Kw[0, 2]) / Kw[0, 0], (vw - Kw[1, 2]) / Kw[1, 1])
    out = resample_image(wide, *undistortion_map(K, dist, W, H, Kw))
    u, v = pixel_grid(H, W, np.float64)
    uu, vu = undistort_pixels(u, v, K, dist)
    assert np.abs(out - f((uu - K[0, 2]) / K[0, 0], (vu - K[1, 2]) / K[1, 1])).max() < 1e-5
    with pytest.raises(ValueError, match="outside the wide image"):
        resample_image(wide[2:-2, 2:-2], *undistortion_map(K, Distortion(k1=-0.35), W, H, Kw))


def _scene():
    """A ground plane z = 0 (instance 1) and an axis-aligned box 0.6 m wide standing on it (instance 2)."""
    plane = np.array([[-20, -20, 0], [20, -20, 0], [20, 20, 0], [-20, 20, 0]], np.float32)
    box = np.array([[x, y, z] for z in (0, 0.6) for y in (-0.3, 0.3) for x in (-0.3, 0.3)], np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = [[0, 1, 2], [0, 2, 3]] + [[4 + a, 4 + b, 4 + c] for q in quads for a, b, c in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))]
    return np.concatenate([plane, box]), np.array(tris, np.int32), np.array([1, 1] + [2] * 12, np.int32)


def _box_hit(origin, dirs):
    """Closed-form slab test against the box of :func:`_scene`: (hit, t)."""
    lo, hi = np.array([-0.3, -0.3, 0.0]), np.array([0.3, 0.3, 0.6])
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - origin) / dirs, (hi - origin) / dirs
    tn, tf = np.minimum(t1, t2).max(-1), np.maximum(t1, t2).min(-1)
    return (tn <= tf) & (tf > 0), tn


@pytest.mark.parametrize("name", ["barrel", "pincushion", "all"])
def test_distorted_geometry_keys_match_opencv_and_closed_form(name):
    dist, cam = MODELS[name], _camera(eye=(0.4, -3.0, 1.3), target=(0.0, 0.0, -0.4))
    keys = cast_geometry(*_scene(), cam, dist, W, H)
    u, v = pixel_grid(H, W, np.float64)
    found = np.isfinite(keys["depth"])
    assert found.all()  # the plane fills the view
    # every pixel's surface point is imaged by OpenCV at that very pixel
    assert np.abs(_opencv(keys["position"].astype(np.float64), cam, dist) - np.stack([u, v], -1)).max() < 0.01
    # planar depth and the instance from closed-form intersections along each distorted pixel's ray
    origin, dirs = cam.world_to_cam()[1], distorted_ray_directions(u, v, cam, dist)
    in_box, t_box = _box_hit(origin, dirs)
    t_plane = -origin[2] / dirs[..., 2]
    depth = np.where(in_box, np.minimum(t_box, np.where(t_plane > 0, t_plane, np.inf)), t_plane)
    assert np.abs(keys["depth"] / depth - 1).max() < 1e-4
    inside = in_box & (t_box < t_plane)
    assert inside.any() and (~inside).any()
    # the instance is exact where the ray is not within float32 reach of the box's silhouette
    edge = np.abs(t_box - t_plane) < 1e-4
    assert (keys["instance"][~edge] == np.where(inside, 2, 1)[~edge]).all()


@pytest.mark.parametrize("name", ["barrel", "all"])
def test_distorted_flow_matches_opencv_at_the_next_frame(name):
    dist, cam = MODELS[name], _camera(eye=(0.4, -3.0, 1.3), target=(0.0, 0.0, -0.4))
    dist_next = view_distortion(dist, (0, 1), seed=7, spread=0.05)  # another view's lens: both ends through their model
    keys = cast_geometry(*_scene(), cam, dist, W, H)
    # every point moves rigidly (a turn about z and a shift); the camera moves too
    a = 0.05
    Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    nxt = keys["position"].astype(np.float64) @ Rz.T + np.array([0.05, -0.02, 0.0])
    cam_next = Camera(cam.K, look_at_pose(np.array([0.5, -2.9, 1.3]), np.array([0.0, 0.0, -0.4])))
    flow, ok = flow_distorted(nxt, cam_next, dist_next)
    assert ok.all()
    u, v = pixel_grid(H, W, np.float64)
    assert np.abs(flow + np.stack([u, v], -1) - _opencv(nxt, cam_next, dist_next)).max() < 0.01


def test_flow_is_invalid_where_a_point_is_behind_or_beyond_the_fold():
    dist, cam = Distortion(k1=-0.3), _camera()
    forward = cam.cam_to_world[:3, 2]
    here = cam.cam_to_world[:3, 3]
    side = cam.cam_to_world[:3, 0]
    pts = np.array([[here + 3 * forward,          # in view
                     here - 3 * forward,          # behind the camera
                     here + 2 * forward + 3.2 * side,  # beyond the fold (x = 1.6): the model would fold it back into the image
                     [np.nan] * 3]])
    ud, _, _ = project_distorted(pts[0, 2], cam, dist)
    assert 0 <= ud <= W - 1  # folded back into the image by the model
    flow, ok = flow_distorted(pts, cam, dist)
    assert ok.tolist() == [[True, False, False, False]]
    assert np.isfinite(flow[0, 0]).all() and np.isnan(flow[0, 1:]).all()


def test_each_view_draws_its_own_lens_reproducibly():
    base = MODELS["all"]
    assert view_distortion(base, (0, 0)) == base
    a, b = view_distortion(base, (0, 0), seed=3, spread=0.1), view_distortion(base, (0, 1), seed=3, spread=0.1)
    assert a != b and a == view_distortion(base, (0, 0), seed=3, spread=0.1)
    assert a != view_distortion(base, (0, 0), seed=4, spread=0.1)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_a_camera_with_a_lens_projects_and_casts_through_it(dtype):
    from lfusd.camera import backproject, project, ray_directions, ray_lengths

    dist, cam = MODELS["all"], _camera()
    lens = Camera(cam.K, cam.cam_to_world, dist)
    u, v = pixel_grid(H, W, dtype)
    z = np.linspace(1.0, 30.0, H * W).reshape(H, W).astype(dtype)
    points = backproject(u, v, z, lens)
    assert points.dtype == dtype
    # the point the lens sees at each pixel is where OpenCV images it, at the planar depth asked for
    tol = 0.01 if dtype == np.float32 else 1e-6
    assert np.abs(_opencv(points.astype(np.float64), lens, dist) - np.stack([u, v], -1)).max() < tol
    pu, pv, pz = project(points, lens)
    assert np.abs(pu - u).max() < tol and np.abs(pv - v).max() < tol and np.abs(pz / z - 1).max() < 1e-5
    dirs = ray_directions(u, v, lens)
    assert np.abs(dirs @ cam.world_to_cam()[0][2] - 1).max() < 1e-5  # camera-frame z = 1
    assert np.abs(ray_lengths(cam.K, H, W, dist) - np.linalg.norm(distorted_ray_directions(u.astype(np.float64), v.astype(np.float64), cam, dist), axis=-1)).max() < 1e-12
    # without a lens the pinhole is unchanged
    assert np.abs(project(points, cam)[0] - project(points, Camera(cam.K, cam.cam_to_world, Distortion()))[0]).max() == 0


def test_disparity_of_a_distorted_view_is_the_shifted_cameras_column_and_the_pinholes_without_a_lens():
    from lfusd.data.passes import disparity, disparity_distorted
    from lfusd.camera import point_disparity

    dist, cam = MODELS["all"], _camera()
    K = np.asarray(cam.K, np.float64)
    rng = np.random.default_rng(4)
    depth = rng.uniform(1.0, 6.0, (H, W)).astype(np.float32)
    depth[0, :5] = np.inf  # no surface: 0, as the pinhole key has it
    b = 0.1
    got = disparity_distorted(depth, K, dist, b)
    u, v = pixel_grid(H, W, np.float64)
    lensed = Camera(K, cam.cam_to_world, dist)
    from lfusd.camera import backproject

    P = backproject(u, v, np.where(np.isfinite(depth), depth, 1.0).astype(np.float64), lensed)
    shifted = np.array(cam.cam_to_world, np.float64)
    shifted[:3, 3] += b * shifted[:3, 0]
    want = u - _opencv(P, Camera(K, shifted), dist)[..., 0]  # where OpenCV images the point in the moved camera
    fg = np.isfinite(depth)
    assert np.abs(got[fg] - want[fg]).max() < 1e-3 and (got[~fg] == 0).all()
    np.testing.assert_allclose(point_disparity(P, lensed, b)[fg], want[fg], atol=1e-6)  # the motion keys' disparity, the same
    np.testing.assert_allclose(disparity_distorted(depth, K, Distortion(), b)[fg], disparity(depth, K[0, 0], b)[fg], rtol=1e-5)


def test_visibility_and_mixed_through_the_lens():
    """A point outside the pinhole's image that the barrel lens brings in is visible through it (and not
    through the pinhole); one beyond the fold is not; a wall hides what lies behind it as without a lens."""
    from lfusd.truth.visibility import Occluders, mixed_footprint, visible

    dist, cam = MODELS["barrel"], _camera()
    K = np.asarray(cam.K, np.float64)
    lensed = Camera(K, cam.cam_to_world, dist)
    corner_in = undistort_pixels(np.array([1.0]), np.array([1.0]), K, dist)  # the ray the lens images near pixel (1, 1)
    from lfusd.camera import backproject

    inside = backproject(corner_in[0], corner_in[1], np.array([3.0]), Camera(K, cam.cam_to_world))
    assert corner_in[0][0] < -0.5  # outside the pinhole's image
    far = backproject(np.array([-40.0 * W]), np.array([H / 2.0]), np.array([3.0]), Camera(K, cam.cam_to_world))  # far past the fold
    points = np.concatenate([inside, far]).astype(np.float32)
    empty = Occluders(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32))
    assert visible(points, np.ones(2, bool), lensed, H, W, empty).tolist() == [True, False]
    assert visible(points, np.ones(2, bool), cam, H, W, empty).tolist() == [False, False]
    # a wall between the camera and the point hides it
    C = cam.world_to_cam()[1]
    mid = C + 0.5 * (inside[0] - C)
    n = np.cross(inside[0] - C, [0.0, 0.0, 1.0])
    n /= np.linalg.norm(n)
    up = np.cross(n, inside[0] - C)
    up /= np.linalg.norm(up)
    quad = np.array([mid + a * n + c * up for a, c in ((-1, -1), (1, -1), (1, 1), (-1, 1))], np.float32)
    wall = Occluders(quad, np.array([[0, 1, 2], [0, 2, 3]], np.int32), np.array([1, 1], np.int32))
    assert visible(points[:1], np.ones(1, bool), lensed, H, W, wall).tolist() == [False]
    # mixed: a plane parallel to the image, one instance, no motion: no pixel mixed; a half plane's edge is mixed
    R = np.asarray(cam.cam_to_world, np.float64)[:3, :3]
    centre = C + 4.0 * R[:, 2]
    plane = np.array([centre + 50 * (a * R[:, 0] + c * R[:, 1]) for a, c in ((-1, -1), (1, -1), (1, 1), (-1, 1))], np.float32)
    flat = Occluders(plane, np.array([[0, 1, 2], [0, 2, 3]], np.int32), np.array([1, 1], np.int32))
    assert not mixed_footprint(lensed, H, W, flat, flat, lensed).any()
    x0 = 1.2  # the half plane x >= x0 (camera frame) at depth 4: a straight column in the pinhole, a curve through the lens
    half = np.array([centre + (x0 + 50 * a) * R[:, 0] + 50 * c * R[:, 1] for a, c in ((0, -1), (1, -1), (1, 1), (0, 1))], np.float32)
    tris = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    edge = mixed_footprint(lensed, H, W, Occluders(half, tris, np.array([1, 1], np.int32)))
    vs = np.linspace(-20 * H, 20 * H, 40001)
    ud, vd = distort_pixels(np.full_like(vs, K[0, 2] + K[0, 0] * x0 / 4.0), vs, K, dist)  # the edge's image through the lens
    curve = np.stack([ud, vd], -1)[(vd > -1) & (vd < H) & (ud > -1) & (ud < W)]
    rows, cols = np.nonzero(edge)
    assert set(rows.tolist()) == set(range(H))  # every row crosses the edge once
    near = np.min(np.hypot(cols[:, None] - curve[None, :, 0], rows[:, None] - curve[None, :, 1]), axis=1)
    assert near.max() <= 1.0  # each mixed pixel's footprint holds the curve (within a pixel's reach)
    assert np.ptp(curve[:, 0]) > 2  # curved: the pinhole's straight column would not do
    assert (mixed_footprint(cam, H, W, Occluders(half, tris, np.array([1, 1], np.int32))) != edge).any()
