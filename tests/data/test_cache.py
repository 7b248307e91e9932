"""The training cache (lfusd.data.cache, `lfusd export cache`) and the loader reading it."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
import torch

from support.fake import FakeDataset
from lfusd import LfusdError
from lfusd import keys as keyreg

KEYS = ("rgb", "depth", "disparity", "position", "normal", "instance", "flow_fwd", "flow_bwd", "scene_flow", "disparity_change",
        "valid_fwd", "occlusion_bwd")


@pytest.fixture(scope="module")
def fake():
    return FakeDataset(rows=3, cols=5, width=24, height=20, frames=(1, 2, 3))


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal dtype, shape and bytes (NaN payloads and signed zeros included)."""
    a, b = np.ascontiguousarray(a), np.ascontiguousarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def check_every_key(ds, cache) -> int:
    n = 0
    assert list(cache.frames) == list(ds.frames)
    for t in ds.frames:
        for v in ds.views:
            for k in cache.keys:
                assert same_bits(cache.read(t, v, k), ds.read(t, v, k)), (t, v, k)
                n += 1
            np.testing.assert_array_equal(cache.cam_to_world(t, v), ds.cam_to_world(t, v))
            np.testing.assert_array_equal(cache.intrinsics(v), ds.intrinsics(v))
    return n


def test_every_key_of_every_view_equals_the_reader(fake, tmp_path):
    from lfusd.data.cache import TrainingCache, write_cache

    write_cache(fake, tmp_path / "c", keys=KEYS)
    cache = TrainingCache(tmp_path / "c")
    assert set(cache.keys) == set(KEYS) and cache.rig == fake.rig
    assert list(cache.keys) == [k for k in keyreg.KEYS if k in KEYS]  # registry order, whatever order they were asked in
    assert check_every_key(fake, cache) == 3 * 15 * len(KEYS)
    # uncompressed: each file is the decoded array plus a header of at most 128 bytes
    for k in KEYS:
        size = (tmp_path / "c" / "000002" / f"{k}.npy").stat().st_size
        assert 0 < size - fake.read(2, (0, 0), k).nbytes * 15 <= 128


def test_loader_items_from_the_cache_equal_the_dataset_items(fake, tmp_path):
    from lfusd.data.cache import write_cache
    from lfusd.torch import LightFieldVideoDataset

    write_cache(fake, tmp_path / "c", keys=KEYS)
    keys = ("rgb", "disparity", "flow_fwd", "valid_fwd", "instance", "scene_flow")
    for views in ("all", "cross", [(2, 4), (0, 1)]):
        slow = LightFieldVideoDataset(fake, keys=keys, views=views, crop=(8, 10), clip=2)
        fast = LightFieldVideoDataset(str(tmp_path / "c"), keys=keys, views=views, crop=(8, 10), clip=2)
        assert len(slow) == len(fast) == 1
        a, b = slow[0], fast[0]
        assert a.keys() == b.keys()
        for k in a:
            assert a[k].dtype == b[k].dtype and a[k].shape == b[k].shape, k
            assert torch.equal(a[k], b[k]) or (a[k].is_floating_point() and torch.equal(a[k].nan_to_num(7.0), b[k].nan_to_num(7.0))), k


def test_a_rerun_completes_and_repairs(fake, tmp_path):
    from lfusd.data.cache import RECORD, TrainingCache, write_cache

    dest = tmp_path / "c"
    write_cache(fake, dest, frame=2, keys=("rgb", "depth"))
    assert TrainingCache(dest).frames == [2]
    (dest / "000002" / "depth.npy").write_bytes(b"broken")  # a damaged file
    (dest / "000002" / ".rgb.npy.ab12cd34.tmp").write_bytes(b"left by a killed run")
    (dest / "000002" / "notes.txt").write_text("a user's")
    mtime = os.stat(dest / "000002" / "rgb.npy").st_mtime_ns
    write_cache(fake, dest, keys=("depth", "rgb"))  # the recorded keys (in another order), every frame
    cache = TrainingCache(dest)
    assert cache.frames == [1, 2, 3] and cache.keys == ("rgb", "depth")
    check_every_key(fake, cache)
    assert os.stat(dest / "000002" / "rgb.npy").st_mtime_ns != mtime  # the frame's files were written again
    with pytest.raises(LfusdError, match="another dataset, rig or key set"):
        write_cache(fake, dest, keys=("rgb",))
    doc = json.loads((dest / RECORD).read_text())
    assert sorted(doc["frames"]) == ["1", "2", "3"]
    assert sorted(p.name for p in (dest / "000002").iterdir()) == ["cam_to_world.npy", "depth.npy", "notes.txt", "rgb.npy"]


def test_refusals(fake, tmp_path):
    from lfusd.data.cache import TrainingCache, write_cache

    (tmp_path / "user").mkdir()
    (tmp_path / "user" / "notes.txt").write_text("mine")
    with pytest.raises(LfusdError, match="not empty and holds no lfusd training cache"):
        write_cache(fake, tmp_path / "user", keys=("rgb",))
    assert sorted(p.name for p in (tmp_path / "user").iterdir()) == ["notes.txt"]
    target = tmp_path / "elsewhere"
    target.mkdir()
    os.symlink(target, tmp_path / "link")
    with pytest.raises(LfusdError, match="symbolic link"):
        write_cache(fake, tmp_path / "link", keys=("rgb",))
    assert list(target.iterdir()) == []
    dest = tmp_path / "c"
    write_cache(fake, dest, frame=1, keys=("rgb",))
    os.symlink(target, dest / "000002")  # a planted frame folder
    with pytest.raises(LfusdError, match="symbolic link"):
        write_cache(fake, dest)
    assert list(target.iterdir()) == []
    with pytest.raises(LfusdError, match="not in the cache"):
        TrainingCache(dest).read(1, (0, 0), "depth")
    with pytest.raises(LfusdError, match="no training cache"):
        TrainingCache(tmp_path / "user")
    with pytest.raises(LfusdError, match="unknown ground-truth key"):
        write_cache(fake, tmp_path / "d", keys=("rgb", "colour"))
    assert not (tmp_path / "d").exists()


def test_items_are_copy_on_write_and_uint8_rgb_is_the_stored_bytes(fake, tmp_path):
    from lfusd.data.cache import write_cache
    from lfusd.torch import LightFieldVideoDataset

    write_cache(fake, tmp_path / "c", keys=("rgb", "depth"))
    item = LightFieldVideoDataset(str(tmp_path / "c"), keys=("rgb", "depth"), views="all", uint8_rgb=True)[0]
    assert item["rgb"].dtype == torch.uint8
    np.testing.assert_array_equal(item["rgb"][4].permute(1, 2, 0).numpy(), fake.read(1, (0, 4), "rgb"))
    item["depth"] += 1  # an in-place change of the item reaches neither the file nor the next item
    item2 = LightFieldVideoDataset(str(tmp_path / "c"), keys=("depth",), views="all")[0]
    np.testing.assert_array_equal(item2["depth"][0].numpy(), fake.read(1, (0, 0), "depth"))
    slow = LightFieldVideoDataset(fake, keys=("rgb",), views="cross", uint8_rgb=True, crop=5)[2]
    fast = LightFieldVideoDataset(str(tmp_path / "c"), keys=("rgb",), views="cross", uint8_rgb=True, crop=5)[2]
    assert torch.equal(slow["rgb"], fast["rgb"])


@pytest.mark.render
def test_the_cache_of_a_rendered_dataset_equals_its_reader_bit_for_bit(box_dataset, tmp_path):
    """Every key of every view of both rendered rigs (a planar 3x3 and a spherical 2x3), through the CLI."""
    from lfusd import Dataset
    from lfusd.cli import main
    from lfusd.data.cache import TrainingCache

    _, out = box_dataset
    for rig in ("main", "dome"):
        assert main(["export", "cache", str(out), str(tmp_path / rig), "--rig", rig]) == 0
        ds, cache = Dataset(out, rig=rig), TrainingCache(tmp_path / rig)
        assert {"rgb", "depth", "normal", "position", "instance", "semantic", "depth_euclidean"} <= set(cache.keys)
        assert check_every_key(ds, cache) == len(ds.frames) * len(ds.views) * len(cache.keys)
        assert (tmp_path / rig / "manifest.json").read_bytes() == (out / "manifest.json").read_bytes()
        assert main(["export", "cache", str(out), str(tmp_path / rig), "--rig", rig]) == 0  # a rerun of a complete cache changes nothing


def test_workers_forked_after_the_parent_read_open_their_own_maps(fake, tmp_path):
    from lfusd.data.cache import write_cache
    from lfusd.torch import LightFieldVideoDataset, data_loader

    write_cache(fake, tmp_path / "c", keys=("rgb", "disparity"))
    d = LightFieldVideoDataset(str(tmp_path / "c"), keys=("rgb", "disparity"), views="corners")
    first = d[0]  # the parent maps the files before the workers fork
    batches = list(data_loader(d, batch_size=1, shuffle=False, num_workers=2))
    assert [int(b["frames"][0, 0]) for b in batches] == [1, 2, 3]
    assert torch.equal(batches[0]["rgb"][0], first["rgb"]) and torch.equal(batches[2]["disparity"][0], d[2]["disparity"])


def test_data_loader_batches_equal_the_stacked_items(fake, tmp_path):
    """data_loader reads uint8 rgb and divides after collation: the same float32 values as the items."""
    from lfusd.data.cache import write_cache
    from lfusd.torch import LightFieldVideoDataset, data_loader

    write_cache(fake, tmp_path / "c", keys=("rgb", "disparity"))
    for source in (fake, str(tmp_path / "c")):
        d = LightFieldVideoDataset(source, keys=("rgb", "disparity"), views="cross", crop=7)
        (batch,) = list(data_loader(d, batch_size=3, shuffle=False))
        items = [d[i] for i in range(3)]
        assert not d.uint8_rgb and batch["rgb"].dtype == torch.float32
        for k in ("rgb", "disparity", "intrinsics", "cam_to_world"):
            assert torch.equal(batch[k], torch.stack([it[k] for it in items])), k


def test_a_key_the_dataset_lacks_for_a_frame_is_recorded_missing(tmp_path):
    from lfusd.data.cache import TrainingCache, write_cache

    class Gappy(FakeDataset):
        def read(self, frame, view, key):
            if frame == 3 and key == "flow_fwd" and tuple(view) == (1, 1):  # fails mid-frame, after other views were written
                raise LfusdError("no flow here")
            return super().read(frame, view, key)

    ds = Gappy(rows=2, cols=2, width=8, height=6, frames=(1, 2, 3))
    write_cache(ds, tmp_path / "c", keys=("rgb", "flow_fwd"))
    cache = TrainingCache(tmp_path / "c")
    assert cache.frames == [1, 2, 3]
    assert same_bits(cache.read(3, (1, 1), "rgb"), ds.read(3, (1, 1), "rgb"))
    with pytest.raises(LfusdError, match="gave no 'flow_fwd' for frame 3"):
        cache.read(3, (0, 0), "flow_fwd")
    assert sorted(p.name for p in (tmp_path / "c" / "000003").iterdir()) == ["cam_to_world.npy", "rgb.npy"]
