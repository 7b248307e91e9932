"""render-video --lens with --fstop --focus (issue 40): the OSL lens camera as a thin lens. The focus plane
renders as sharp as through the lens without an aperture, a nearer square spreads over the ellipse the model
images the aperture's disc as, the coc key is that ellipse's largest diameter on a tilted plane (checked
against OpenCV's model), and lfusd verify passes with distortion, defocus and a shutter on."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from support.lens_stage import FSTOP, PLANE_Y, SQUARE, TILT
from support.thinlens_stage import FOCUS, LENS, RIG, SHARP, write_thinlens_stage

from lfusd import Dataset

pytestmark = pytest.mark.render

APERTURE = RIG.focal_length_mm * 1e-3 / FSTOP  # the aperture's diameter in metres
LENS_ARG = ",".join(repr(float(c)) for c in LENS.coeffs)
FRAME, VIEW = 1, (0, 0)


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    from lfusd.cli import main

    root = tmp_path_factory.mktemp("thinlens")
    write_thinlens_stage(root / "s.usda")
    common = ["--quiet", "--device", "cpu", "--light", "none", "--samples", "256", "--lens", LENS_ARG]
    # --verify: exit 0 only when lfusd verify, tracing through the lens, passes with every effect on
    assert main(["render-video", str(root / "s.usda"), "-o", str(root / "thin"), *common, "--fstop", str(FSTOP), "--focus", str(FOCUS),
                 "--shutter", "0.5", "--materials", "--iso", "800", "--verify"]) == 0
    assert main(["render-video", str(root / "s.usda"), "-o", str(root / "lens"), *common, "--keys", "rgb_linear"]) == 0
    return Dataset(root / "thin"), Dataset(root / "lens")


def _undistorted(u: np.ndarray, v: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's undistorted normalised (x, y) of distorted pixels (u, v), iterated to convergence."""
    pts = np.stack([u, v], -1).reshape(-1, 1, 2).astype(np.float64)
    xy = cv2.undistortPointsIter(pts, K, LENS.coeffs, None, None, (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14))
    return xy[:, 0, 0].reshape(u.shape), xy[:, 0, 1].reshape(u.shape)


def _pixel_jacobian(x: np.ndarray, y: np.ndarray, K: np.ndarray) -> np.ndarray:
    """d(u, v)/d(x, y) (..., 2, 2) of OpenCV's projectPoints at undistorted normalised (x, y), by central differences."""
    h = 1e-6

    def project(px, py):
        pts = np.stack([px, py, np.ones_like(px)], -1).reshape(-1, 1, 3)
        uv, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, LENS.coeffs)
        return uv.reshape(*px.shape, 2)

    du_dx = (project(x + h, y) - project(x - h, y)) / (2 * h)
    du_dy = (project(x, y + h) - project(x, y - h)) / (2 * h)
    return np.stack([du_dx, du_dy], -1)


def _blur_ellipse_diameter(z: np.ndarray, M: np.ndarray) -> np.ndarray:
    """The largest diameter in pixels of the aperture's disc at planar depth z imaged through M."""
    return APERTURE * np.abs(1 / FOCUS - 1 / z) * np.linalg.svd(M, compute_uv=False)[..., 0]


def test_coc_is_the_aperture_disc_imaged_through_the_lens_on_a_tilted_plane(renders):
    ds, _ = renders
    K, c2w = ds.intrinsics(VIEW), ds.cam_to_world(FRAME, VIEW)
    v, u = np.mgrid[0 : RIG.height, 0 : RIG.width].astype(np.float64)
    x, y = _undistorted(u, v, K)
    d = np.stack([x, y, np.ones_like(x)], -1) @ c2w[:3, :3].T  # each distorted pixel's ray, camera-frame z = 1
    a = np.radians(TILT)
    n = np.array([-np.sin(a), np.cos(a), 0.0])  # the tilted plane's normal, through (0, PLANE_Y, 0)
    z = (n @ (np.array([0.0, PLANE_Y, 0.0]) - c2w[:3, 3])) / (d @ n)  # closed-form planar depth of the plane at each pixel
    plane = np.isclose(ds.read(FRAME, VIEW, "depth"), z, rtol=1e-4)
    assert plane.sum() > 200 and np.ptp(z[plane]) > 1.0
    M = _pixel_jacobian(x, y, K)
    want = _blur_ellipse_diameter(z, M)
    got = ds.read(FRAME, VIEW, "coc")
    np.testing.assert_allclose(got[plane], want[plane], rtol=1e-4, atol=1e-5)  # atol: 1/S - 1/z cancels near focus (float32 depth)
    assert got[plane].min() < 0.05 and got[plane].max() > 0.8  # in focus across a column, blurred away from it
    # through the lens is not the pinhole's disc: the barrel lens shrinks the blur off-centre
    pinhole = K[0, 0] * APERTURE * np.abs(1 / FOCUS - 1 / z)
    assert (got[plane] / pinhole[plane]).min() < 0.97


def _moments(img: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Total, intensity-weighted mean (u, v) and covariance of an image window."""
    v, u = np.mgrid[0 : img.shape[0], 0 : img.shape[1]].astype(np.float64)
    m = img.sum()
    mean = np.array([(u * img).sum(), (v * img).sum()]) / m
    du, dv = u - mean[0], v - mean[1]
    cov = np.array([[(du * du * img).sum(), (du * dv * img).sum()], [(du * dv * img).sum(), (dv * dv * img).sum()]]) / m
    return m, mean, cov


def _square_pixel(ds: Dataset, centre: tuple[float, float, float]) -> np.ndarray:
    """The distorted pixel (u, v) at which the view's lens images a world point (OpenCV's projectPoints)."""
    cam = ds.camera(FRAME, VIEW)
    R, C = cam.world_to_cam()
    rvec, _ = cv2.Rodrigues(R)
    uv, _ = cv2.projectPoints(np.array([[centre]], np.float64), rvec, -R @ C, cam.K, LENS.coeffs)
    return uv[0, 0]


def test_the_focus_plane_stays_sharp_and_a_nearer_square_spreads_over_the_coc_ellipse(renders):
    ds, lens = renders
    thin, sharp = (d.read(FRAME, VIEW, "rgb_linear").sum(axis=-1).astype(np.float64) for d in (ds, lens))
    K = ds.intrinsics(VIEW)
    # the square in the focus plane: the same image as without the aperture (Monte Carlo noise aside)
    su, sv = np.round(_square_pixel(ds, SHARP[:3])).astype(int)
    win = (slice(sv - 7, sv + 8), slice(su - 7, su + 8))
    (m1, c1, v1), (m0, c0, v0) = _moments(thin[win]), _moments(sharp[win])
    assert abs(m1 / m0 - 1) < 0.03 and np.abs(c1 - c0).max() < 0.05, (m1, m0, c1, c0)
    assert abs(np.trace(v1) / np.trace(v0) - 1) < 0.02, (v1, v0)  # a 0.7 px blur disc would add 2 %
    assert np.abs(thin[win] - sharp[win]).max() < 0.05 * sharp[win].max()
    # the square at planar depth 1 m: its sharp image convolved with the aperture's disc imaged through the
    # lens, an ellipse of covariance (rho^2 / 4) M M^T, rho the disc's radius in undistorted normalised units
    near = _square_pixel(ds, SQUARE[:3])
    bu, bv = np.round(near).astype(int)
    win = (slice(bv - 10, min(bv + 11, RIG.height)), slice(bu - 10, bu + 11))
    (m1, c1, v1), (m0, c0, v0) = _moments(thin[win]), _moments(sharp[win])
    assert abs(m1 / m0 - 1) < 0.03  # the lens moves light, it does not make or lose it
    depth = SQUARE[1] - RIG.at[1]
    x, y = _undistorted(near[:1], near[1:], K)
    M = _pixel_jacobian(x, y, K)[0]
    rho = APERTURE / 2 * abs(1 / FOCUS - 1 / depth)
    want = rho**2 / 4 * M @ M.T
    added = v1 - v0
    assert np.abs(added - want).max() < 0.1 * np.trace(want) / 2, (added, want)
    # the coc key on the square is that ellipse's largest diameter, 4 sqrt of its largest variance
    square = np.isclose(ds.read(FRAME, VIEW, "depth"), depth, rtol=1e-4)
    assert square.sum() > 10
    coc = float(np.median(ds.read(FRAME, VIEW, "coc")[square]))
    assert coc > 4 and abs(coc / float(_blur_ellipse_diameter(np.array(depth), M)) - 1) < 0.02
    assert abs(coc / (4 * np.sqrt(np.linalg.eigvalsh(added)[-1])) - 1) < 0.1
    # the ground truth stays that of the lens centre: every pixel's point is imaged at the pixel
    position = ds.read(FRAME, VIEW, "position").astype(np.float64)
    fg = np.isfinite(position).all(-1)
    cam = ds.camera(FRAME, VIEW)
    R, C = cam.world_to_cam()
    rvec, _ = cv2.Rodrigues(R)
    uv, _ = cv2.projectPoints(position[fg].reshape(-1, 1, 3), rvec, -R @ C, cam.K, LENS.coeffs)
    v, u = np.nonzero(fg)
    assert np.abs(uv[:, 0] - np.stack([u, v], -1)).max() < 0.01


def test_verify_passes_with_every_camera_effect_on_and_the_certificate_names_them(renders):
    from lfusd.data.certificate import certified

    ds, _ = renders
    cert = certified(ds.root)["main"]  # bound to the rendered content, and the binding holds
    assert cert["ok"] and cert["unchecked"] == 0
    assert cert["camera_effects"]["defocus"] == {"fstop": FSTOP, "focus": FOCUS}
    assert cert["camera_effects"]["lens_distortion"]["model"] == LENS.to_dict() and cert["camera_effects"]["motion_blur"] == {"shutter": 0.5}
    assert set(cert["camera_effects"]) == {"motion_blur", "defocus", "sensor_noise", "material_masks", "lens_distortion"}  # issue 40's five
