"""lfusd.truth.motion against closed-form motion of boxes rendered by independent ray casting."""

import numpy as np
import pytest
from support.motion_scenes import Box, Scene, intrinsics, pose, rot

from lfusd.errors import LfusdError
from lfusd.truth.motion import MOTION_KEYS, RawPasses, derive_motion

BACKENDS = ["numpy", "numba"]  # numba is a required dependency
from lfusd.camera import look_at_pose

H = W = 32
F = 40.0
Z0 = 5.0
THIN = 0.01  # half thickness of the plane box: its front face is at Z0 - THIN


def plane_scene(delta, cam=np.eye(4), centre=(0.0, 0.0, Z0)):
    """A wide fronto-parallel plate moving by ``delta`` (world) per frame, frames 1..3."""
    R = cam[:3, :3]
    half = (50.0, 50.0, THIN)
    # The box is posed in the camera's orientation so that its thin axis is the optical axis.
    poses = {f: pose(R, cam[:3, :3] @ np.asarray(centre, float) + cam[:3, 3] + (f - 2) * np.asarray(delta, float)) for f in (1, 2, 3)}
    return Scene([Box(half, poses)], intrinsics(F, W, H), {f: cam for f in (1, 2, 3)}, H, W, baseline=0.1)


def closed_form_flow(d_cam, step=1):
    """Flow of the plate's front face for a camera-frame displacement d_cam per frame (step +-1)."""
    v, u = np.mgrid[0:H, 0:W].astype(float)
    c = (W - 1) / 2
    zf = Z0 - THIN
    X, Y = (u - c) * zf / F, (v - c) * zf / F
    dx, dy, dz = step * np.asarray(d_cam, float)
    return F * (X + dx) / (zf + dz) + c - u, F * (Y + dy) / (zf + dz) + c - v, zf, zf + dz


def derive(scene, exact, frame=2, backend=None):
    nxt = scene.raw(frame + 1, exact) if frame + 1 in scene.cams else None
    prv = scene.raw(frame - 1, exact) if frame - 1 in scene.cams else None
    return derive_motion(scene.raw(frame, exact), nxt, prv, baseline=scene.baseline, backend=backend)


CASES = {  # camera-frame displacement per frame and the sign it must produce
    "right": (0.1, 0.0, 0.0),
    "down": (0.0, 0.1, 0.0),
    "towards": (0.0, 0.0, -0.5),
    "away": (0.0, 0.0, 0.5),
}


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("exact", [True, False], ids=["position-aov", "vector+depth"])
@pytest.mark.parametrize("case", list(CASES))
def test_signs_and_axes_of_forward_and_backward_motion(case, exact, backend):
    d = CASES[case]
    m = derive(plane_scene(d), exact, backend=backend)
    du, dv, z0, z1 = closed_form_flow(d, +1)
    bu, bv, _, _ = closed_form_flow(d, -1)
    valid = m["valid_fwd"]
    assert valid.mean() > 0.7 and m["valid_bwd"].all()
    np.testing.assert_allclose(m["flow_fwd"][..., 0][valid], du[valid], atol=2e-3)
    np.testing.assert_allclose(m["flow_fwd"][..., 1][valid], dv[valid], atol=2e-3)
    np.testing.assert_allclose(m["flow_bwd"][..., 0], bu, atol=2e-3)
    np.testing.assert_allclose(m["flow_bwd"][..., 1], bv, atol=2e-3)
    np.testing.assert_allclose(m["scene_flow"][valid], np.broadcast_to(d, (valid.sum(), 3)), atol=1e-4)
    fb = F * 0.1
    np.testing.assert_allclose(m["disparity_change"][valid], (fb / z1 - fb / z0), rtol=1e-4, atol=1e-6)
    fu, fv = m["flow_fwd"][..., 0], m["flow_fwd"][..., 1]
    gu, gv = m["flow_bwd"][..., 0], m["flow_bwd"][..., 1]
    right_half = np.zeros((H, W), bool)
    right_half[:, W // 2 + 2 :] = True
    if case == "right":  # seen moving right: +u forward, -u backward, no vertical motion
        assert (fu[valid] > 0.7).all() and (gu < -0.7).all() and np.abs(fv).max() < 1e-3
    if case == "down":  # v grows downward
        assert (fv[valid] > 0.7).all() and (gv < -0.7).all() and np.abs(fu).max() < 1e-3
    if case == "towards":  # expands; disparity grows
        assert (fu[valid & right_half] > 0).all() and (gu[right_half] < 0).all()
        assert (m["disparity_change"][valid] > 0).all()
    if case == "away":  # contracts; disparity shrinks
        assert (fu[valid & right_half] < 0).all() and (gu[right_half] > 0).all()
        assert (m["disparity_change"][valid] < 0).all()


def test_world_axes_with_a_z_up_rig_pose():
    """A rig looking along world +Y (Z up): world +X is image right, world -Z image down."""
    cam = look_at_pose(np.array([0.0, -Z0, 1.5]), np.array([0.0, 0.0, 1.5]))
    for delta, axis in (((0.1, 0, 0), 0), ((0, 0, -0.1), 1)):
        scene = plane_scene(delta, cam=cam, centre=(0, 0, Z0))
        m = derive(scene, exact=False)
        v = m["valid_fwd"]
        assert v.mean() > 0.7
        assert (m["flow_fwd"][..., axis][v] > 0.7).all() and np.abs(m["flow_fwd"][..., 1 - axis][v]).max() < 1e-3
        np.testing.assert_allclose(m["scene_flow"][v], np.broadcast_to(delta, (v.sum(), 3)), atol=1e-4)


def occluder_scene(spin=False, cam_motion=False, n=96):
    K = intrinsics(n * 1.05, n, n)
    back = Box((5, 5, 0.05), {f: pose(t=(0, 0, 6.0)) for f in (1, 2, 3)}, instance=1, prim_path="/World/Back")
    if spin:  # a cube spinning 8 degrees per frame about a tilted axis, in front of the wall
        front = Box((0.6, 0.6, 0.6), {f: pose(rot((0.3, 1, 0.2), 15.0 * f + 20), (0.1, 0.0, 4.0)) for f in (1, 2, 3)}, 2, "/World/Cube")
    else:  # a block sliding right in front of the wall
        front = Box((0.5, 0.7, 0.3), {f: pose(rot((0, 0, 1), 10.0), (-0.3 + 0.25 * f, 0.1, 3.5)) for f in (1, 2, 3)}, 2, "/World/Block")
    cams = {f: pose(rot((0, 1, 0), 2.0 * (f - 2)), (0.2 * (f - 2), 0.05 * (f - 2), 0)) if cam_motion else np.eye(4) for f in (1, 2, 3)}
    return Scene([back, front], K, cams, n, n, baseline=0.2)


def exact_truth(scene, frame=2):
    t = scene.truth(frame)
    fg = t["which"] >= 0
    v, u = np.mgrid[0 : scene.H, 0 : scene.W].astype(float)
    nu, nv, nz = scene.project(t["next_position"], frame + 1)
    pu, pv, _ = scene.project(t["prev_position"], frame - 1)
    fb = scene.K[0, 0] * scene.baseline
    return {
        "fg": fg,
        "flow_fwd": np.stack([nu - u, nv - v], -1),
        "flow_bwd": np.stack([pu - u, pv - v], -1),
        "scene_flow": t["next_position"] - t["position"],
        "disparity_change": fb / nz - fb / t["depth"],
    }


SCENES = {
    "sliding": dict(),
    "spinning": dict(spin=True),
    "moving-rig": dict(spin=True, cam_motion=True),
}


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("exact", [True, False], ids=["position-aov", "vector+depth"])
@pytest.mark.parametrize("name", list(SCENES))
def test_motion_and_occlusion_against_ray_cast_truth(name, exact, backend):
    scene = occluder_scene(**SCENES[name])
    m = derive(scene, exact, backend=backend)
    truth = exact_truth(scene)
    fg = truth["fg"]
    for key, step in (("occlusion_fwd", 1), ("occlusion_bwd", -1)):
        hidden = fg & ~scene.visible_at(2, step)
        assert hidden.sum() > 20, "the scene must have occlusions for this test to mean anything"
        agree = (m[key] == hidden).mean()
        assert agree > 0.99, f"{key} agrees with ray-cast visibility on only {agree:.4f} of pixels"
    # Flow is exact on all foreground pixels (the vector pass follows hidden points too).
    for key in ("flow_fwd", "flow_bwd"):
        err = np.linalg.norm(m[key] - truth[key], axis=-1)[fg]
        assert err.max() < 2e-3, (key, err.max())
    v = m["valid_fwd"]
    if exact:
        np.testing.assert_array_equal(v, fg)  # defined for hidden points too
    else:
        assert not (v & m["occlusion_fwd"]).any() and v.sum() > 0.8 * (fg & ~m["occlusion_fwd"]).sum()
    sf_err = np.linalg.norm(m["scene_flow"] - truth["scene_flow"], axis=-1)[v]
    assert np.median(sf_err) < 5e-5 and np.percentile(sf_err, 99) < 5e-4
    dc_err = np.abs(m["disparity_change"] - truth["disparity_change"])[v]
    assert np.percentile(dc_err, 99) < 2e-3
    assert not m["valid_fwd"][~fg].any() and not m["valid_bwd"][~fg].any()
    assert (m["flow_fwd"][~fg] == 0).all() and (m["scene_flow"][~fg] == 0).all()


@pytest.mark.parametrize("backend", BACKENDS)
def test_first_and_last_frames_mask_the_missing_direction(backend):
    scene = plane_scene(CASES["right"])
    last = derive_motion(scene.raw(3), None, scene.raw(2), baseline=0.1, backend=backend)
    assert set(last) == set(MOTION_KEYS)
    assert not last["valid_fwd"].any() and not last["occlusion_fwd"].any()
    assert (last["flow_fwd"] == 0).all() and (last["scene_flow"] == 0).all() and (last["disparity_change"] == 0).all()
    assert last["valid_bwd"].all() and (last["flow_bwd"][..., 0] < 0).all()
    first = derive_motion(scene.raw(1), scene.raw(2), None, baseline=0.1, backend=backend)
    assert not first["valid_bwd"].any() and (first["flow_bwd"] == 0).all() and first["valid_fwd"].mean() > 0.7


@pytest.mark.parametrize("backend", BACKENDS)
def test_output_types(backend):
    m = derive(plane_scene(CASES["down"]), exact=True, backend=backend)
    for key, (shape, dtype) in {
        "flow_fwd": ((H, W, 2), np.float32),
        "flow_bwd": ((H, W, 2), np.float32),
        "scene_flow": ((H, W, 3), np.float32),
        "disparity_change": ((H, W), np.float32),
        "valid_fwd": ((H, W), bool),
        "occlusion_bwd": ((H, W), bool),
    }.items():
        assert m[key].shape == shape and m[key].dtype == dtype, key


def test_mismatched_resolution_names_the_pass_and_frame():
    scene = plane_scene(CASES["right"])
    cur, nxt = scene.raw(2), scene.raw(3)
    bad = RawPasses(nxt.depth[:-1], nxt.vector[:-1], nxt.camera)
    with pytest.raises(LfusdError, match="frame t\\+1: depth has shape"):
        derive_motion(cur, bad, None)
    bad = RawPasses(cur.depth, cur.vector[:, :-1], cur.camera)
    with pytest.raises(LfusdError, match="frame t: vector has shape"):
        derive_motion(bad, nxt, None)


@pytest.mark.parametrize("exact", [True, False], ids=["position-aov", "vector+depth"])
def test_numba_backend_matches_the_numpy_reference(exact):
    scene = occluder_scene(spin=True, cam_motion=True)
    a, b = derive(scene, exact, backend="numpy"), derive(scene, exact, backend="numba")
    for key in ("occlusion_fwd", "occlusion_bwd", "valid_fwd", "valid_bwd"):
        assert (a[key] != b[key]).mean() < 0.003, key  # float32 vs float64 at thresholds only
    both = a["valid_fwd"] & b["valid_fwd"]
    np.testing.assert_allclose(a["flow_fwd"], b["flow_fwd"], atol=1e-4)
    np.testing.assert_allclose(a["flow_bwd"], b["flow_bwd"], atol=1e-4)
    np.testing.assert_allclose(a["scene_flow"][both], b["scene_flow"][both], atol=1e-5)
    np.testing.assert_allclose(a["disparity_change"][both], b["disparity_change"][both], atol=1e-4)


def test_unknown_backend_is_refused():
    scene = plane_scene(CASES["right"])
    with pytest.raises(LfusdError, match="backend 'cuda'"):
        derive_motion(scene.raw(2), scene.raw(3), None, backend="cuda")


@pytest.mark.parametrize("backend", BACKENDS)
def test_points_leaving_the_image_are_occluded_and_keep_their_motion(backend):
    """A plate sliding right by 3 px per frame: the last three columns leave the image at t+1."""
    scene = plane_scene((3 * (Z0 - THIN) / F, 0.0, 0.0))
    m = derive(scene, exact=True, backend=backend)
    du, _, _, _ = closed_form_flow((3 * (Z0 - THIN) / F, 0.0, 0.0))
    leaving = np.arange(W)[None, :] + du > W - 0.5
    assert leaving[:, -3:].all() and not leaving[:, :-4].any()
    np.testing.assert_array_equal(m["occlusion_fwd"], np.broadcast_to(leaving, (H, W)))
    assert m["valid_fwd"].all()  # the exact route knows where they go
    np.testing.assert_allclose(m["flow_fwd"][..., 0], du, atol=2e-3)
    np.testing.assert_array_equal(m["occlusion_bwd"][:, :3], True)  # came in from the left
    assert not m["occlusion_bwd"][:, 4:].any()


def test_a_one_pixel_wide_view_is_refused():
    scene = plane_scene(CASES["right"])
    raw = scene.raw(2)
    thin = RawPasses(raw.depth[:, :1], raw.vector[:, :1], raw.camera)
    with pytest.raises(LfusdError, match="at least 2x2"):
        derive_motion(thin, thin, None)
