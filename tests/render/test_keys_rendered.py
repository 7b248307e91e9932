"""Every key of the registry (lfusd.keys) reads from a real render-video dataset with its dtype and shape."""

from __future__ import annotations

import numpy as np
import pytest
from support.scenes import write_motion_stage

from lfusd import Dataset, keys
from lfusd.camera import RigSpec

pytestmark = pytest.mark.render

RIG = RigSpec(name="main", rows=1, cols=2, width=20, height=14, baseline=0.1, at=(0.3, -5.0, 1.8), look_at=(0.0, 0.5, 0.6))


@pytest.fixture(scope="module")
def tiny_video(tmp_path_factory):
    from lfusd.cli import main

    root = tmp_path_factory.mktemp("keys_video")
    stage = root / "movers.usda"
    write_motion_stage(stage, RIG, 3)
    out = root / "out"
    assert main(["render-video", str(stage), "-o", str(out), "--samples", "1", "--quiet", "--device", "cpu", "--keep-raw",
                 "--materials", "--iso", "400", "--shutter", "0.5", "--fstop", "2", "--focus", "5"]) == 0  # every camera effect: every key
    return out


def test_every_registry_key_reads_with_its_dtype_and_shape(tiny_video):
    ds = Dataset(tiny_video)
    for view in ds.views:
        for key, k in keys.KEYS.items():
            a = ds.read(2, view, key)  # frame 2 has both neighbours: every motion key is defined
            assert a.dtype == np.dtype(k.dtype), (key, a.dtype)
            assert a.shape == k.full_shape(RIG.height, RIG.width), (key, a.shape)
    assert ds.read(2, (0, 1), "valid_fwd").any() and ds.read(2, (0, 1), "valid_bwd").any()


def test_torch_dataset_serves_every_registry_key(tiny_video):
    pytest.importorskip("torch")
    from lfusd.torch import LightFieldVideoDataset

    item = LightFieldVideoDataset(tiny_video, keys=keys.names(), frames=[2])[0]
    for key, k in keys.KEYS.items():
        v, (h, w) = len(RIG.views), (RIG.height, RIG.width)
        channels = k.shape if k.shape else ()
        assert tuple(item[key].shape) == (v, *channels, h, w), key
