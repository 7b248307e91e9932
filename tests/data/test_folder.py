"""The dataset folder's one owner (lfusd.data.folder): atomic writes, typed records that write back
exactly what they read, the security checks on the way in, and the opener."""

from __future__ import annotations

import json
import os
import stat
from dataclasses import replace

import numpy as np
import pytest
from support.fake import FakeDataset
from test_faults import fake_render, project, render  # noqa: F401  (fixtures)

from lfusd import Dataset, LfusdError, layout
from lfusd.camera import RigSpec
from lfusd.data import folder
from lfusd.data.dataset import open_dataset, open_datasets
from lfusd.data.folder import FrameMeta, Manifest, ObjectTable, RenderSettings

EYE = np.eye(4).tolist()


def _manifest_doc(**extra) -> dict:
    """A manifest as lfusd writes it (fields in its order), plus ``extra`` fields."""
    return {
        "format": layout.FORMAT, "version": 2, "id": "0123abcd",
        "stage": {"path": "/p/scene.usda", "sha256": "ab", "files": {}},
        "world": {"up_axis": "Y", "meters_per_unit": 0.01},
        "rigs": ["main"], "frames": [1, 2, 3],
        "settings": {"stage_id": "x", "versions": {"lfusd": "0.1.0", "bpy": "5.0.1"},
                     "rigs": {"main": RigSpec(name="main", rows=1, cols=2, width=8, height=6).to_dict()},
                     "samples": 4, "motion": True, "light": "auto", "format_version": 2, "keys": ["rgb", "depth"],
                     "keep_raw": False, "stage_frames": [1, 3]},
        "device": None, "complete": {"main": [1, 2]}, "software": {"python": "3.11"}, "layout": "OUT/...",
        **extra,
    }


def test_a_manifest_writes_back_byte_for_byte_what_it_read_unknown_fields_included():
    doc = _manifest_doc(certificate={"main": {"ok": True}}, note_from_a_newer_lfusd=[1, 2])
    m = Manifest.from_dict(json.loads(json.dumps(doc)))
    assert m.to_json() == json.dumps(doc, indent=1)
    assert m.rigs == ("main",) and m.frames == (1, 2, 3) and m.version == 2 and m.device is None
    assert m.settings.keys == ("rgb", "depth") and m.settings.motion and m.settings.stage_frames == (1, 3)
    assert m.complete_frames("main") == [1, 2] and m.complete_frames("other") is None
    assert m.rig_spec("main").cols == 2


def test_fields_a_manifest_lacks_read_as_defaults_and_stay_absent():
    doc = {k: v for k, v in _manifest_doc().items() if k not in ("version", "complete", "world", "device")}
    doc["settings"] = {k: v for k, v in doc["settings"].items() if k in ("rigs", "samples")}
    m = Manifest.from_dict(doc)
    assert m.version == 1 and m.complete_frames("main") is None and m.settings.keys is None and not m.settings.motion
    assert m.to_dict() == doc and list(m.to_dict()) == list(doc)
    # a field set afterwards is written after the document's own, in lfusd's order
    cert = replace(m, certificate={"main": {}}).to_dict()
    assert list(cert)[-1] == "certificate" and list(cert)[:-1] == list(doc)


def test_a_new_record_writes_its_fields_in_the_order_given():
    m = Manifest.new(format=layout.FORMAT, version=2, id="x", rigs=("a",), frames=(4, 5),
                     settings=RenderSettings.from_dict({"rigs": {}, "keys": None}), device=None)
    assert json.loads(m.to_json()) == {"format": layout.FORMAT, "version": 2, "id": "x", "rigs": ["a"], "frames": [4, 5],
                                        "settings": {"rigs": {}, "keys": None}, "device": None}
    assert list(json.loads(m.to_json())) == ["format", "version", "id", "rigs", "frames", "settings", "device"]


@pytest.mark.parametrize("field,value,named", [
    ("rigs", ["../victim"], "rig name"),  # would become a path
    ("frames", [1, 10**12], "frame"),
    ("rigs", [], "rigs"),
    ("settings", "fast", "settings"),
    ("format", "something-else", "not an lfusd dataset manifest"),
])
def test_a_crafted_manifest_is_one_line_naming_the_file(field, value, named):
    doc = _manifest_doc()
    doc[field] = value
    with pytest.raises(LfusdError) as e:
        Manifest.from_dict(doc, "/d/manifest.json")
    msg = str(e.value)
    assert "/d/manifest.json" in msg and named in msg and "\n" not in msg


def test_object_table_and_frame_meta_round_trip_and_refuse_what_lfusd_does_not_write():
    table = {"classes": ["unlabelled", "box"], "objects": [{"id": 1, "prim_path": "/World/Box", "label": "box", "class_id": 1, "meshes": ["/World/Box/m"]}]}
    t = ObjectTable.from_dict(json.loads(json.dumps(table)))
    assert t.to_json() == json.dumps(table, indent=1) and t.objects[0].prim_path == "/World/Box" and t.objects[0].meshes == ("/World/Box/m",)
    with pytest.raises(LfusdError, match="objects.json"):
        ObjectTable.from_dict({"classes": ["a"], "objects": [{"id": 1, "prim_path": 5, "label": "a", "class_id": 0}]})
    meta = {"frame": 2, "time_code": 2, "cam_to_world": {"00_00": EYE}, "object_poses": {"/World/Box": EYE}}
    f = FrameMeta.from_dict(json.loads(json.dumps(meta)), "frame.json", views=["00_00"], prims=["/World/Box"])
    assert f.to_json() == json.dumps(meta) and np.array_equal(f.cam_to_world["00_00"], np.eye(4))
    with pytest.raises(LfusdError, match="4x4"):
        FrameMeta.from_dict({**meta, "cam_to_world": {"00_00": [[1, 0], [0, 1]]}}, "frame.json")
    with pytest.raises(LfusdError, match="no pose of 00_01"):
        FrameMeta.from_dict(meta, "frame.json", views=["00_00", "00_01"])


def test_atomic_write_writes_text_bytes_or_through_a_writer_and_a_failure_leaves_nothing(tmp_path):
    p = tmp_path / "a.json"
    folder.atomic_write(p, "one")
    assert p.read_text() == "one"
    folder.atomic_write(p, b"\x00two", sync=True)
    assert p.read_bytes() == b"\x00two"
    assert stat.S_IMODE(p.stat().st_mode) == 0o666 & ~_umask()  # readable like the folder's other files, not mkstemp's 0600
    folder.atomic_write(tmp_path / "m.npz", lambda tmp: np.savez(tmp, a=np.arange(3)), prefix=".m.", suffix=".npz")
    assert np.load(tmp_path / "m.npz")["a"].tolist() == [0, 1, 2]

    def dies(tmp):
        with open(tmp, "w") as f:
            f.write("half")
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError):
        folder.atomic_write(p, dies)
    assert p.read_bytes() == b"\x00two" and sorted(x.name for x in tmp_path.iterdir()) == ["a.json", "m.npz"]


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def test_the_writer_output_round_trips_and_opens_through_the_one_opener(capsys, tmp_path, project, fake_render):  # noqa: F811
    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    text = (out / layout.MANIFEST).read_text()
    assert folder.read_manifest(out).to_json() == text  # what the render wrote is what the record writes
    assert folder.read_objects(out).to_json() == (out / layout.OBJECTS).read_text()
    meta = layout.frame_dir(out, "main", 1) / layout.FRAME_META
    assert folder.read_frame_meta(meta).to_json() == meta.read_text()
    assert folder.existing_dataset(out) == folder.read_manifest(out)
    (ds,) = open_datasets(out)
    assert isinstance(ds, Dataset) and ds.record.rigs == ("main",) and ds.manifest == json.loads(text)
    with pytest.raises(LfusdError, match="does not exist"):
        open_dataset(tmp_path / "nowhere")


def test_a_dataset_and_the_analytic_fake_read_like_a_dataset():
    assert isinstance(FakeDataset(root="/d/s", rows=1, cols=2, width=8, height=6, frames=(1, 2)), folder.DatasetLike)
    assert not isinstance(object(), folder.DatasetLike)


def test_one_resumable_folder_rule_for_render_study_and_recipe(tmp_path):
    """A missing or empty folder (its lock aside) is new; a file, or other files without the
    record, is refused in one line and left as it was; a record is read by the caller's check."""
    def read(path):
        return path.read_text()

    def check(out, **kw):
        return folder.resumable_folder(out, "record.json", "study", "rig study", read, **kw)

    assert check(tmp_path / "new") is None
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / layout.LOCK).write_text("")
    assert check(tmp_path / "empty") is None
    (tmp_path / "file").write_text("x")
    with pytest.raises(LfusdError, match="is a file; give a folder for the study"):
        check(tmp_path / "file")
    users = tmp_path / "users"
    users.mkdir()
    (users / "notes.txt").write_text("mine")
    with pytest.raises(LfusdError) as e:
        check(users)
    assert "not empty and holds no rig study" in str(e.value) and "\n" not in str(e.value)
    assert check(users, foreign=True) is None  # a recipe's folder may hold other files
    assert sorted(p.name for p in users.iterdir()) == ["notes.txt"]
    (users / "record.json").write_text("ours")
    assert check(users) == "ours"


@pytest.mark.parametrize("command", [["preview"], ["export", "hci"]])
def test_a_two_rig_dataset_opened_without_rig_names_the_rig_option(capsys, tmp_path, command):
    """Issue 39.19: `lfusd preview OUT` on a dataset of two rigs says `--rig NAME`, not a Python call."""
    from support.cli import assert_one_line_error, run_cli

    out = tmp_path / "two"
    out.mkdir()
    doc = _manifest_doc(rigs=["left", "right"], complete={"left": [1], "right": [1]})
    doc["settings"]["rigs"] = {r: RigSpec(name=r, rows=1, cols=2, width=8, height=6).to_dict() for r in ("left", "right")}
    (out / layout.MANIFEST).write_text(json.dumps(doc))
    code, _, err = run_cli(capsys, *command, out, *([tmp_path / "dest"] if command[0] == "export" else []))
    assert_one_line_error(code, err, "holds rigs left, right", "--rig NAME")
    assert "Dataset(" not in err and not (tmp_path / "dest").exists()
