"""One error contract (issue 26 item 3): every command that reads a dataset (verify, verify --integrity,
derive, eval, export, preview, dataset make) answers a corrupt or incomplete manifest, object table or
frame record with one line naming the file and the fix, exit 2, as ``lfusd.Dataset`` does: they all
read it through lfusd.data.dataset.read_manifest. On main, verify and flow ended in internal errors
(JSONDecodeError, KeyError, TypeError; exit 3).

The dataset is written by ``lfusd render`` with the Blender workers stood in for (the view folders a
worker commits), so these run in seconds."""

from __future__ import annotations

import json
import shutil

import pytest
from support.fake import fake_run_units
from support.cli import assert_one_line_error, run_cli
from support.scenes import write_box_stage

from lfusd import Dataset
from lfusd.camera import RigSpec
from lfusd.errors import LfusdError
from lfusd.layout import FRAME_META, MANIFEST, OBJECTS, frame_dir
from lfusd.render import executors
from lfusd.truth import derive

RIG = RigSpec(name="main", rows=1, cols=2, width=16, height=12, baseline=0.1, at=(0, -5, 1), look_at=(0, 0, 0.5))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("contract")
    stage = root / "scene.usda"
    write_box_stage(stage, [RIG])
    mp = pytest.MonkeyPatch()

    run_units = fake_run_units()

    mp.setattr(executors, "run_units", run_units)
    mp.setattr(derive, "derive_dataset", lambda *a, **k: 0)
    from lfusd.cli import main

    out = root / "out"
    try:
        assert main(["render", str(stage), "-o", str(out), "--samples", "1", "--device", "cpu", "--quiet"]) == 0
    finally:
        mp.undo()
    return out


def _edit(key_path):
    """A damage to the manifest: delete or replace the field at ``key_path`` (a tuple of keys)."""
    def damage(m, value):
        *parents, last = key_path
        for k in parents:
            m = m[k]
        if value is _DELETE:
            del m[last]
        else:
            m[last] = value
    return damage


_DELETE = object()
CORRUPT = {
    "invalid JSON": ("text", '{"format": "lfusd-dataset", "rigs": ['),
    "empty file": ("text", ""),
    "a list, not a record": ("text", "[1, 2]"),
    "no rigs": ("rigs",), "rigs a string": ("rigs", "main"), "rigs of numbers": ("rigs", [1]),
    "no frames": ("frames",), "frames a string": ("frames", "1-4"), "frames of strings": ("frames", ["1"]),
    "no settings": ("settings",), "settings a list": ("settings", []),
    "no rig specs": ("settings", "rigs"), "rig specs a list": ("settings", "rigs", ["main"]),
    "rig spec mistyped": ("settings", "rigs", "main", "rows", "three"),
    "rig spec incomplete": ("settings", "rigs", "main", "at"),
    "keys mistyped": ("settings", "keys", 7),
    "version mistyped": ("version", "two"),
    "complete mistyped": ("complete", {"main": "all"}),
    "stage mistyped": ("stage", "scene.usda"),
}


def _corrupt(out, case):
    spec = CORRUPT[case]
    path = out / MANIFEST
    if spec[0] == "text":
        path.write_text(spec[1])
        return
    m = json.loads(path.read_text())
    if len(spec) == 1 or (len(spec) == 2 and spec[0] == "settings" and spec[1] == "rigs") or case == "rig spec incomplete":
        keys, value = spec, _DELETE
    else:
        keys, value = spec[:-1], spec[-1]
    _edit(keys)(m, value)
    path.write_text(json.dumps(m))


def commands(out, tmp_path):
    pred = tmp_path / "pred"
    pred.mkdir(exist_ok=True)
    return {
        "verify": ("verify", out),
        "verify --integrity": ("verify", out, "--integrity"),
        "derive": ("derive", out),
        "eval": ("eval", "--task", "disparity", "--pred", pred, "--gt", out),
        "export": ("export", "flo", out, tmp_path / "flo"),
        "preview": ("preview", out, "-o", tmp_path / "preview", "--no-video"),
    }


@pytest.mark.parametrize("case", list(CORRUPT))
def test_a_corrupt_manifest_is_one_line_and_exit_2_in_every_command(capsys, tmp_path, dataset, case):
    out = tmp_path / "out"
    shutil.copytree(dataset, out)
    _corrupt(out, case)
    with pytest.raises(LfusdError) as e:
        Dataset(out)
    assert MANIFEST in str(e.value) and "\n" not in str(e.value)
    for name, argv in commands(out, tmp_path).items():
        code, _, err = run_cli(capsys, *argv)
        assert code == 2, (name, err)
        assert_one_line_error(code, err, str(out / MANIFEST))
    assert not (tmp_path / "flo").exists() and not (tmp_path / "preview").exists()


@pytest.mark.parametrize("file, text, words", [
    (OBJECTS, "{oops", "unreadable"),
    (OBJECTS, json.dumps({"classes": [""], "objects": [{"id": 1}]}), "not written by lfusd or is damaged"),
    (OBJECTS, json.dumps({"classes": [""], "objects": [{"id": 1, "prim_path": 5, "label": "", "class_id": 0}]}), "no prim path or label string"),
    (FRAME_META, "{oops", "unreadable"),
    (FRAME_META, json.dumps({"cam_to_world": {}, "object_poses": {}}), "no pose of 00_00"),
    (FRAME_META, json.dumps({"cam_to_world": {"00_00": [[1, 0], [0, 1]]}, "object_poses": {}}), "no 4x4 pose"),
    (FRAME_META, json.dumps([]), "not a JSON object"),
])
def test_a_corrupt_object_table_or_frame_record_is_one_line(capsys, tmp_path, dataset, file, text, words):
    out = tmp_path / "out"
    shutil.copytree(dataset, out)
    path = out / file if file == OBJECTS else frame_dir(out, "main", 1) / file
    path.write_text(text)
    with pytest.raises(LfusdError) as e:
        ds = Dataset(out)
        ds.cam_to_world(1, (0, 0))
        ds.objects
    assert str(path) in str(e.value) and words in str(e.value) and "\n" not in str(e.value)
    for name, argv in commands(out, tmp_path).items():
        if name in ("verify --integrity", "derive") or (file == FRAME_META and name != "verify"):
            continue  # they read neither (records and raw passes only); the others read poses after the (fake) pixels
        code, _, err = run_cli(capsys, *argv)
        assert code == 2, (name, err)
        assert_one_line_error(code, err, str(path), words)


def test_dataset_make_reads_its_scenes_through_the_same_reader(capsys, tmp_path, dataset, monkeypatch):
    """A recipe's scene whose render left a corrupt manifest: verification of the scene is one line."""
    from pathlib import Path

    from lfusd.author import scenes
    from lfusd.render import job

    recipes = Path(__file__).resolve().parents[1] / "recipes"

    def fake_render(req, *a, **k):
        shutil.copytree(dataset, req.out)
        _corrupt(req.out, "no rigs")

    monkeypatch.setattr(scenes, "generate", lambda template, stage, *a, **k: Path(stage).parent.mkdir(parents=True, exist_ok=True)
                        or Path(stage).write_text("#usda 1.0\n"))
    monkeypatch.setattr(job, "render", fake_render)
    monkeypatch.setattr(job, "render_video", fake_render)
    code, _, err = run_cli(capsys, "dataset", "make", recipes / "tiny.toml", "-o", tmp_path / "ds", "--quiet")
    assert_one_line_error(code, err, MANIFEST, "no 'rigs'")
    assert code == 2
