"""lfusd.Dataset on small hand-made dataset folders: what it reads when, and that it never goes stale."""

from __future__ import annotations

import json
import pathlib

import numpy as np
import pytest

from lfusd import Dataset, LfusdError, layout
from lfusd.camera import RigSpec
from lfusd.data import integrity

RIG = RigSpec(name="main", rows=1, cols=2, width=8, height=6)


def make(root: pathlib.Path, frames=(1, 2), rendered=(1, 2), complete: list[int] | None = None) -> pathlib.Path:
    """A dataset folder with frame.json files and, for the ``rendered`` frames, view folders whose
    files (holding no image) match their completion record."""
    manifest = {"format": layout.FORMAT, "version": layout.FORMAT_VERSION, "rigs": ["main"], "frames": list(frames), "settings": {"rigs": {"main": RIG.to_dict()}}}
    if complete is not None:
        manifest["complete"] = {"main": complete}
    root.mkdir(parents=True, exist_ok=True)
    (root / layout.MANIFEST).write_text(json.dumps(manifest))
    (root / layout.OBJECTS).write_text(json.dumps({"classes": ["unlabelled"], "objects": [{"id": 1, "prim_path": "/World/A", "label": "", "class_id": 0}]}))
    for f in frames:
        d = layout.frame_dir(root, "main", f)
        d.mkdir(parents=True, exist_ok=True)
        write_pose(root, f, 0.0)
        if f in rendered:
            for v in RIG.views:
                (d / layout.view_key(v)).mkdir(exist_ok=True)
                for name in integrity.RENDER_FILES:
                    (d / layout.view_key(v) / name).write_bytes(b"stand-in")
                integrity.record_render(d / layout.view_key(v))
    return root


def write_pose(root, frame, x):
    pose = np.eye(4)
    pose[0, 3] = x
    meta = {"cam_to_world": {layout.view_key(v): pose.tolist() for v in RIG.views}, "object_poses": {"/World/A": pose.tolist()}}
    (layout.frame_dir(root, "main", frame) / layout.FRAME_META).write_text(json.dumps(meta))


def test_frames_come_from_the_manifest_once_and_refresh_looks_at_the_folders(tmp_path):
    root = make(tmp_path / "ds", frames=(1, 2, 3), rendered=(1, 2, 3), complete=[1, 2])
    ds = Dataset(root)
    assert ds.frames == [1, 2]  # the manifest's record, not a listing of the folders
    ds.refresh()
    assert ds.frames == [1, 2, 3]


def test_frames_of_an_old_manifest_are_found_in_the_folders(tmp_path):
    assert Dataset(make(tmp_path / "ds", frames=(1, 2, 3), rendered=(1, 3))).frames == [1, 3]


def test_a_view_whose_files_do_not_match_their_record_is_not_complete(tmp_path):
    root = make(tmp_path / "ds", frames=(1, 2, 3), rendered=(1, 2, 3))
    (layout.frame_dir(root, "main", 2) / "00_01" / layout.PASSES_EXR).write_bytes(b"cut")
    assert Dataset(root).frames == [1, 3]


def test_structure_properties_do_no_io(tmp_path, monkeypatch):
    ds = Dataset(make(tmp_path / "ds", complete=[1, 2]))

    def no_io(*args, **kw):
        raise AssertionError("file-system access in a property")

    for name in ("is_dir", "is_file", "exists", "stat", "read_text", "iterdir"):
        monkeypatch.setattr(pathlib.Path, name, no_io)
    for _ in range(3):
        assert ds.frames == [1, 2] and ds.views == [(0, 0), (0, 1)]
        assert ds.resolution == (8, 6) and ds.baseline == RIG.baseline


def test_a_reopened_dataset_sees_rewritten_files(tmp_path):
    """Caches belong to one Dataset: nothing is kept per path across instances."""
    root = make(tmp_path / "ds", complete=[1, 2])
    assert Dataset(root).cam_to_world(1, (0, 1))[0, 3] == 0.0
    assert Dataset(root).objects[1].poses[1][0, 3] == 0.0
    write_pose(root, 1, 2.5)
    assert Dataset(root).cam_to_world(1, (0, 1))[0, 3] == 2.5
    assert Dataset(root).objects[1].poses[1][0, 3] == 2.5


def test_unknown_and_underived_keys_are_one_line_errors(tmp_path):
    ds = Dataset(make(tmp_path / "ds", complete=[1, 2]))
    with pytest.raises(LfusdError, match="unknown ground-truth key 'flow'"):
        ds.read(1, (0, 0), "flow")
    with pytest.raises(LfusdError, match=f"no {layout.MOTION_FILE} .*'lfusd derive'"):
        ds.read(1, (0, 0), "flow_fwd")
