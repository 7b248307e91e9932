"""lfusd.torch.LightFieldVideoDataset over the analytic fake dataset."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from support.fake import FakeDataset
from lfusd import LfusdError


@pytest.fixture(scope="module")
def ds():
    return FakeDataset(rows=5, cols=5, width=24, height=20, frames=(1, 2, 3, 4))


def test_module_does_not_shadow_pytorch():
    import lfusd.torch as lt
    import lfusd.evaluation.metrics_torch as mt

    assert mt.torch is torch and hasattr(torch, "Tensor")
    assert issubclass(lt.LightFieldVideoDataset, torch.utils.data.Dataset)


def test_items_hold_the_dataset_values(ds):
    from lfusd.torch import LightFieldVideoDataset

    d = LightFieldVideoDataset(ds, keys=("rgb", "disparity", "flow_fwd", "valid_fwd", "instance"), views="corners")
    assert len(d) == 3  # frame 4 has no forward motion
    item = d[1]
    assert item["frames"].tolist() == [2]
    assert item["views"].tolist() == [[0, 0], [0, 4], [4, 0], [4, 4]]
    assert item["rgb"].shape == (4, 3, 20, 24) and item["rgb"].dtype == torch.float32
    np.testing.assert_allclose(item["rgb"][3].permute(1, 2, 0).numpy(), ds.read(2, (4, 4), "rgb") / 255.0, atol=1e-7)
    np.testing.assert_array_equal(item["flow_fwd"][1].permute(1, 2, 0).numpy(), ds.read(2, (0, 4), "flow_fwd"))
    np.testing.assert_array_equal(item["disparity"][2].numpy(), ds.read(2, (4, 0), "disparity"))
    assert item["valid_fwd"].dtype == torch.bool and item["instance"].dtype == torch.int64
    assert item["offsets"].tolist() == [[-2, -2], [2, -2], [-2, 2], [2, 2]]


def test_crop_moves_the_principal_point(ds):
    from lfusd.torch import LightFieldVideoDataset

    d = LightFieldVideoDataset(ds, keys=("rgb", "depth"), views="centre", crop=(8, 10))
    item = d[0]
    y0, x0 = item["crop"].tolist()
    assert (y0, x0) == (6, 7)
    np.testing.assert_array_equal(item["depth"][0].numpy(), ds.read(1, (2, 2), "depth")[6:14, 7:17])
    k = item["intrinsics"][0].numpy()
    assert k[0, 2] == pytest.approx((24 - 1) / 2 - 7) and k[1, 2] == pytest.approx((20 - 1) / 2 - 6)
    torch.manual_seed(0)
    r = LightFieldVideoDataset(ds, keys=("rgb",), crop=8, random_crop=True)
    crops = {tuple(r[0]["crop"].tolist()) for _ in range(8)}
    assert len(crops) > 1 and all(0 <= y <= 12 and 0 <= x <= 16 for y, x in crops)


def test_clips_targets_and_dataloader(ds):
    from lfusd.torch import LightFieldVideoDataset

    d = LightFieldVideoDataset(ds, keys=("rgb", "flow_bwd"), views="corners", target_views="all", clip=2)
    assert len(d) == 2  # clips (2,3), (3,4): the first frame has no backward motion
    item = d[0]
    assert item["frames"].tolist() == [2, 3]
    assert item["rgb"].shape == (2, 4, 3, 20, 24) and item["flow_bwd"].shape == (2, 4, 2, 20, 24)
    assert item["target_rgb"].shape == (2, 25, 3, 20, 24)
    assert item["cam_to_world"].shape == (2, 4, 4, 4)
    batch = next(iter(torch.utils.data.DataLoader(d, batch_size=2)))
    assert batch["rgb"].shape == (2, 2, 4, 3, 20, 24)


def test_bad_arguments_are_one_line_errors(ds):
    from lfusd.torch import LightFieldVideoDataset

    for kw in ({"keys": ("colour",)}, {"views": [(9, 9)]}, {"crop": (64, 64)}, {"frames": [99]}, {"views": "diagonal"}, {"clip": 0}):
        with pytest.raises(LfusdError) as e:
            LightFieldVideoDataset(ds, **kw)
        assert "\n" not in str(e.value)
    with pytest.raises(LfusdError):
        LightFieldVideoDataset("/nonexistent/dataset/folder")
