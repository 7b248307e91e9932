"""Exact occlusion and ``mixed`` with the scene in two parts (lfusd.truth.visibility.Parts) and the
static part's answers kept from frame to frame (StaticMemo): every pixel the same as one cast
against the whole scene, and occlusion the same as the closed-form box oracle, over a video in
which objects stand still, move, start moving, and the camera starts moving."""

import numpy as np
import pytest
from support.motion_scenes import Box, Scene, intrinsics, pose, rot

from lfusd.truth import visibility
from lfusd.truth.motion import MOTION_KEYS
from lfusd.truth.visibility import Occluders, StaticMemo, mixed_footprint, visible

FRAMES = range(1, 7)


def street(n=96, camera_moves_from=None):
    """A wall, a static post in front of it, a block sliding behind the post, and a cube that stands
    still until frame 4 and then moves; the camera still, or moving from ``camera_moves_from``."""
    wall = Box((5, 5, 0.05), {f: pose(t=(0, 0, 6.0)) for f in FRAMES}, instance=1, prim_path="/World/Wall")
    post = Box((0.15, 2.0, 0.15), {f: pose(t=(0.05, 0.0, 3.0)) for f in FRAMES}, instance=2, prim_path="/World/Post")
    block = Box((0.5, 0.7, 0.3), {f: pose(rot((0, 0, 1), 10.0), (-0.9 + 0.3 * f, 0.1, 4.2)) for f in FRAMES}, 3, "/World/Block")
    cube = Box((0.4, 0.4, 0.4), {f: pose(rot((0.3, 1, 0.2), 12.0 * max(0, f - 3)), (-0.8 + 0.2 * max(0, f - 3), -0.9, 3.6))
                                 for f in FRAMES}, 4, "/World/Cube")
    cams = {f: np.eye(4) if camera_moves_from is None or f < camera_moves_from
            else pose(rot((0, 1, 0), 1.5 * (f - camera_moves_from + 1)), (0.1 * (f - camera_moves_from + 1), 0, 0)) for f in FRAMES}
    return Scene([wall, post, block, cube], intrinsics(n * 1.05, n, n), cams, n, n, baseline=0.2)


def _count_rays(monkeypatch) -> dict:
    """Count the segments exact occlusion casts (visibility._occluded), at any part or the whole scene."""
    counts = {"rays": 0}
    cast = visibility._occluded

    def counting(scene, rays, eps):
        counts["rays"] += len(rays)
        return cast(scene, rays, eps)

    monkeypatch.setattr(visibility, "_occluded", counting)
    return counts


@pytest.mark.parametrize("moves_from", [None, 5], ids=["still-camera", "camera-moves-at-5"])
def test_parts_and_memo_give_the_whole_scenes_answers_on_every_pixel(moves_from, monkeypatch):
    scene = street(camera_moves_from=moves_from)
    counts = _count_rays(monkeypatch)
    memo = StaticMemo(0)
    checked = 0
    for f in FRAMES:
        whole = scene.derive(f)  # no memo: one cast against every triangle
        counts["rays"] = 0
        split = scene.derive(f, memo=memo)
        for key in MOTION_KEYS:
            assert np.array_equal(whole[key], split[key]), f"frame {f}: {key} differs from the whole scene's cast"
        fg = scene.truth(f)["which"] >= 0
        for key, step in (("occlusion_fwd", 1), ("occlusion_bwd", -1)):
            if f + step in scene.cams:
                hidden = fg & ~scene.visible_at(f, step)
                wrong = (split[key] != hidden) & fg
                assert not wrong.any(), f"frame {f}: {key} differs from the box oracle on {wrong.sum()} px"
                checked += int(hidden.sum())
        if f in (2, 5) and moves_from is None:
            # the still wall and post: their segments were cast a frame before, and are not cast again
            # (at frame 3 the cube's start splits t+1 apart from t-1: both cast)
            # two directions: a whole cast would be about 2 x fg.sum() segments
            assert 0 < counts["rays"] < 0.5 * (2 * fg.sum()), f"frame {f}: {counts['rays']} segments cast, memo unused"
        if moves_from is not None and f >= moves_from:
            assert counts["rays"] > 0.8 * fg.sum(), "a moved camera casts its rays again"
    assert checked > 500, "the video must hide points for this test to mean anything"


def _random_triangles(rng, m, near_camera):
    """m triangles in front of the camera, of three sizes; with ``near_camera`` also three at its
    side that reach behind it, and one wholly behind it."""
    centres = rng.uniform([-3, -3, 0.5], [3, 3, 8], (m, 1, 3))
    corners = centres + rng.normal(0, 1, (m, 3, 3)) * rng.choice([0.02, 0.3, 1.5], (m, 1, 1))
    if near_camera:
        side = np.array([[[0.3, 0.1, -0.5], [0.6, -0.2, 0.8], [0.25, 0.3, 1.5]], [[-0.4, -0.3, 1.0], [-0.5, 0.1, -0.4], [-0.3, 0.2, 0.6]],
                         [[0.1, 0.3, -0.3], [-0.2, 0.4, 1.2], [0.2, 0.5, 0.9]], [[0, 0, -1], [1, 0, -2], [0, 1, -1.5]]])
        corners = np.concatenate([corners, side])
    return corners.reshape(-1, 3).astype(np.float32), np.arange(corners.size // 3).reshape(-1, 3)


@pytest.mark.parametrize("seed", range(4))
def test_culling_by_screen_rectangles_never_drops_a_ray_that_meets_a_moving_triangle(seed, monkeypatch):
    """Every triangle moves (all dynamic, nothing kept): segments to random points and the corner
    rays of ``mixed`` give what one cast against all triangles gives, with triangles that reach
    behind the camera, lie wholly behind it, or cover a tenth of a pixel."""
    rng = np.random.default_rng(seed)
    h, w = 48, 64
    K = intrinsics(50.0, w, h)
    cam_pose = pose(rot((0.2, 1, 0.1), rng.uniform(-10, 10)), rng.uniform(-0.2, 0.2, 3))
    from lfusd.camera import Camera

    cam = Camera(K, cam_pose)
    v, t = _random_triangles(rng, 60, near_camera=seed % 2 == 1)
    here = Occluders(v, t, (np.arange(len(t)) // 3).astype(np.int32))
    other = Occluders(v + np.float32(0.01), t)  # every vertex moved: all dynamic
    parts = here.parts(other)
    assert parts.static is None and len(parts.dynamic_ids) == len(t)
    # end points: on the triangles themselves (the hard case), and anywhere in view
    bary = rng.dirichlet((1, 1, 1), h * w // 2)
    on = np.einsum("nk,nkd->nd", bary, v.reshape(-1, 3, 3)[rng.integers(0, len(t), len(bary))])
    anywhere = cam_pose[:3, 3] + rng.normal(0, 1, (h * w - len(bary), 3)) * [2, 2, 0] + [0, 0, 1] * rng.uniform(0.2, 9, (h * w - len(bary), 1))
    points = np.concatenate([on, anywhere]).astype(np.float32)
    valid = np.ones(len(points), bool)
    whole = visible(points, valid, cam, h, w, here)
    memo = StaticMemo(0)
    assert np.array_equal(whole, visible(points, valid, cam, h, w, here, parts=parts, memo=memo))  # fills the memo
    calls = []
    by_parts = visibility._visible_parts
    monkeypatch.setattr(visibility, "_visible_parts", lambda *a: calls.append(1) or by_parts(*a))
    split = visible(points, valid, cam, h, w, here, parts=parts, memo=memo)  # the memo holds this camera: by parts
    assert calls, "the second cast must go by parts, culled by the screen rectangles"
    assert (~whole).sum() > 100 and whole.sum() > 100
    assert np.array_equal(whole, split)
    a = mixed_footprint(cam, h, w, here)
    b = mixed_footprint(cam, h, w, here, parts=parts, memo=StaticMemo(0))
    assert a.any() and np.array_equal(a, b)


def test_a_triangle_reaching_behind_the_camera_covers_every_pixel():
    from lfusd.truth._motion_numba import depth_map

    M = intrinsics(50.0, 8, 6)
    v = np.array([[0, 0, -1], [0.1, 0, 2], [0, 0.1, 2], [5, 5, -2], [6, 5, -2], [5, 6, -1]], np.float32)
    z = depth_map(v, np.array([[0, 1, 2]], np.uint32), M, np.zeros(3), np.array([0, 0, 1.0]), 6, 8, 1.0, 1e-3)
    assert (z == 0).all()
    z = depth_map(v, np.array([[3, 4, 5]], np.uint32), M, np.zeros(3), np.array([0, 0, 1.0]), 6, 8, 1.0, 1e-3)
    assert np.isinf(z).all()  # wholly behind: covers nothing


def test_memos_are_held_within_the_budget_and_another_datasets_make_room(monkeypatch):
    monkeypatch.setattr(visibility, "_MEMOS", type(visibility._MEMOS)())
    per_view = visibility.MEMO_BYTES_PER_PIXEL * 11 * 11
    monkeypatch.setattr(visibility, "MEMO_BYTES", 3 * per_view)
    held = [visibility.memo_for(("a", "rig", (0, k)), 10, 10) for k in range(4)]
    assert all(m is not None for m in held[:3]) and held[3] is None  # the views held stay held
    assert visibility.memo_for(("a", "rig", (0, 1)), 10, 10) is held[1]
    assert visibility.memo_for(("b", "rig", (0, 0)), 10, 10) is not None  # another dataset's make room
    assert ("a", "rig", (0, 0)) not in visibility._MEMOS


def test_a_cast_that_fails_leaves_no_half_filled_memo(monkeypatch):
    """The memo's slots take a segment's end point before its answer is cast: if the cast fails,
    the memo is dropped, and the next derivation gives the whole scene's answers again."""
    scene = street()
    memo = StaticMemo(0)
    scene.derive(1, memo=memo)
    cast = visibility._occluded

    def failing(scene_, rays, eps):
        if any(scene_ is s for s in visibility._STATIC.values()):
            raise RuntimeError("Embree ran out of memory")
        return cast(scene_, rays, eps)

    monkeypatch.setattr(visibility, "_occluded", failing)
    with pytest.raises(RuntimeError):
        scene.derive(2, memo=memo)
    assert memo.segments is None
    monkeypatch.setattr(visibility, "_occluded", cast)
    whole, split = scene.derive(2), scene.derive(2, memo=memo)
    for key in MOTION_KEYS:
        assert np.array_equal(whole[key], split[key]), key


@pytest.mark.parametrize("backend", ["numba", "numpy"])
@pytest.mark.parametrize("aovs", [True, False], ids=["position-aovs", "no-aovs"])
def test_a_neighbours_images_are_decoded_only_where_its_occlusion_is_not_ray_cast(backend, aovs):
    """Ray-cast occlusion uses a neighbouring frame's camera, not its images (so a video's raw
    passes are decoded once each): derived lazily, every key equals the eagerly decoded
    derivation, and the neighbours' images are decoded exactly where another route reads them."""
    from lfusd.data.passes import LazyRawPasses
    from lfusd.truth.motion import derive_motion

    scene, f = street(), 3
    decoded = []

    def lazy(g):
        raw = scene.raw(g, aovs)
        return LazyRawPasses(raw.camera, raw.shape, lambda: decoded.append(g) or raw)

    occ = {k: scene.occluders(g) for k, g in (("next", f + 1), ("prev", f - 1), ("here", f))}
    args = dict(baseline=scene.baseline, backend=backend, occluders=occ)
    eager = derive_motion(scene.raw(f, aovs), scene.raw(f + 1, aovs), scene.raw(f - 1, aovs), **args)
    got = derive_motion(scene.raw(f, aovs), lazy(f + 1), lazy(f - 1), **args)
    for key in MOTION_KEYS:
        assert np.array_equal(eager[key], got[key]), key
    assert sorted(decoded) == ([] if aovs and backend == "numba" else [f - 1, f + 1])
    if aovs and backend == "numba":
        assert got["occlusion_fwd"].any() and got["occlusion_bwd"].any()  # the rays had something to find


def test_a_neighbour_of_another_size_is_refused_without_decoding_it():
    from lfusd.data.passes import LazyRawPasses
    from lfusd.errors import LfusdError
    from lfusd.truth.motion import derive_motion

    scene, f = street(), 3
    raw = scene.raw(f + 1)
    small = LazyRawPasses(raw.camera, (raw.shape[0], raw.shape[1] - 1), lambda: pytest.fail("decoded"))
    occ = {k: scene.occluders(g) for k, g in (("next", f + 1), ("here", f))}
    with pytest.raises(LfusdError, match=r"frame t\+1: the view is 95x96 but frame t is 96x96"):
        derive_motion(scene.raw(f), small, None, baseline=scene.baseline, occluders=occ)
