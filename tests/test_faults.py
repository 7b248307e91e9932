"""Data safety (issue 13, ownership / identity / lock / error contract): lfusd deletes only what it
can prove it wrote, resumes only the very scene it rendered, lets one run write a folder, and
answers every failure with one line and exit 2.

Most cases refuse before any rendering; the ones that need a dataset use ``fake_render``, which
stands in for the Blender workers (it creates the view folders a worker would), so the checks run
in seconds. ``test_resume_after_a_texture_repaint_is_refused_rendered`` is the same case with Blender.
"""

from __future__ import annotations

import errno
import json
import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from pxr import Sdf, UsdShade
from support.cli import assert_one_line_error, run_cli
from support.scenes import write_box_stage

from lfusd.camera import RigSpec
from lfusd.layout import frame_dir

RIG = RigSpec(name="main", rows=1, cols=1, width=16, height=16, at=(0, -5, 1), look_at=(0, 0, 0.5))


def snapshot(folder: Path) -> dict[str, bytes | None]:
    """Every entry under ``folder`` with its bytes (None for folders)."""
    return {str(p.relative_to(folder)): (None if p.is_dir() else p.read_bytes()) for p in sorted(folder.rglob("*"))}


@pytest.fixture
def project(tmp_path):
    """A project folder: a stage (frames 1-4, one 1x1 rig of 16x16 px) with a sublayer and a
    texture, and the user's notes."""
    from lfusd.data.formats import write_png

    root = tmp_path / "project"
    (root / "textures").mkdir(parents=True)
    write_png(root / "textures" / "paint.png", np.full((4, 4, 3), 200, np.uint8))
    sub = Sdf.Layer.CreateNew(str(root / "sub.usda"))
    sub.Save()
    stage_path = root / "scene.usda"
    write_box_stage(stage_path, [RIG])
    from lfusd.author.stage import open_stage

    stage = open_stage(stage_path)
    stage.SetEndTimeCode(4)
    stage.GetRootLayer().subLayerPaths.append("sub.usda")
    mat = UsdShade.Material.Define(stage, "/World/Looks/Paint")
    tex = UsdShade.Shader.Define(stage, "/World/Looks/Paint/Tex")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("./textures/paint.png")
    surf = UsdShade.Shader.Define(stage, "/World/Looks/Paint/Surface")
    surf.CreateIdAttr("UsdPreviewSurface")
    surf.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
    mat.CreateSurfaceOutput().ConnectToSource(surf.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(stage.GetPrimAtPath("/World/Ground")).Bind(mat)
    stage.GetRootLayer().Save()
    (root / "notes.txt").write_text("my notes")
    return root


@pytest.fixture
def fake_render(monkeypatch):
    """Blender workers stood in for: each unit's view folders appear with their completion
    record, as a worker's would (the files hold no image)."""
    from lfusd.data import integrity
    from lfusd.render import executors

    def run_units(units, req, report):
        for u in units:
            for f in u.frames:
                for key in u.cameras:
                    d = frame_dir(req.out, u.rig, f) / key
                    d.mkdir(parents=True, exist_ok=True)
                    for name in integrity.RENDER_FILES:
                        (d / name).write_bytes(b"fake")
                    integrity.record_render(d)
        return "cpu"

    monkeypatch.setattr(executors, "run_units", run_units)


def render(capsys, stage, out, *extra):
    return run_cli(capsys, "render", stage, "-o", out, "--samples", "1", "--device", "cpu", "--quiet", *extra)


# -- case 1: ownership ------------------------------------------------------------------------


def test_a_folder_with_an_unrelated_manifest_is_refused_even_with_overwrite(capsys, project):
    (project / "manifest.json").write_text(json.dumps({"name": "app"}))
    (project / "src").mkdir()
    (project / "src" / "main.py").write_text("print('app')")
    before = snapshot(project)
    code, _, err = run_cli(capsys, "render-video", project / "scene.usda", "-o", project, "--device", "cpu", "--quiet")
    assert_one_line_error(code, err, "not an lfusd dataset")
    assert "pass --overwrite" not in err  # it is not safe, so it is not suggested
    code, _, err = run_cli(capsys, "render-video", project / "scene.usda", "-o", project, "--device", "cpu", "--quiet", "--overwrite")
    assert_one_line_error(code, err, "not an lfusd dataset")
    assert code == 2 and snapshot(project) == before


def test_overwrite_removes_only_lfusds_own_files(capsys, tmp_path, project, fake_render):
    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    (out / "README.txt").write_text("the user's own file")
    (out / "results").mkdir()
    (out / "results" / "table.csv").write_text("a,b")
    code, _, err = render(capsys, project / "scene.usda", out, "--samples", "2")
    assert_one_line_error(code, err, "holds a different dataset", "samples", "--overwrite")
    assert render(capsys, project / "scene.usda", out, "--samples", "2", "--overwrite")[0] == 0
    assert (out / "README.txt").read_text() == "the user's own file" and (out / "results" / "table.csv").read_text() == "a,b"
    assert json.loads((out / "manifest.json").read_text())["settings"]["samples"] == 2


def test_overwrite_is_refused_for_the_current_folder_a_stages_folder_and_a_symlink(capsys, monkeypatch, tmp_path, project, fake_render):
    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    # The dataset folder now also holds a stage (copied in): neither --overwrite nor -o . may remove it.
    (out / "scene.usda").write_bytes((project / "scene.usda").read_bytes())
    (out / "sub.usda").write_bytes((project / "sub.usda").read_bytes())
    before = snapshot(out)
    code, _, err = render(capsys, out / "scene.usda", out, "--overwrite")
    assert_one_line_error(code, err, "--overwrite is refused here", "holds the stage")
    monkeypatch.chdir(out)
    code, _, err = render(capsys, project / "scene.usda", ".", "--samples", "2", "--overwrite")
    assert_one_line_error(code, err, "--overwrite is refused here", "current folder")
    monkeypatch.chdir(tmp_path)
    link = tmp_path / "link"
    link.symlink_to(out)
    code, _, err = render(capsys, project / "scene.usda", link, "--samples", "2", "--overwrite")
    assert_one_line_error(code, err, "--overwrite is refused here", "symbolic link")
    assert snapshot(out) == before


# -- case 3: the dataset id covers every file the pixels depend on -------------------------------


@pytest.mark.parametrize("edit,named", [
    (lambda root: (root / "textures" / "paint.png").write_bytes((root / "textures" / "paint.png").read_bytes() + b"\0"), "textures/paint.png"),
    (lambda root: (root / "sub.usda").write_text('#usda 1.0\n\nover "World"\n{\n    custom double extra = 1\n}\n'), "sub.usda"),
])
def test_resume_after_a_dependency_changed_is_refused_naming_the_file(capsys, tmp_path, project, fake_render, edit, named):
    out = tmp_path / "out"
    from lfusd.render.job import RenderRequest, render as render_frames

    render_frames(RenderRequest(stage=project / "scene.usda", out=out, frames=[1, 2], device="cpu", quiet=True))
    assert json.loads((out / "manifest.json").read_text())["frames"] == [1, 2]
    edit(project)
    before = snapshot(out)
    code, _, err = run_cli(capsys, "render-video", project / "scene.usda", "-o", out, "--frames", "1-4", "--device", "cpu", "--quiet")
    assert_one_line_error(code, err, "holds a different dataset", f"stage file {named}", "changed")
    assert snapshot(out) == before


def test_an_unchanged_stage_resumes_and_reuses_the_recorded_hashes(capsys, monkeypatch, tmp_path, project, fake_render):
    from lfusd.author import stage as stage_mod

    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    files = json.loads((out / "manifest.json").read_text())["stage"]["files"]
    assert {"scene.usda", "sub.usda", "textures/paint.png"} <= set(files)
    hashed = []
    real = stage_mod.file_hash
    monkeypatch.setattr(stage_mod, "file_hash", lambda p: hashed.append(Path(p).name) or real(p))
    assert render(capsys, project / "scene.usda", out)[0] == 0
    assert hashed == []  # same size and mtime: the manifest's hashes are reused
    os.utime(project / "textures" / "paint.png", ns=(1, 1))  # touched, same bytes: hashed again, same id, resumes
    assert render(capsys, project / "scene.usda", out)[0] == 0 and hashed == ["paint.png"]


@pytest.mark.render
def test_resume_after_a_texture_repaint_is_refused_rendered(capsys, tmp_path, project):
    from lfusd.data.formats import write_png

    out = tmp_path / "out"
    args = ("--device", "cpu", "--samples", "1", "--quiet")
    assert run_cli(capsys, "render-video", project / "scene.usda", "-o", out, "--frames", "1-2", *args)[0] == 0
    write_png(project / "textures" / "paint.png", np.full((4, 4, 3), 20, np.uint8))
    before = snapshot(out)
    code, _, err = run_cli(capsys, "render-video", project / "scene.usda", "-o", out, "--frames", "1-4", *args)
    assert_one_line_error(code, err, "stage file textures/paint.png")
    assert snapshot(out) == before and not frame_dir(out, "main", 3).exists()


# -- case 6: one writer per folder -----------------------------------------------------------------


def test_a_second_run_is_refused_naming_the_first_and_a_dead_runs_lock_is_taken(capsys, tmp_path, project, fake_render):
    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    (out / ".scratch").mkdir()
    (out / ".scratch" / "work.exr").write_bytes(b"the first run's scratch file")
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from pathlib import Path; from lfusd.render.job import output_lock\n"
         "with output_lock(Path(sys.argv[1])):\n    print('held', flush=True); time.sleep(60)", str(out)],
        stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        for extra in ((), ("--samples", "2", "--overwrite")):
            code, _, err = render(capsys, project / "scene.usda", out, *extra)
            assert_one_line_error(code, err, "is being written by process", str(holder.pid))
            assert (out / ".scratch" / "work.exr").read_bytes() == b"the first run's scratch file"
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    # The holder died without cleaning up: its lock file stays, its lock is gone.
    assert (out / ".lock").read_text().startswith(str(holder.pid))
    assert render(capsys, project / "scene.usda", out)[0] == 0
    assert not (out / ".scratch").exists()


# -- case 8: one error contract ---------------------------------------------------------------------


def test_unwritable_output_and_full_disk_are_one_line_with_exit_2(capsys, monkeypatch, tmp_path, project, fake_render):
    import tempfile

    from lfusd.truth import derive

    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    code, _, err = render(capsys, project / "scene.usda", blocker / "out")
    assert_one_line_error(code, err, "cannot write to", "Not a directory")
    assert code == 2

    def read_only(*a, **k):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(tempfile, "mkstemp", read_only)
    code, _, err = render(capsys, project / "scene.usda", tmp_path / "ro")
    assert_one_line_error(code, err, "Read-only file system", "writable")
    assert code == 2
    monkeypatch.undo()

    from lfusd.render import executors

    monkeypatch.setattr(executors, "run_units", lambda units, req, report: "cpu")

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(derive, "derive_dataset", full)
    code, _, err = run_cli(capsys, "render-video", project / "scene.usda", "-o", tmp_path / "full", "--device", "cpu", "--quiet")
    assert_one_line_error(code, err, "No space left on device", "free disk space")
    assert code == 2 and "make it writable" not in err


@pytest.mark.parametrize("damage", ["manifest.json", "objects.json", "motion.npz", "frame.json"])
def test_a_corrupt_dataset_file_is_named_in_one_line(capsys, tmp_path, project, fake_render, damage):
    from lfusd import Dataset
    from lfusd.errors import LfusdError

    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    target = {"manifest.json": out / "manifest.json", "objects.json": out / "objects.json",
              "frame.json": frame_dir(out, "main", 1) / "frame.json",
              "motion.npz": frame_dir(out, "main", 1) / "00_00" / "motion.npz"}[damage]
    target.write_bytes(b"\x00garbage{")
    with pytest.raises(LfusdError, match=damage.replace(".", r"\.")):
        ds = Dataset(out)
        ds.objects  # reads frame.json
        ds.read(1, (0, 0), "flow_fwd")
    code, _, err = run_cli(capsys, "export", "pfm", out, tmp_path / "exp")
    if damage in ("manifest.json", "objects.json"):
        assert_one_line_error(code, err, damage)
    assert code in (0, 2)


def test_unwritable_export_preview_and_stage_destinations_are_one_line(capsys, tmp_path, project, fake_render):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    for argv in (["export", "lfmat", out, blocker / "exp"], ["preview", out, "-o", blocker / "prev", "--no-video"],
                 ["stage", "new", "room", "-o", blocker / "s.usda", "--frames", "2", "--rigs", "0"]):
        code, _, err = run_cli(capsys, *argv)
        assert_one_line_error(code, err, str(blocker))
        assert code == 2
    assert blocker.read_text() == "x"


@pytest.mark.parametrize("name", ["../../evil", "evil", "/World/Bad Name", "/"])
def test_add_person_refuses_a_name_that_is_not_a_prim_path(capsys, project, name):
    before = snapshot(project)
    code, _, err = run_cli(capsys, "animate", "add-person", project / "scene.usda", "--path", "0,0", "1,0", "--name", name)
    assert_one_line_error(code, err, "not an absolute prim path")
    assert code == 2 and snapshot(project) == before


# -- case 9: smaller ----------------------------------------------------------------------------------


def test_absurd_sizes_are_refused_up_front(capsys, tmp_path, project):
    t0 = time.perf_counter()
    code, _, err = run_cli(capsys, "render-video", project / "scene.usda", "-o", tmp_path / "big", "--resolution", "100000x100000", "--device", "cpu")
    assert_one_line_error(code, err, "GB of memory", "--force")
    code, _, err = run_cli(capsys, "stage", "new", "room", "-o", tmp_path / "s.usda", "--grid", "1000x1000", "--rigs", "1")
    assert_one_line_error(code, err, "1000000 views", "--force")
    code, _, err = run_cli(capsys, "rig", "add", project / "scene.usda", "--name", "huge", "--grid", "1000x1000")
    assert_one_line_error(code, err, "1000000 views", "--force")
    assert time.perf_counter() - t0 < 30 and not (tmp_path / "big").exists() and not (tmp_path / "s.usda").exists()


def test_disk_estimate_beyond_free_space_is_refused(monkeypatch, tmp_path, project):
    from lfusd.errors import LfusdError
    from lfusd.render import request
    from lfusd.render.job import RenderRequest, render

    monkeypatch.setattr(request, "_free_disk", lambda path: 1000)
    with pytest.raises(LfusdError, match=r"disk .*--force"):
        render(RenderRequest(stage=project / "scene.usda", out=tmp_path / "out", device="cpu"))
    assert not (tmp_path / "out").exists()


def test_workers_are_capped_to_the_cores(caplog):
    from lfusd.render.request import RenderRequest

    cores = len(os.sched_getaffinity(0))
    req = RenderRequest(stage=Path("s.usda"), out=Path("o"), workers=64).capped()
    assert req.workers == min(64, cores)
    assert cores >= 64 or "CPU cores" in caplog.text
    assert RenderRequest(stage=Path("s.usda"), out=Path("o"), workers=64, executor="ray").capped().workers == 64


def test_metadata_files_are_readable_by_group_and_others(capsys, tmp_path, project, fake_render):
    out = tmp_path / "out"
    old = os.umask(0o022)
    try:
        assert render(capsys, project / "scene.usda", out)[0] == 0
    finally:
        os.umask(old)
    for p in (out / "manifest.json", out / "objects.json", frame_dir(out, "main", 1) / "frame.json"):
        mode = stat.S_IMODE(p.stat().st_mode)
        assert mode & 0o044 == 0o044, (p, oct(mode))


def test_stage_new_and_add_person_do_not_overwrite_without_force(capsys, tmp_path, project):
    stage = tmp_path / "room.usda"
    stage.write_text("#usda 1.0\n")
    code, _, err = run_cli(capsys, "stage", "new", "room", "-o", stage, "--frames", "2", "--rigs", "0")
    assert_one_line_error(code, err, "already exists", "--force")
    assert stage.read_text() == "#usda 1.0\n"
    code, _, err = run_cli(capsys, "animate", "add-person", project / "scene.usda", "--path", "0,0", "1,0", "--name", "/World/BoxB")
    assert_one_line_error(code, err, "already has a prim at /World/BoxB", "--force")


def test_a_failed_export_leaves_nothing_that_blocks_the_retry(capsys, monkeypatch, tmp_path):
    from support.fake import FakeDataset

    from lfusd.data import export, formats

    ds = FakeDataset(tmp_path / "fake", rows=3, cols=3, width=16, height=12)
    dest = tmp_path / "exp"
    calls = []
    real = formats.write_pfm

    def failing(path, array):
        calls.append(path)
        if len(calls) == 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        real(path, array)

    monkeypatch.setattr(formats, "write_pfm", failing)
    from lfusd.errors import LfusdError

    with pytest.raises(LfusdError, match="No space left"):
        export.export(ds, "pfm", dest)
    assert not dest.exists() and not list(tmp_path.glob(".exp*"))
    monkeypatch.setattr(formats, "write_pfm", real)
    files = export.export(ds, "pfm", dest)
    assert files and all(p.is_file() and dest in p.parents for p in files)


def test_an_os_error_anywhere_is_one_line_with_exit_2(capsys, monkeypatch, tmp_path, project, fake_render):
    """A failure of the machine (here: a full disk while `lfusd flow` writes) is no bug: one line, exit 2."""
    from lfusd.truth import derive

    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device", str(out / "main"))

    monkeypatch.setattr(derive, "derive_dataset", full)
    code, _, err = run_cli(capsys, "flow", out)
    assert_one_line_error(code, err, "No space left on device", "free disk space")
    assert code == 2
