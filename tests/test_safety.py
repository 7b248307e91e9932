"""Nothing outside what the user named (issue 29): a crafted dataset folder, manifest, checkpoint
or stage cannot make lfusd write, delete or read outside the folder the user gave, run code, or
open a cluster to others. Each test starts from the crafted input that broke lfusd before (a
``.lock`` or log link to a canary file, a manifest naming ``../canary`` or an absolute folder as a
rig, a symlinked rig folder, a user's file inside a rig folder with ``--overwrite``, a pickle
payload checkpoint, a same-size same-mtime texture edit, ...) and shows the canary intact, the
payload not run, the edit refused.

Renders are stood in for by ``fake_render`` (tests/test_faults.py: view folders with their
completion records), so the checks run in seconds.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from support.cli import assert_one_line_error, run_cli
from test_faults import fake_render, project, render, snapshot  # noqa: F401  (fixtures)

from lfusd import Dataset
from lfusd.data import confined
from lfusd.errors import LfusdError
from lfusd.layout import frame_dir

CANARY = b"the user's precious file\n"


@pytest.fixture
def canary(tmp_path) -> Path:
    """A user's file and folder outside every dataset folder: nothing may touch them."""
    home = tmp_path / "home"
    (home / "photos").mkdir(parents=True)
    (home / "precious.txt").write_bytes(CANARY)
    (home / "photos" / "cat.png").write_bytes(CANARY)
    # shaped like what lfusd's resume used to clean: <rig>/f*/.*.tmp-*
    (home / "f000001" / ".00_00.tmp-1-2").mkdir(parents=True)
    (home / "f000001" / ".00_00.tmp-1-2" / "keep.txt").write_bytes(CANARY)
    return home


def intact(home: Path) -> bool:
    return (snapshot(home) == {
        "f000001": None, "f000001/.00_00.tmp-1-2": None, "f000001/.00_00.tmp-1-2/keep.txt": CANARY,
        "photos": None, "photos/cat.png": CANARY, "precious.txt": CANARY})


def snap(out: Path) -> dict:
    """:func:`snapshot` without the lock file (each run writes its pid there)."""
    return {k: v for k, v in snapshot(out).items() if k != ".lock"}


def edit_manifest(out: Path, change) -> None:
    path = out / "manifest.json"
    m = json.loads(path.read_text())
    change(m)
    path.write_text(json.dumps(m))


# -- 1. no link is followed for writing or deleting inside OUT ----------------------------------


@pytest.mark.parametrize("existing", [False, True])
def test_a_lock_link_to_a_users_file_is_refused_and_the_file_untouched(capsys, tmp_path, project, fake_render, canary, existing):
    out = tmp_path / "out"
    if existing:
        assert render(capsys, project / "scene.usda", out)[0] == 0
        (out / ".lock").unlink()
    else:
        out.mkdir()  # a folder holding only the planted link is not an empty folder
    (out / ".lock").symlink_to(canary / "precious.txt")
    for command in ("render", "render-video"):
        code, _, err = run_cli(capsys, command, project / "scene.usda", "-o", out, "--samples", "1", "--device", "cpu", "--quiet")
        assert_one_line_error(code, err, ".lock")
        assert code == 2
    assert intact(canary)


def test_dataset_make_refuses_a_lock_link(capsys, tmp_path, canary):
    root = tmp_path / "made"
    root.mkdir()
    (root / ".lock").symlink_to(canary / "precious.txt")
    recipe = Path(__file__).resolve().parents[1] / "recipes" / "tiny.toml"
    code, _, err = run_cli(capsys, "dataset", "make", recipe, "-o", root, "--quiet")
    assert_one_line_error(code, err, ".lock", "symbolic link")
    assert intact(canary) and sorted(p.name for p in root.iterdir()) == [".lock"]


@pytest.mark.parametrize("entry", ["stages", "scenes"])
def test_dataset_make_refuses_a_linked_stages_or_scenes_folder(capsys, tmp_path, canary, entry):
    root = tmp_path / "made"
    root.mkdir()
    (root / entry).symlink_to(canary)
    recipe = Path(__file__).resolve().parents[1] / "recipes" / "tiny.toml"
    code, _, err = run_cli(capsys, "dataset", "make", recipe, "-o", root, "--quiet")
    assert_one_line_error(code, err, str(root / entry), "symbolic link")
    assert intact(canary)


@pytest.mark.parametrize("entry", ["logs/main-unit0000.log", "logs", ".scratch", "objects.json"])
def test_a_link_among_lfusds_entries_is_refused_before_anything_is_written(capsys, tmp_path, project, fake_render, canary, entry):
    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    target = out / entry
    if target.is_dir():
        os.rename(target, tmp_path / "moved")
    elif target.exists():
        target.unlink()
    target.parent.mkdir(exist_ok=True)
    target.symlink_to(canary / "precious.txt" if "." in target.name and entry != ".scratch" else canary)
    before = snap(out)
    code, _, err = render(capsys, project / "scene.usda", out, "--frame", "2")
    assert_one_line_error(code, err, entry, "symbolic link")
    assert intact(canary) and snap(out) == before


def test_a_worker_log_is_never_written_through_a_link(tmp_path, canary):
    link = tmp_path / "main-unit0000.log"
    link.symlink_to(canary / "precious.txt")
    with pytest.raises(LfusdError, match="symbolic link"):
        confined.open_new(link)
    with pytest.raises(LfusdError, match="symbolic link"):
        confined.open_new(link, append=True)
    assert intact(canary)


@pytest.mark.parametrize("overwrite", [False, True])
def test_a_symlinked_rig_folder_is_refused_and_its_target_untouched(capsys, tmp_path, project, fake_render, canary, overwrite):
    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    os.rename(out / "main", tmp_path / "moved")
    (out / "main").symlink_to(canary)
    extra = ("--samples", "2", "--overwrite") if overwrite else ()
    code, _, err = render(capsys, project / "scene.usda", out, *extra)
    assert_one_line_error(code, err, str(out / "main"))
    assert intact(canary)


def test_a_symlinked_frame_or_view_folder_is_refused(capsys, tmp_path, project, fake_render, canary):
    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    view = frame_dir(out, "main", 1) / "00_00"
    os.rename(view, tmp_path / "moved")
    view.symlink_to(canary)
    code, _, err = render(capsys, project / "scene.usda", out)
    assert_one_line_error(code, err, str(view), "symbolic link")
    assert intact(canary)


# -- 2. metadata is validated before it is used; --overwrite removes exactly lfusd's files ------


@pytest.mark.parametrize("rig", ["../home", "ABSOLUTE", "main/../../home", "..", ""])
def test_a_manifest_naming_a_folder_outside_as_a_rig_is_refused_before_any_file_operation(capsys, monkeypatch, tmp_path, project, fake_render,
                                                                                         canary, rig):
    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    rig = str(canary) if rig == "ABSOLUTE" else rig

    def craft(m):
        m["rigs"].append(rig)
        m["settings"]["rigs"][rig] = dict(m["settings"]["rigs"]["main"], name=rig)
        m["frames"].append(1)

    edit_manifest(out, craft)
    before = snap(out)
    for extra in ((), ("--samples", "2", "--overwrite")):
        code, _, err = render(capsys, project / "scene.usda", out, *extra)
        assert_one_line_error(code, err, "manifest.json", "rig name")
        assert code == 2 and intact(canary) and snap(out) == before
    monkeypatch.undo()  # the real derivation for 'lfusd derive'
    for argv in (("verify", out, "--integrity"), ("derive", out), ("export", "pfm", out, tmp_path / "exp")):
        code, _, err = run_cli(capsys, *argv)
        assert_one_line_error(code, err, "manifest.json", "rig name")
    with pytest.raises(LfusdError, match="rig name"):
        Dataset(out, rig="main")
    assert intact(canary)


def test_overwrite_of_a_manifest_listing_a_users_folder_as_a_rig_leaves_that_folder(capsys, tmp_path, project, fake_render):
    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    docs = out / "Documents"  # the user keeps a folder next to the dataset; the manifest claims it
    (docs / "f000001").mkdir(parents=True)
    (docs / "thesis.tex").write_text("chapter 1")
    (docs / "f000001" / "draft.txt").write_text("draft")

    def craft(m):
        m["rigs"].append("Documents")
        m["settings"]["rigs"]["Documents"] = dict(m["settings"]["rigs"]["main"], name="Documents")

    edit_manifest(out, craft)
    before = snapshot(docs)
    assert render(capsys, project / "scene.usda", out, "--samples", "2", "--overwrite")[0] == 0
    assert snapshot(docs) == before


def test_overwrite_deletes_exactly_lfusds_files_not_a_users_files_inside_its_folders(capsys, tmp_path, project, fake_render):
    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    assert render(capsys, project / "scene.usda", out, "--frame", "2")[0] == 0
    view = frame_dir(out, "main", 1) / "00_00"
    mine = {out / "main" / "README.txt": "about this rig", frame_dir(out, "main", 2) / "notes.md": "frame 2 looks odd",
            view / "labels_extra.png": "my own label image", out / "logs" / "my-notes.txt": "run on the cluster"}
    for p, text in mine.items():
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    # the dataset from before, to be replaced: its own files carry this run's bytes
    assert (view / "rgb.exr").read_bytes() == b"fake"
    (view / "rgb.exr").write_bytes(b"old render")
    (view / "passes.exr").write_bytes(b"old passes")
    assert render(capsys, project / "scene.usda", out, "--samples", "2", "--overwrite")[0] == 0
    assert {p: p.read_text() for p in mine} == mine
    assert (view / "rgb.exr").read_bytes() == b"fake"  # lfusd's own file was removed and rendered again
    assert json.loads((out / "manifest.json").read_text())["settings"]["samples"] == 2


def test_overwrite_removes_all_of_lfusds_files_and_folders(tmp_path, project, fake_render, capsys):
    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    assert render(capsys, project / "scene.usda", out, "--frame", "2")[0] == 0
    (out / "logs").mkdir(exist_ok=True)
    (out / "logs" / "main-unit0000.log").write_text("blender said")
    (frame_dir(out, "main", 1) / ".frame.json.abc123de.tmp").write_text("killed mid-write")
    from lfusd.data.folder import read_manifest

    confined.remove_own(out, read_manifest(out))
    assert sorted(p.name for p in out.iterdir()) == [".lock"]


@pytest.mark.parametrize("field,value,named", [
    ("frames", [1, 10**12], "frame"),
    ("frames", list(range(1_000_001)), "frame numbers"),
    ("frames", ["../x"], "frame"),
    ("grid", 10**6, "rows"),
    ("width", 10**9, "width"),
])
def test_absurd_manifest_fields_are_refused_in_one_line(capsys, tmp_path, project, fake_render, field, value, named):
    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0

    def craft(m):
        if field == "frames":
            m["frames"] = value
        elif field == "grid":
            m["settings"]["rigs"]["main"]["rows"] = value
        else:
            m["settings"]["rigs"]["main"]["width"] = value

    edit_manifest(out, craft)
    code, _, err = run_cli(capsys, "verify", out, "--integrity")
    assert_one_line_error(code, err, "manifest.json", named)
    with pytest.raises(LfusdError, match=named):
        Dataset(out)


@pytest.mark.parametrize("craft,named", [
    (lambda m: m["settings"].__setitem__("keys", ["rgb", "bogus"]), "'settings.keys' names 'bogus'"),
    (lambda m: m["stage"].__setitem__("path", ["x"]), "'stage.path' is not a string"),
    (lambda m: m["stage"].__setitem__("path", 5), "'stage.path' is not a string"),
    (lambda m: m["stage"].__setitem__("files", ["scene.usda"]), "'stage.files'"),
])
def test_crafted_manifest_records_are_one_line_not_exit_3(capsys, tmp_path, project, fake_render, craft, named):
    """Issue 39 item 6: a key list naming a key lfusd does not know (export webdataset, derive) and
    a stage record of the wrong type (verify) are refused in one line, exit 2, by every reader."""
    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    edit_manifest(out, craft)
    for argv in (("verify", out), ("export", "webdataset", out, tmp_path / "exp"), ("verify", out, "--integrity")):
        code, _, err = run_cli(capsys, *argv)
        assert code == 2, (argv, err)
        assert_one_line_error(code, err, "manifest.json", named)
    with pytest.raises(LfusdError, match=named):
        Dataset(out)
    assert not (tmp_path / "exp").exists()


@pytest.mark.parametrize("craft,named", [
    (lambda t: t["objects"].append({"id": 10**12, "prim_path": "/X", "label": "x", "class_id": 0}), "object id"),
    (lambda t: t["objects"].append({"id": 5, "prim_path": "/X", "label": "x", "class_id": 99}), "class id"),
])
def test_a_crafted_object_table_is_refused_in_one_line(tmp_path, project, fake_render, capsys, craft, named):
    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    table = json.loads((out / "objects.json").read_text())
    craft(table)
    (out / "objects.json").write_text(json.dumps(table))
    with pytest.raises(LfusdError, match=f"objects.json.*{named}"):
        Dataset(out)


def test_a_crafted_frame_record_is_refused_in_one_line(tmp_path, project, fake_render, capsys):
    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    path = frame_dir(out, "main", 1) / "frame.json"
    meta = json.loads(path.read_text())
    meta["cam_to_world"]["../../x"] = meta["cam_to_world"]["00_00"]
    path.write_text(json.dumps(meta))
    with pytest.raises(LfusdError, match="frame.json.*view '../../x'"):
        Dataset(out).cam_to_world(1, (0, 0))


# -- 5. identity that edits cannot fool; nothing outside the stage's folder but its images and layers


def _edit_keeping_size_and_mtime(path: Path, how: str) -> None:
    """Change one byte of ``path`` and give it back its size and mtime, as ``touch -r`` (in place)
    or ``cp -p`` / ``rsync -a`` / ``tar x`` (a new file over it) leave it."""
    st = os.stat(path)
    data = bytearray(path.read_bytes())
    if path.suffix == ".usda":
        data = data.replace(b"extra = 1", b"extra = 2")  # still a layer, one digit different
    else:
        data[len(data) // 2] ^= 0x01
    if how == "in place":
        path.write_bytes(bytes(data))
    else:
        tmp = path.with_name(path.name + ".new")
        tmp.write_bytes(bytes(data))
        os.replace(tmp, path)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert os.stat(path).st_size == st.st_size and os.stat(path).st_mtime_ns == st.st_mtime_ns


@pytest.mark.parametrize("how", ["in place", "replaced"])
@pytest.mark.parametrize("name", ["textures/paint.png", "sub.usda"])
def test_an_edit_that_keeps_size_and_mtime_is_refused(capsys, tmp_path, project, fake_render, name, how):
    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    if name == "sub.usda":  # a layer with room for a same-size edit
        (project / name).write_text('#usda 1.0\n\nover "World"\n{\n    custom double extra = 1\n}\n')
        assert render(capsys, project / "scene.usda", tmp_path / "out2")[0] == 0
        out = tmp_path / "out2"
    _edit_keeping_size_and_mtime(project / name, how)
    before = snap(out)
    code, _, err = render(capsys, project / "scene.usda", out, "--frame", "2")
    assert_one_line_error(code, err, "holds a different dataset", f"stage file {name}", "changed")
    assert snap(out) == before


def test_only_images_and_layers_outside_the_stages_folder_are_read_into_the_identity(capsys, tmp_path, project, fake_render):
    from pxr import Sdf, Usd, UsdShade

    from lfusd.data.formats import write_png

    secret = tmp_path / "secret" / "credentials.txt"
    secret.parent.mkdir()
    secret.write_text("password=hunter2\n")
    shared = tmp_path / "library" / "wood.png"
    shared.parent.mkdir()
    write_png(shared, np.full((4, 4, 3), 90, np.uint8))
    stage = Usd.Stage.Open(str(project / "scene.usda"))
    for name, path in (("Secret", "../secret/credentials.txt"), ("Wood", "../library/wood.png")):
        tex = UsdShade.Shader.Define(stage, f"/World/Looks/Paint/{name}")
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(path)
    stage.GetRootLayer().Save()
    out = tmp_path / "out"
    code, _, err = render(capsys, project / "scene.usda", out)
    assert code == 0
    text = (out / "manifest.json").read_text()
    files = json.loads(text)["stage"]["files"]
    assert "credentials" not in text  # neither its path nor its size nor its hash
    assert files[shared.as_posix()]["size"] == shared.stat().st_size  # an image the stage uses: recorded by path and hash
    assert [ln for ln in err.splitlines() if "credentials.txt" in ln and "not read" in ln], err


# -- 6. verify checks every view's file records first; every writer takes the lock ---------------


@pytest.mark.render
def test_verify_fails_a_dataset_with_a_truncated_rgb_exr(capsys, tmp_path, box_dataset):
    import shutil

    _, rendered = box_dataset
    out = tmp_path / "out"
    shutil.copytree(rendered, out)  # the session's dataset stays whole
    rig = json.loads((out / "manifest.json").read_text())["rigs"][0]
    rgb = frame_dir(out, rig, 1) / "00_01" / "rgb.exr"
    rgb.write_bytes(rgb.read_bytes()[: rgb.stat().st_size // 2])
    code, stdout, _ = run_cli(capsys, "verify", out, "--rig", rig)
    assert code == 1
    fails = [ln for ln in stdout.splitlines() if ln.startswith("FAIL")]
    assert any("rgb.exr" in ln and "view 0,1" in ln for ln in fails), stdout
    # the geometry of the other views was still compared, and passes
    assert "rgb.exr" not in " ".join(ln for ln in fails if "view 0,1" not in ln)


def test_lfusd_flow_takes_the_lock(capsys, monkeypatch, tmp_path, project, fake_render):
    import signal
    import subprocess
    import sys

    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    monkeypatch.undo()  # the real derivation
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from pathlib import Path; from lfusd.data.folder import output_lock\n"
         "with output_lock(Path(sys.argv[1])):\n    print('held', flush=True); time.sleep(60)", str(out)],
        stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    try:
        assert holder.stdout.readline().strip() == "held"
        before = snap(out)
        code, _, err = run_cli(capsys, "derive", out)
        assert_one_line_error(code, err, "is being written by process", str(holder.pid))
        assert snap(out) == before
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()


def test_lfusd_flow_refuses_a_linked_view_folder(capsys, monkeypatch, tmp_path, project, fake_render, canary):
    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    monkeypatch.undo()
    view = frame_dir(out, "main", 1) / "00_00"
    os.rename(view, tmp_path / "moved")
    view.symlink_to(canary)
    code, _, err = run_cli(capsys, "derive", out)
    assert_one_line_error(code, err, str(view), "symbolic link")
    assert intact(canary)


# -- 7. limits up front: generated stages appear only whole ---------------------------------------


def test_a_killed_stage_generation_leaves_no_stage_and_the_rerun_makes_it(tmp_path):
    import signal
    import subprocess
    import sys
    import time

    stage = tmp_path / "stages" / "room.usda"
    argv = [sys.executable, "-m", "lfusd", "stage", "new", "room", "-o", stage, "--frames", "1", "--rigs", "1",
            "--grid", "1x1", "--resolution", "16x16"]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    p = subprocess.Popen(list(map(str, argv)), env=env, stderr=subprocess.PIPE)
    deadline = time.time() + 120
    while time.time() < deadline and not any(x.name.endswith(".tmp.usda") for x in stage.parent.glob(".*")):
        time.sleep(0.02)  # the generation has begun writing
    p.send_signal(signal.SIGKILL)
    p.wait()
    assert not stage.exists()  # nothing half-written where the stage goes (dataset make would take it for the scene)
    assert [x.name for x in stage.parent.glob(".room.*.tmp.usda")]  # the killed run's temporary
    (stage.parent / ".room.notmine.tmp.usda").write_text("a user's file, not lfusd's temporary name")
    assert subprocess.run(list(map(str, argv)), env=env, capture_output=True).returncode == 0
    from pxr import Usd

    assert Usd.Stage.Open(str(stage)).GetPrimAtPath("/World")
    assert sorted(x.name for x in stage.parent.glob(".*")) == [".room.notmine.tmp.usda"]


def test_a_rerun_removes_exactly_the_temporaries_of_dead_generations_of_that_stage(tmp_path):
    """USD saves lfusd's temporary through one of its own (``<temporary without suffix>.<6 random>``,
    renamed over it when whole): a generation killed inside that save leaves USD's file, which
    names the dead process and lfusd's random part, so it is provably lfusd's. Files that only
    look alike stay: another pid's (alive), another stage's, a user's name, a link."""
    import subprocess
    import sys

    from lfusd.author.scenes import generate

    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    alive = os.getpid()
    folder = tmp_path / "stages"
    folder.mkdir()
    ours = [f".room.{dead.pid}-y9mk0khd.tmp.usda", f".room.{dead.pid}-y9mk0khd.tmp.fDK981"]
    kept = [f".room.{alive}-y9mk0khd.tmp.usda", f".room.{alive}-y9mk0khd.tmp.fDK981",  # a generation still running
            f".hall.{dead.pid}-y9mk0khd.tmp.fDK981",  # another stage's
            ".room.notmine.tmp.fDK981", f".room.{dead.pid}-y9mk0khd.tmp.fDK98", f".room.{dead.pid}-y9mk0khd.tmp.fDK981x",
            f"room.{dead.pid}-y9mk0khd.tmp.fDK981"]
    for name in ours + kept:
        (folder / name).write_text("x")
    (folder / "target").write_text("a user's file")
    (folder / f".room.{dead.pid}-abcdefgh.tmp.Qw3rTy").symlink_to(folder / "target")
    kept.append(f".room.{dead.pid}-abcdefgh.tmp.Qw3rTy")
    generate("room", folder / "room.usda", 0, frames=1, rigs=1, grid=(1, 1), resolution=(16, 16))
    names = {x.name for x in folder.iterdir()}
    assert not names & set(ours)
    assert set(kept) <= names
    assert (folder / "target").read_text() == "a user's file"


def test_an_absurd_frame_range_is_refused_before_any_list_is_made(capsys, tmp_path, project, fake_render):
    code, _, err = run_cli(capsys, "render-video", project / "scene.usda", "-o", tmp_path / "out", "--frames", "1-100000000",
                           "--device", "cpu", "--quiet")
    assert_one_line_error(code, err, "100000000 frames", "smaller range")
    assert not (tmp_path / "out").exists()


def test_a_stage_range_of_a_billion_frames_is_refused_in_one_line(capsys, tmp_path, project, fake_render):
    from pxr import Usd

    stage = Usd.Stage.Open(str(project / "scene.usda"))
    stage.SetEndTimeCode(1e9)
    stage.GetRootLayer().Save()
    code, _, err = run_cli(capsys, "render-video", project / "scene.usda", "-o", tmp_path / "out", "--device", "cpu", "--quiet")
    assert_one_line_error(code, err, "1000000000 frames", "--frames")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("field,value,named", [("frames", 10**9, "frames"), ("scenes", 10**8, "scenes"), ("disk", None, "of disk")])
def test_absurd_recipes_are_refused_before_anything_is_made(capsys, monkeypatch, tmp_path, field, value, named):
    from lfusd.render import request

    recipe = tmp_path / "r.toml"
    text = (Path(__file__).resolve().parents[1] / "recipes" / "tiny.toml").read_text()
    if field == "disk":  # the tiny recipe on a disk with 1 kB free
        monkeypatch.setattr(request, "_free_disk", lambda path: 1000)
    else:
        lines = text.splitlines()
        last = max(i for i, ln in enumerate(lines) if ln.startswith("[[part]]"))  # the dynamic part
        body = [ln for ln in lines[last:] if not ln.startswith(f"{field} ")]
        text = "\n".join(lines[:last] + body + [f"{field} = {value}"]) + "\n"
    recipe.write_text(text)
    code, _, err = run_cli(capsys, "dataset", "make", recipe, "-o", tmp_path / "made", "--quiet")
    assert_one_line_error(code, err, named)
    assert not (tmp_path / "made").exists()


def test_the_memory_check_honours_a_container_limit(tmp_path, capsys, project):
    from lfusd.render import request

    # cgroup v2: the process's group and its parent, the lower limit wins; v1: memory.limit_in_bytes
    (tmp_path / "proc").write_text("0::/user.slice/job\n")
    (tmp_path / "fs" / "user.slice" / "job").mkdir(parents=True)
    (tmp_path / "fs" / "user.slice" / "job" / "memory.max").write_text("max\n")
    (tmp_path / "fs" / "user.slice" / "memory.max").write_text(f"{3 << 30}\n")
    assert request.cgroup_memory_limit(str(tmp_path / "proc"), str(tmp_path / "fs")) == 3 << 30
    (tmp_path / "proc1").write_text("4:memory:/docker/abc\n1:cpu:/\n")
    (tmp_path / "fs1" / "memory" / "docker" / "abc").mkdir(parents=True)
    (tmp_path / "fs1" / "memory" / "docker" / "abc" / "memory.limit_in_bytes").write_text(f"{1 << 30}\n")
    (tmp_path / "fs1" / "memory" / "memory.limit_in_bytes").write_text("9223372036854771712\n")
    assert request.cgroup_memory_limit(str(tmp_path / "proc1"), str(tmp_path / "fs1")) == 1 << 30
    # a render whose views fit the machine but not the container is refused, naming the limit
    monkeypatch = pytest.MonkeyPatch()
    monkeypatch.setattr(request, "cgroup_memory_limit", lambda *a, **k: 256 << 20)
    try:
        assert request.memory_available() == 256 << 20
        code, _, err = run_cli(capsys, "render-video", project / "scene.usda", "-o", tmp_path / "out", "--resolution", "2048x2048",
                               "--device", "cpu", "--quiet")
    finally:
        monkeypatch.undo()
    assert_one_line_error(code, err, "of memory", "this machine has 0.268 GB")
    assert not (tmp_path / "out").exists()


@pytest.mark.render
def test_a_full_disk_during_export_lfmat_is_one_line_and_leaves_nothing(tmp_path, box_dataset):
    """The file size limit (RLIMIT_FSIZE) makes write(2) fail as a full disk does (EFBIG for ENOSPC):
    HDF5 failing inside its own writes crashed the process (SIGSEGV)."""
    import resource
    import subprocess
    import sys

    _, out = box_dataset
    dest = tmp_path / "exp"
    limit = 64 * 1024  # far below one light field of the 3x3 rig, above everything else the command writes

    def small_files():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path), "PYTHONDONTWRITEBYTECODE": "1"}
    r = subprocess.run([sys.executable, "-m", "lfusd", "export", "lfmat", str(out), str(dest), "--rig", "main"],
                       capture_output=True, text=True, env=env, preexec_fn=small_files, timeout=300)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1 and lines[0].startswith("lfusd: error: cannot write export"), r.stderr[-2000:]
    assert "File too large" in lines[0]
    assert not dest.exists() and not list(tmp_path.glob(".exp.partial-*"))


def test_a_killed_exports_partial_folder_is_removed_by_the_rerun(tmp_path):
    from lfusd.data.folder import remove_stale_partials

    dest = tmp_path / "exp"
    dead = tmp_path / ".exp.partial-999999999-k2j3h4x9"  # lfusd's name, of no running process
    (dead / "sub").mkdir(parents=True)
    (dead / "sub" / "scene_f0001.h5").write_bytes(b"half")
    alive = tmp_path / f".exp.partial-{os.getpid()}-a1b2c3d4"  # a running export's
    alive.mkdir()
    other = tmp_path / ".exp.partial-notes"
    other.mkdir()
    remove_stale_partials(dest)
    assert not dead.exists() and alive.is_dir() and other.is_dir()


def test_export_keeps_a_partial_named_folder_it_cannot_prove_it_made(tmp_path):
    """Issue 39 item 8: a folder named like a partial export of a dead process, but without
    lfusd's random part (someone else's), or a link of that name, is left alone."""
    from lfusd.data.folder import new_folder

    dest = tmp_path / "exp"
    users = tmp_path / ".exp.partial-999999999"  # no random part: not a name lfusd makes
    users.mkdir()
    (users / "thesis.tex").write_text("the user's")
    target = tmp_path / "elsewhere"
    target.mkdir()
    (target / "keep").write_text("the user's")
    (tmp_path / ".exp.partial-999999998-zzzzzzzz").symlink_to(target, target_is_directory=True)
    with new_folder(dest) as tmp:
        assert tmp.name.startswith(f".exp.partial-{os.getpid()}-") and len(tmp.name) == len(f".exp.partial-{os.getpid()}-") + 8
        tmp.mkdir()
    assert (users / "thesis.tex").read_text() == "the user's" and (target / "keep").read_text() == "the user's"
    assert dest.is_dir()


def test_a_rerun_removes_the_temporaries_of_a_killed_run_and_nothing_else(capsys, tmp_path, project, fake_render):
    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    frame = frame_dir(out, "main", 1)
    debris = [out / ".manifest.json.k2j3h4_x.tmp", out / ".objects.json.a1b2c3d4.tmp", frame / ".frame.json.zz9y8x7w.tmp",
              frame / "00_00" / ".gt.q1w2e3r4.exr", frame / "00_00" / ".motion.q1w2e3r4.exr", frame / "00_00" / ".view.abcdefgh.json"]
    for p in debris:
        p.write_bytes(b"half-written by a killed run")
    (frame / ".00_00.tmp-4242-1399").mkdir()
    (frame / ".00_00.tmp-4242-1399" / "rgb.exr").write_bytes(b"half")
    mine = [out / ".my_notes", frame / "00_00" / ".gt.backup", frame / ".frame.json.bak"]
    for p in mine:
        p.write_text("the user's")
    assert render(capsys, project / "scene.usda", out)[0] == 0
    assert not any(p.exists() for p in debris) and not (frame / ".00_00.tmp-4242-1399").exists()
    assert all(p.read_text() == "the user's" for p in mine)


def test_a_certificate_is_republished_only_while_bound_to_the_content(capsys, tmp_path, project, fake_render):
    """Issue 39 item 4: verify's figures are bound to the digests of what they certify and the
    verifier's version; a certificate pasted into manifest.json, or one whose files changed since,
    is not passed on by the exports (nor the card, lfusd.recipe._certificate: the same check)."""
    from types import SimpleNamespace

    from lfusd.data.certificate import certified
    from lfusd.exports.webdataset import verification_figures
    from lfusd.recipe import _certificate
    from lfusd.truth.verify import record_certificate

    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    figures = {"ok": True, "valid": 256, "unchecked": 0,
               "keys": {"depth": {"count": 256, "coverage": 1.0, "p99": 0.0, "max": 0.0, "over": 0, "ties": 0, "threshold": 0.001}}}
    record_certificate(out, {"main": SimpleNamespace(certificate=lambda: figures)})
    cert = certified(out, "main")["main"]
    assert {k: cert[k] for k in figures} == figures and cert["binding"]["verifier"].startswith("lfusd ")
    assert verification_figures(Dataset(out))["certificate"]["main"]["keys"] == figures["keys"]
    assert _certificate(out)["depth"]["count"] == 256
    manifest = json.loads((out / "manifest.json").read_text())

    # a certificate pasted into the manifest (no binding, or the binding of other content)
    for pasted in ({"main": figures}, {"main": {**figures, "binding": {"verifier": "lfusd 0.1.0", "content_sha256": "0" * 64}}}):
        (out / "manifest.json").write_text(json.dumps({**manifest, "certificate": pasted}))
        assert certified(out) == {} and verification_figures(Dataset(out)) == {} and _certificate(out) == {}
    (out / "manifest.json").write_text(json.dumps(manifest))
    assert certified(out, "main")

    # a file it covers changed (same size), its record kept, then the record made to match
    rgb = frame_dir(out, "main", 1) / "00_00" / "rgb.exr"
    rgb.write_bytes(b"FAKE")
    assert certified(out) == {} and verification_figures(Dataset(out)) == {}
    from lfusd.data import integrity

    integrity.record_files(rgb.parent, {"rgb.exr": integrity.file_entry(rgb)})
    assert certified(out) == {} and _certificate(out) == {}


def test_exports_read_no_verification_outside_the_dataset_folder(tmp_path):
    """Issue 39 item 4: a sibling <name>.json and a grandparent card.json saying "verified" are not
    the dataset's: an export republishes nothing from them."""
    from support.fake import FakeDataset

    from lfusd.exports.webdataset import verification_figures

    root = tmp_path / "recipe"
    (root / "scenes" / "street_000").mkdir(parents=True)
    (root / "scenes" / "street_000.json").write_text(json.dumps({"verified": True, "compared": 12345}))
    (root / "card.json").write_text(json.dumps({"name": "streets", "verified": True, "pixels": 999}))
    ds = FakeDataset(root=root / "scenes" / "street_000", rows=1, cols=2, width=16, height=12, frames=(1,))
    assert verification_figures(ds) == {}


@pytest.mark.parametrize("claim", ["grid", "complete frames", "listed frames"])
def test_a_manifest_claiming_far_more_than_is_on_disk_is_refused_before_work_scales(capsys, tmp_path, project, fake_render, claim):
    """Issue 39 item 5: a 1x1, one-frame dataset whose manifest claims a 512x512 grid, or a million
    frames (complete, or listed; 100,000 here, to stay fast), is refused in one line by the readers before they loop over the
    claim (verify ran for minutes), in well under the time one pass over the claim takes."""
    import time

    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0

    def craft(m):
        if claim == "grid":
            m["settings"]["rigs"]["main"].update(rows=512, cols=512)
        else:
            m["frames"] = list(range(1, 100_001))
            if claim == "complete frames":
                m["complete"]["main"] = m["frames"]

    edit_manifest(out, craft)
    t0 = time.monotonic()
    for argv in (("verify", out), ("verify", out, "--integrity")):
        code, _, err = run_cli(capsys, *argv)
        assert code == 2, (argv, err)
        assert_one_line_error(code, err, "manifest.json", "views of rig 'main'", "on disk")
    if claim != "listed frames":  # a render still running lists frames not yet on disk: a reader opens it
        with pytest.raises(LfusdError, match="records as complete"):
            Dataset(out)
    assert time.monotonic() - t0 < 30


def test_a_manifest_claiming_another_image_size_is_refused_when_its_pixels_are_read(capsys, tmp_path, project, fake_render, monkeypatch):
    """Issue 39 item 5: a manifest claiming 65536x65536 for 16x16 images gives every export the
    claimed intrinsics; a read compares the array with the claim and refuses the mismatch."""
    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    monkeypatch.setattr(Dataset, "_read", lambda self, frame, view, key: np.zeros((16, 16), np.float32))  # the fake files hold no image
    assert Dataset(out).read(1, (0, 0), "depth").shape == (16, 16)
    edit_manifest(out, lambda m: m["settings"]["rigs"]["main"].update(width=65536, height=65536))
    with pytest.raises(LfusdError, match="holds depth of 16x16 px, but .*manifest.json says rig 'main' is 65536x65536"):
        Dataset(out).read(1, (0, 0), "depth")


@pytest.mark.render
def test_an_export_of_a_rendered_dataset_claiming_another_size_is_one_line(capsys, tmp_path, box_dataset):
    """Issue 39 item 5, rendered: `export pfm` of a dataset whose manifest claims 65536x65536 exits 2
    in one line (it wrote the claimed intrinsics, exit 0) and leaves no export."""
    import shutil

    _, rendered = box_dataset
    out = tmp_path / "out"
    shutil.copytree(rendered, out)
    rig = json.loads((out / "manifest.json").read_text())["rigs"][0]
    edit_manifest(out, lambda m: m["settings"]["rigs"][rig].update(width=65536, height=65536))
    code, _, err = run_cli(capsys, "export", "pfm", out, tmp_path / "exp", "--rig", rig)
    assert_one_line_error(code, err, "says rig", "65536x65536")
    assert code == 2 and not (tmp_path / "exp").exists()
