"""`lfusd export hf|webdataset`: tar shards read back with Hugging Face `datasets`, WebDataset's own
reader and mlcroissant, every array equal to the dataset's (an analytic fake, and a real render)."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest

from support.fake import FakeDataset

from lfusd import keys as keyreg
from lfusd import exports as export
from lfusd.exports.webdataset import sample_key

FAKE_KEYS = ("rgb", "depth", "normal", "instance", "flow_fwd", "flow_bwd", "scene_flow", "disparity_change",
             "valid_fwd", "valid_bwd", "occlusion_fwd", "occlusion_bwd")


@pytest.fixture(autouse=True)
def offline(monkeypatch, tmp_path):
    monkeypatch.setenv("HF_DATASETS_OFFLINE", "1")
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_HOME", str(tmp_path / "hf_home"))


def fake():
    ds = FakeDataset(root="/data/fakescene", rows=2, cols=3, width=24, height=20, frames=(1, 2, 3))
    ds.keys = FAKE_KEYS  # what the fake can read (Dataset records the keys a render wrote)
    return ds


def assert_same(got, want, name):
    got, want = np.asarray(got), np.asarray(want)
    assert got.shape == want.shape, name
    if want.dtype.kind == "f":
        np.testing.assert_array_equal(np.asarray(got, want.dtype), want, err_msg=name)  # NaN == NaN here, bit for bit otherwise
    else:
        np.testing.assert_array_equal(got, want, err_msg=name)


def check_round_trip(ds, dest, rig="rig"):
    """datasets.load_dataset('webdataset'), webdataset.WebDataset and mlcroissant give ds.read's arrays."""
    import datasets
    import mlcroissant as mlc
    import webdataset as wds

    names = [k for k in keyreg.stored(ds.keys) if k != "rgb"]
    names += [k for k, src in (("disparity", "depth"), ("semantic", "instance")) if src in names]  # the learning targets too
    expected = {sample_key(rig, t, v): (t, tuple(v)) for t in ds.frames for v in ds.views}
    shards = sorted(str(p) for p in (dest / "shards").glob("*.tar"))
    assert shards
    # Hugging Face datasets' webdataset builder
    hf = datasets.load_dataset("webdataset", data_files={"train": shards}, split="train", cache_dir=str(dest.parent / "hf_cache"))
    assert sorted(hf["__key__"]) == sorted(expected)
    hf = hf.with_format("numpy")
    for row in hf:
        t, v = expected[row["__key__"]]
        meta = row["json"]
        assert (meta["frame"], meta["row"], meta["col"]) == (t, *v)
        # (datasets' numpy format hands the json's numbers back as float32)
        np.testing.assert_allclose(meta["cam_to_world"], ds.cam_to_world(t, v), rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(meta["K"], ds.intrinsics(v), rtol=1e-6)
        assert_same(row["rgb.png"], ds.read(t, v, "rgb"), "rgb")
        for n in names:
            assert_same(row[f"{n}.npy"], ds.read(t, v, n), n)
    # WebDataset's own reader, raw bytes decoded with numpy (dtype kept exactly)
    seen = 0
    for s in wds.WebDataset(shards, shardshuffle=False).decode("rgb8"):
        t, v = expected[s["__key__"]]
        meta = s["json"] if isinstance(s["json"], dict) else json.loads(s["json"])
        assert meta["cam_to_world"] == ds.cam_to_world(t, v).tolist()  # exact through JSON
        for n in names:
            arr = np.load(io.BytesIO(s[f"{n}.npy"])) if isinstance(s[f"{n}.npy"], bytes) else s[f"{n}.npy"]
            assert arr.dtype == np.dtype(keyreg.get(n).dtype), n
            assert_same(arr, ds.read(t, v, n), n)
        seen += 1
    assert seen == len(expected)
    # mlcroissant: the metadata validates and its record sets give every key's bytes
    croissant = mlc.Dataset(jsonld=str(dest / "metadata.json"))
    meta = json.loads((dest / "metadata.json").read_text())
    assert {r["name"] for r in meta["recordSet"]} == {"rgb", "meta", *names}
    for n in names:
        field = next(f for r in meta["recordSet"] if r["name"] == n for f in r["field"] if f["name"] == n)
        k = keyreg.get(n)
        assert k.meaning in field["description"] and f"unit: {k.unit}" in field["description"] and k.dtype in field["description"]
        records = list(croissant.records(record_set=n))
        assert len(records) == len(expected)
        for rec in records:
            t, v = expected[rec[f"{n}/sample"].decode()]
            assert_same(np.load(io.BytesIO(rec[f"{n}/{n}"])), ds.read(t, v, n), n)
    for rec in croissant.records(record_set="rgb"):
        t, v = expected[rec["rgb/sample"].decode()]
        assert_same(np.asarray(rec["rgb/rgb"]), ds.read(t, v, "rgb"), "rgb")


@pytest.mark.slow
def test_webdataset_export_round_trips_with_datasets_webdataset_and_croissant(tmp_path):
    ds = fake()
    shards = export.export(ds, "webdataset", tmp_path / "wds")
    assert len(shards) == 1 and shards[0].name.startswith("fakescene-rig-000000-") and shards[0].suffix == ".tar"
    assert not (tmp_path / "wds" / "README.md").exists()
    check_round_trip(ds, tmp_path / "wds")


@pytest.mark.slow
def test_hf_export_loads_from_its_folder(tmp_path):
    import datasets

    ds = fake()
    export.export(ds, "hf", tmp_path / "hf", frame=2)
    card = (tmp_path / "hf" / "README.md").read_text()
    assert card.startswith("---\n") and "path: shards/*.tar" in card
    d = datasets.load_dataset(str(tmp_path / "hf"), split="train", cache_dir=str(tmp_path / "cache"))
    assert sorted(d["__key__"]) == sorted(sample_key("rig", 2, v) for v in ds.views)
    with pytest.raises(Exception, match="already exists"):
        export.export(ds, "hf", tmp_path / "hf")


@pytest.mark.slow
def test_hf_card_declares_every_array_so_rows_load_as_typed_arrays(tmp_path):
    """Issue 39.12: the card's features make every .npy a fixed-shape array of its key's dtype
    (not nested lists), instance and semantic int32; disparity and semantic are in the shards."""
    import datasets

    ds = fake()
    export.export(ds, "hf", tmp_path / "hf", frame=1)
    d = datasets.load_dataset(str(tmp_path / "hf"), split="train", cache_dir=str(tmp_path / "cache"))
    h, w = ds.rig.height, ds.rig.width
    names = [k for k in keyreg.stored(ds.keys) if k != "rgb"] + ["disparity", "semantic"]
    for n in names:
        k = keyreg.get(n)
        f = d.features[f"{n}.npy"]
        assert isinstance(f, (datasets.Array2D, datasets.Array3D)), (n, f)
        assert f.shape == (h, w, *k.shape) and f.dtype == k.dtype, (n, f)
    rows = d.with_format("numpy", dtype=None)
    for row in rows:
        key = row["__key__"]
        v = next(v for v in ds.views if sample_key("rig", 1, v) == key)
        for n in names:
            got = row[f"{n}.npy"]
            assert got.dtype == np.dtype(keyreg.get(n).dtype), n
            assert_same(got, ds.read(1, v, n), n)
    assert rows[0]["instance.npy"].dtype == np.int32


@pytest.mark.render
def test_rendered_dataset_round_trips(box_dataset, tmp_path):
    """The real reader: every stored key of a rendered rig, through the CLI."""
    from lfusd import Dataset
    from lfusd.cli import main

    _, out = box_dataset
    assert main(["export", "webdataset", str(out), str(tmp_path / "wds"), "--rig", "main"]) == 0
    ds = Dataset(out, rig="main")
    assert {"depth", "normal", "instance"} <= set(keyreg.stored(ds.keys))
    check_round_trip(ds, tmp_path / "wds", rig="main")
    objects = json.loads((tmp_path / "wds" / "objects.json").read_text())
    assert objects["classes"] == ds.classes


def test_metadata_carries_only_a_given_license_and_nothing_from_outside_the_dataset(tmp_path):
    """No license is claimed unless given; a recipe's scene record (scenes/<scene>.json) and card
    (card.json) lie outside the dataset's folder, so nothing of them is republished (issue 39 item 4:
    the certificate comes from the manifest, bound to the content, tests/test_safety.py)."""
    root = tmp_path / "recipe"
    (root / "scenes" / "street_000").mkdir(parents=True)
    (root / "scenes" / "street_000.json").write_text(json.dumps({"verified": True, "compared": 12345, "stats": {}}))
    (root / "card.json").write_text(json.dumps({"name": "streets", "verified": True, "pixels": 999, "scenes": []}))
    ds = FakeDataset(root=root / "scenes" / "street_000", rows=1, cols=2, width=16, height=12, frames=(1,))
    ds.keys = ("rgb", "depth")
    export.export(ds, "hf", tmp_path / "a")
    meta = json.loads((tmp_path / "a" / "metadata.json").read_text())
    assert not (tmp_path / "a" / "lfusd_verification.json").exists()
    assert "12345" not in meta["description"] and "Verification" not in meta["description"]
    assert "license" not in meta and "url" not in meta
    assert "license: unknown" in (tmp_path / "a" / "README.md").read_text()
    export.hf.export_hf(ds, tmp_path / "b", license="cc-by-4.0")
    assert json.loads((tmp_path / "b" / "metadata.json").read_text())["license"] == "cc-by-4.0"
    assert "license: cc-by-4.0" in (tmp_path / "b" / "README.md").read_text()
    # the metadata's keys and their descriptions come from lfusd.keys
    depth = next(r for r in meta["recordSet"] if r["name"] == "depth")
    assert keyreg.get("depth").meaning in depth["description"] and "H,W float32" in depth["description"]


def test_a_view_that_cannot_be_read_fails_the_export_instead_of_dropping_its_keys(tmp_path):
    """Issue 39 item 3: the keys come from the manifest (here: every key a still render makes),
    not from the first view; that view's damaged ground truth is one error, not an export
    without depth, normal and instance."""
    from types import SimpleNamespace

    from lfusd.errors import LfusdError

    class Damaged(FakeDataset):
        def read(self, frame, view, key):
            if tuple(view) == (0, 0) and key != "rgb":
                raise LfusdError(f"{self.root}/f000001/00_00/gt.exr is damaged; rerun the render")
            return super().read(frame, view, key)

    ds = Damaged(root=tmp_path / "scene", rows=1, cols=2, width=16, height=12, frames=(1,))
    ds.keys = None  # format version 1, or a render of every key: the manifest records no key list
    ds.record = SimpleNamespace(settings=SimpleNamespace(motion=False), certificate=None)
    names = webdataset_keys(ds)
    assert {"depth", "normal", "instance"} <= set(names) and not {"flow_fwd", "scene_flow"} & set(names)
    with pytest.raises(LfusdError, match="gt.exr is damaged"):
        export.export(ds, "webdataset", tmp_path / "out")
    assert not (tmp_path / "out").exists()


def webdataset_keys(ds):
    from lfusd.exports.webdataset import exported_keys

    return exported_keys(ds)
