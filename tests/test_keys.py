"""The key registry (lfusd.keys) against the modules that produce or list keys."""

import numpy as np
import pytest

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

