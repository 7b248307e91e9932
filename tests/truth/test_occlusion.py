"""Exact occlusion: ray-cast visibility of each pixel's point against the other frame's triangles,
checked on every foreground pixel (silhouettes included) against the closed-form box oracle."""

import numpy as np
import pytest
from test_motion import BACKENDS, exact_truth, occluder_scene

from lfusd.truth.motion import derive_motion

@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("name", ["sliding", "spinning", "moving-rig"])
def test_exact_occlusion_agrees_with_ray_cast_visibility_on_every_pixel(name, backend):
    from test_motion import SCENES

    scene = occluder_scene(**SCENES[name])
    m = scene.derive(2, backend=backend)
    fg = exact_truth(scene)["fg"]
    for key, step in (("occlusion_fwd", 1), ("occlusion_bwd", -1)):
        hidden = fg & ~scene.visible_at(2, step)
        assert hidden.sum() > 20, "the scene must have occlusions for this test to mean anything"
        wrong = np.flatnonzero((m[key] != hidden) & fg)
        assert wrong.size == 0, f"{key} differs from ray-cast visibility on {wrong.size} of {fg.sum()} px (e.g. {wrong[:5]})"
        assert m[f"valid_{key.split('_')[1]}"][fg].all()


def test_the_image_space_test_it_replaces_was_wrong_at_silhouettes():
    """The heuristic (no triangles given) misses pixels near silhouettes that the exact test gets right:
    the exact test is what makes the difference (guards against a test that passes with either)."""
    scene = occluder_scene(spin=True, cam_motion=True)
    m = derive_motion(scene.raw(2, True), scene.raw(3, True), scene.raw(1, True), baseline=scene.baseline)
    fg = exact_truth(scene)["fg"]
    hidden = fg & ~scene.visible_at(2, 1)
    assert ((m["occlusion_fwd"] != hidden) & fg).sum() > 0


def test_unknown_next_position_is_flagged_invalid_not_guessed():
    """NaN next/prev positions (the worker's mark of a mesh whose topology changed) make the
    pixels invalid with zero flow, on both backends, never the vector pass's guess."""
    scene = occluder_scene(spin=True)
    cur = scene.raw(2, True)
    fg = exact_truth(scene)["fg"]
    bad = fg.copy()
    bad[:, : scene.W // 2] = False
    cur.next_position = np.where(bad[..., None], np.nan, cur.next_position).astype(np.float32)
    cur.prev_position = np.where(bad[..., None], np.nan, cur.prev_position).astype(np.float32)
    for backend in BACKENDS:
        m = derive_motion(cur, scene.raw(3, True), scene.raw(1, True), baseline=scene.baseline, backend=backend)
        for sfx in ("fwd", "bwd"):
            assert not m[f"valid_{sfx}"][bad].any() and m[f"valid_{sfx}"][fg & ~bad].all()
            assert not m[f"occlusion_{sfx}"][bad].any()
            assert (m[f"flow_{sfx}"][bad] == 0).all()
        assert (m["scene_flow"][bad] == 0).all()


def test_static_point_off_the_pixel_ray_has_zero_flow():
    """Blender's sample on a sliver triangle lands off the pixel's ray: flow is measured from the
    point sampled, so a static point seen by a static camera has exactly zero flow."""
    scene = occluder_scene()
    cur, nxt, prv = (scene.raw(f, True) for f in (2, 3, 1))
    # a static point: next = prev = position, moved off the pixel ray by up to 0.3 px sideways
    rng = np.random.default_rng(0)
    pos = cur.position.astype(np.float64)
    pos = pos + rng.uniform(-1, 1, pos.shape) * 0.3 * pos[..., 2:3] / scene.K[0, 0]
    for a in ("position", "next_position", "prev_position"):
        setattr(cur, a, np.where(np.isfinite(cur.position), pos, np.nan).astype(np.float32))
    for c in (cur, nxt, prv):
        c.camera = cur.camera
    for backend in BACKENDS:
        m = derive_motion(cur, nxt, prv, baseline=scene.baseline, backend=backend)
        fg = np.isfinite(cur.position).all(-1)
        assert np.abs(m["flow_fwd"][fg]).max() < 1e-9 and np.abs(m["flow_bwd"][fg]).max() < 1e-9
        assert np.abs(m["scene_flow"][fg]).max() == 0


@pytest.mark.parametrize("name", ["sliding", "spinning", "moving-rig"])
def test_mixed_marks_footprints_with_more_than_one_surface_or_motion(name):
    """``mixed`` against the closed-form oracle: four rays through each pixel's corners (+-1/2 px)
    cast at the boxes (each pixel's own four, not shared with its neighbours), their instances,
    depths and forward flows (hits moved with their box to t+1) compared."""
    from test_motion import SCENES

    from lfusd.truth.visibility import CORNERS, MIXED_DEPTH_REL, MIXED_FLOW_PX

    scene = occluder_scene(**SCENES[name])
    m = scene.derive(2)
    H, W = scene.H, scene.W
    v, u = np.mgrid[0:H, 0:W].astype(float)
    c2w = scene.cams[2]
    inst, depth, flow = [], [], []
    for du, dv in CORNERS:
        pix = np.stack([u + du, v + dv, np.ones_like(u)], -1)
        d = pix @ np.linalg.inv(scene.K).T @ c2w[:3, :3].T
        s, which, local = scene.cast(np.broadcast_to(c2w[:3, 3], d.shape), d, 2)
        inst.append(np.where(which >= 0, np.array([b.instance for b in scene.boxes] + [0])[which], -1))
        depth.append(s)
        X1 = scene.to_world(which, local, 3)
        pu, pv, _ = scene.project(X1, 3)
        flow.append(np.stack([pu - (u + du), pv - (v + dv)], -1))
    inst, depth, flow = np.stack(inst), np.stack(depth), np.stack(flow)
    with np.errstate(invalid="ignore"):
        lo, hi = depth.min(0), depth.max(0)
        spread = np.linalg.norm(flow[:, None] - flow[None], axis=-1).max(axis=(0, 1))
    want = (inst != inst[:1]).any(0) | (np.isfinite(lo) & (hi - lo > MIXED_DEPTH_REL * lo)) | (spread > MIXED_FLOW_PX)
    assert want.sum() > 20 and (~want).sum() > 20
    # exact, bar sub-samples within float tolerance of a threshold
    near = (np.abs(spread - MIXED_FLOW_PX) < 1e-6) | (np.abs(hi - lo - MIXED_DEPTH_REL * lo) < 1e-9)
    wrong = (m["mixed"] != want) & ~near
    assert not wrong.any(), f"mixed differs from the oracle on {wrong.sum()} px"
