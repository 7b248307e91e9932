"""Ray flow (lfusd.evaluation.rayflow, after Ma, Smith & Gupta 2018) against analytic motion: a
light field of a textured fronto-parallel plane, ray-traced here in closed form, translating in 3-D
by a known (dX, dY, dZ); and the composition of the submission arrays by hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest

from lfusd.errors import LfusdError
from lfusd.evaluation.rayflow import compose, ray_flow

F, N, B, Z0 = 40.0, 48, 0.1, 2.0  # px, px, m, m: disparity F B / Z0 = 2 px per baseline step
C = (N - 1) / 2
K = np.array([[F, 0, C], [0, F, C], [0, 0, 1.0]])
MOTION = np.array([0.02, -0.015, 0.1])  # m: about 0.4 px of flow, and 5 % of depth (1.2 px at the border)
OFFSETS = {(r, c): (c - 1.0, r - 1.0) for r in range(3) for c in range(3)}  # a 3x3 rig, x right, y down


def _texture(X, Y):
    """Three channels of smooth sinusoids on the plane (wavelengths 0.25-0.6 m, 5-12 px at Z0)."""
    rng = np.random.default_rng(3)
    out = []
    for c in range(3):
        acc = 0.5
        for _ in range(8):
            k = rng.uniform(-1, 1, 2) / rng.uniform(0.25, 0.6)
            acc = acc + 0.08 * np.sin(2 * np.pi * (k[0] * X + k[1] * Y) + rng.uniform(0, 6.3))
        out.append(acc)
    return np.clip(np.stack(out, -1), 0, 1).astype(np.float32)


def _view(offset, t):
    """The view at ``offset`` (baselines) at time t in {0, 1}: each pixel's ray from its camera
    centre (B sx, B sy, 0) meets the plane Z0 + t dZ, whose texture has moved by t (dX, dY)."""
    v, u = np.mgrid[0:N, 0:N].astype(np.float64)
    z = Z0 + t * MOTION[2]
    X = B * offset[0] + (u - C) / F * z
    Y = B * offset[1] + (v - C) / F * z
    return _texture(X - t * MOTION[0], Y - t * MOTION[1])


@pytest.fixture(scope="module")
def plane_pair():
    return {s: _view(o, 0) for s, o in OFFSETS.items()}, {s: _view(o, 1) for s, o in OFFSETS.items()}


# Tolerance: in the interior (8 px from the border, where no view's ray leaves the image) each
# component's mean absolute error per pixel is below 1 % of |MOTION| (about 1 mm) for dX and dY and
# 2 % for dZ (the worst-conditioned component: it moves the rays of a view by x_s dZ, and x_s varies
# over the views by d / f only). Measured: below 0.1 mm and 0.2 mm with either solver.
TOLERANCE = (0.01, 0.02)  # (X and Y, Z) as fractions of |MOTION|


@pytest.mark.parametrize("solver", ["global", "local"])
def test_ray_flow_recovers_a_planes_3d_translation(plane_pair, solver):
    i0, i1 = plane_pair
    ref = (1, 1)
    d = np.full((N, N), F * B / Z0)  # the plane's disparity; the bench takes it from a plane sweep
    motion = ray_flow(i0, i1, OFFSETS, ref, K, d, solver=solver) * B  # baselines -> metres
    err = np.abs(motion[8:-8, 8:-8] - MOTION).reshape(-1, 3).mean(0)
    tol_xy, tol_z = TOLERANCE
    size = np.linalg.norm(MOTION)
    assert err[0] < tol_xy * size and err[1] < tol_xy * size, err
    assert err[2] < tol_z * size, err
    # the submission arrays of the reference view follow from it: flow and disparity change against
    # the plane's projection at t+1 (rig still: world scene flow = camera-frame motion)
    flow, dchange, sf = compose(d, motion / B, K, B, np.eye(4), np.eye(4))
    v, u = np.mgrid[0:N, 0:N].astype(np.float64)
    x1 = F * ((u - C) / F * Z0 + MOTION[0]) / (Z0 + MOTION[2]) + C
    y1 = F * ((v - C) / F * Z0 + MOTION[1]) / (Z0 + MOTION[2]) + C
    flow_gt = np.stack([x1 - u, y1 - v], -1)
    epe = np.linalg.norm(flow - flow_gt, axis=-1)[8:-8, 8:-8].mean()
    assert epe < 0.02, epe  # px; the true flow is 0.4 to 1.5 px
    dchange_gt = F * B / (Z0 + MOTION[2]) - F * B / Z0  # -0.095 px
    assert np.abs(dchange[8:-8, 8:-8] - dchange_gt).mean() < 0.05 * abs(dchange_gt)
    np.testing.assert_allclose(sf, motion, atol=1e-9)


def test_a_still_plane_has_no_ray_flow(plane_pair):
    i0, _ = plane_pair
    motion = ray_flow(i0, i0, OFFSETS, (0, 2), K, np.full((N, N), F * B / Z0), solver="global")
    assert np.abs(motion[8:-8, 8:-8] * B).max() < 1e-3  # m, against a motion of 0.1 m elsewhere


def test_compose_adds_the_rigs_own_motion_and_projects_the_moved_point():
    f, b = 10.0, 0.5
    k = np.array([[f, 0, 1.0], [0, f, 1.0], [0, 0, 1]])
    d = np.full((3, 3), 1.0)  # z = f b / d = 5 m
    c0 = np.eye(4)
    c1 = np.eye(4)
    c1[:3, 3] = [0.3, 0.0, -0.2]  # the rig moved; the points moved with it (no motion in its frame)
    flow, dchange, sf = compose(d, np.zeros((3, 3, 3)), k, b, c0, c1)
    np.testing.assert_allclose(sf, np.broadcast_to([0.3, 0.0, -0.2], (3, 3, 3)), atol=1e-12)
    assert np.abs(flow).max() < 1e-12 and np.abs(dchange).max() < 1e-12
    m = np.zeros((3, 3, 3))
    m[1, 1] = [0.0, 0.0, 1.0 / b]  # the centre pixel's point recedes 1 m: 5 m -> 6 m
    m[0, 0] = [1.0 / b, 0.0, 0.0]  # pixel (0, 0): X = (0 - 1) / 10 * 5 = -0.5 m -> +0.5 m at z 5: u = 10 * 0.1 + 1 = 2
    flow, dchange, sf = compose(d, m, k, b, c0, c0)
    assert dchange[1, 1] == pytest.approx(f * b / 6.0 - 1.0)
    assert flow[1, 1] == pytest.approx([0.0, 0.0], abs=1e-12)
    assert flow[0, 0] == pytest.approx([2.0, 0.0])
    np.testing.assert_allclose(sf[1, 1], [0, 0, 1.0], atol=1e-12)


def test_compose_predicts_no_motion_where_there_is_no_positive_disparity():
    k = np.array([[10.0, 0, 1], [0, 10.0, 1], [0, 0, 1]])
    d = np.zeros((3, 3))
    flow, dchange, sf = compose(d, np.ones((3, 3, 3)), k, 0.5, np.eye(4), np.eye(4))
    assert not flow.any() and not dchange.any() and not sf.any()


def test_an_unknown_solver_is_refused(plane_pair):
    i0, i1 = plane_pair
    with pytest.raises(LfusdError, match="solver"):
        ray_flow(i0, i1, OFFSETS, (1, 1), K, np.ones((N, N)), solver="hs")


def _step_view(offset, t):
    """A static back plane at Z0 (disparity 2 px) and, in front of its right half, a half-plane at
    4/3 m (disparity 3 px) moving by STEP_MOTION: each ray takes the front plane where it meets it
    right of the plane's own edge (which moves with it), the back plane elsewhere."""
    v, u = np.mgrid[0:N, 0:N].astype(np.float64)
    z1 = STEP_Z + t * STEP_MOTION[2]
    X1 = B * offset[0] + (u - C) / F * z1 - t * STEP_MOTION[0]
    Y1 = B * offset[1] + (v - C) / F * z1 - t * STEP_MOTION[1]
    X0, Y0 = B * offset[0] + (u - C) / F * Z0, B * offset[1] + (v - C) / F * Z0
    front = X1 >= 0.0
    return np.where(front[..., None], _texture(X1, Y1), _texture(X0 + 7.0, Y0 + 3.0)), front


STEP_Z, STEP_MOTION = 4.0 / 3.0, np.array([0.02, -0.015, 0.05])


@pytest.mark.parametrize("solver", ["global", "local"])
def test_ray_flow_keeps_a_moving_surface_and_a_still_one_apart_at_a_depth_edge(solver):
    i0 = {s: _step_view(o, 0)[0] for s, o in OFFSETS.items()}
    i1 = {s: _step_view(o, 1)[0] for s, o in OFFSETS.items()}
    front = _step_view(OFFSETS[(1, 1)], 0)[1]
    d = np.where(front, F * B / STEP_Z, F * B / Z0)
    motion = ray_flow(i0, i1, OFFSETS, (1, 1), K, d, solver=solver) * B
    edge = int(np.argmax(front[N // 2]))  # the front plane's first column in the reference view
    inner = motion[8:-8]
    # 4 px either side of the edge (a window's half and the rays a view sees past the edge) each
    # surface keeps its own motion: mean error per component under 1 mm (dX, dY) and 3 mm (dZ).
    # Without the window-aggregated data term the global solver carried 17 mm of the front's dZ
    # onto the still plane.
    for part, truth in ((inner[:, 8:edge - 4], np.zeros(3)), (inner[:, edge + 4:-8], STEP_MOTION)):
        err = np.abs(part - truth).reshape(-1, 3).mean(0)
        assert err[0] < 1e-3 and err[1] < 1e-3 and err[2] < 3e-3, err
