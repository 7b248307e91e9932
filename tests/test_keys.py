"""The key registry (lfusd.keys) against the modules that produce or list keys."""

import numpy as np
import pytest
from support.analytic import cast, pixel_rays
from support.scenes import GROUND_HALF, PLANE_RIG, boxes_world

from lfusd import LfusdError, keys, layout
from lfusd.data import passes


def test_every_key_is_fully_described():
    for k in keys.KEYS.values():
        assert k.stage in keys.STAGES, k.name
        assert np.dtype(k.dtype).name == k.dtype, k.name
        assert k.file in layout.VIEW_FILES, k.name
        assert (k.stage == keys.MOTION) == (k.file == layout.MOTION_FILE), k.name
        assert k.step in (-1, 0, 1) and (k.step == 0 or k.stage == keys.MOTION), k.name
        assert (k.accuracy is None) == (k.accuracy_unit is None), k.name
        assert k.meaning and k.unit, k.name


def test_producers_and_consumers_take_their_key_lists_from_the_registry():
    from lfusd.truth import verify
    from lfusd.truth.motion import MOTION_KEYS

    assert set(passes.DERIVED) == set(keys.names(keys.STATIC))
    assert MOTION_KEYS == keys.names(keys.MOTION)
    assert verify.THRESHOLDS == keys.accuracies() and set(verify.UNITS) == set(verify.THRESHOLDS)
    assert set(verify.THRESHOLDS) <= set(verify.KEYS)
    assert keys.names() == tuple(keys.KEYS)
    assert set(keys.names(keys.IMAGE, keys.RAW, keys.STATIC, keys.MOTION)) == set(keys.KEYS)


def test_torch_dataset_accepts_every_key():
    pytest.importorskip("torch")
    from lfusd.data.torch import BACKWARD, FORWARD, KEYS

    assert KEYS == keys.names()
    assert FORWARD == {"flow_fwd", "scene_flow", "disparity_change", "valid_fwd", "occlusion_fwd"}
    assert BACKWARD == {"flow_bwd", "valid_bwd", "occlusion_bwd"}


def test_unknown_key_is_a_one_line_error_listing_the_keys():
    with pytest.raises(LfusdError, match=r"unknown ground-truth key 'dpeth'; use one of rgb, .*occlusion_bwd") as e:
        keys.get("dpeth")
    assert "\n" not in str(e.value)
    with pytest.raises(ValueError):
        keys.names("derived")


def test_depth_euclidean_is_the_distance_to_the_analytic_hit_point():
    """depth_euclidean from planar depth and K equals |hit - camera centre| of closed-form ray casts."""
    K = PLANE_RIG.intrinsics()
    for view in [(0, 0), (1, 2)]:
        c2w = PLANE_RIG.cam_to_world(view)
        depth, hit = cast(K, c2w, PLANE_RIG.width, PLANE_RIG.height, boxes_world(), GROUND_HALF)
        origin, dirs = pixel_rays(K, c2w, PLANE_RIG.width, PLANE_RIG.height)
        points = origin + np.where(np.isfinite(depth), depth, 0)[..., None] * dirs
        distance = np.where(np.isfinite(depth), np.linalg.norm(points - origin, axis=-1), np.inf)
        got = passes.depth_euclidean(depth.astype(np.float32), K)
        assert got.dtype == np.float32 and got.shape == depth.shape
        fin = np.isfinite(depth)
        assert fin.mean() > 0.5 and (hit[fin] != "ground").any()  # the boxes are in view, not only the ground
        np.testing.assert_allclose(got[fin], distance[fin], rtol=1e-6)
        assert np.all(np.isinf(got[~fin]))
        # off-axis pixels are further along their ray than their planar depth
        assert np.all(got[fin] >= depth[fin] * (1 - 1e-6)) and (got[fin] > depth[fin] * 1.001).any()
