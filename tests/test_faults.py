"""Data safety (issue 13): lfusd deletes only what it can prove it wrote, resumes only the very
scene it rendered, lets one run write a folder, answers every failure with one line and exit 2
(first half); content, not existence, decides completeness, ranges join without a seam, verify
fails on missing files, and shutdown leaves no process behind (second half). Each test names the
issue's case it covers.

Most cases refuse before any rendering; the ones that need a dataset use ``fake_render``, which
stands in for the Blender workers (it creates the view folders a worker would), so the checks run
in seconds. ``test_resume_after_a_texture_repaint_is_refused_rendered`` is the same case with Blender.
"""

from __future__ import annotations

import errno
import json
import os
import signal
import shutil
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
from pxr import Sdf, UsdShade
from support.fake import fake_run_units
from support.cli import assert_one_line_error, run_cli
from support.processes import alive
from support.scenes import write_box_stage

from lfusd import Dataset
from lfusd.camera import RigSpec
from lfusd.data import integrity
from lfusd.errors import LfusdError
from lfusd.layout import GT_FILE, MOTION_FILE, PASSES_EXR, RGB_EXR, VIEW_RECORD, frame_dir
from lfusd.render import executors
from lfusd.render.plan import WorkUnit
from lfusd.truth import derive

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

    run_units = fake_run_units()

    monkeypatch.setattr(executors, "run_units", run_units)
    monkeypatch.setattr(derive, "derive_dataset", lambda *a, **k: 0)  # nothing to derive from files holding no image


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
        [sys.executable, "-c", "import sys, time; from pathlib import Path; from lfusd.data.folder import output_lock\n"
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


    monkeypatch.setattr(executors, "run_units", lambda units, req, report: "cpu")

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(derive, "derive_dataset", full)
    code, _, err = run_cli(capsys, "render-video", project / "scene.usda", "-o", tmp_path / "full", "--device", "cpu", "--quiet")
    assert_one_line_error(code, err, "No space left on device", "free disk space")
    assert code == 2 and "make it writable" not in err


@pytest.mark.parametrize("damage", ["manifest.json", "objects.json", "gt.exr", "frame.json"])
def test_a_corrupt_dataset_file_is_named_in_one_line(capsys, tmp_path, project, fake_render, damage):

    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0
    target = {"manifest.json": out / "manifest.json", "objects.json": out / "objects.json",
              "frame.json": frame_dir(out, "main", 1) / "frame.json",
              "gt.exr": frame_dir(out, "main", 1) / "00_00" / GT_FILE}[damage]
    target.write_bytes(b"\x00garbage{")
    with pytest.raises(LfusdError, match=damage.replace(".", r"\.")):
        ds = Dataset(out)
        ds.objects  # reads frame.json
        ds.read(1, (0, 0), "depth")
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
    from lfusd.render import request
    from lfusd.render.job import RenderRequest, render

    monkeypatch.setattr(request, "_free_disk", lambda path: 1000)
    with pytest.raises(LfusdError, match=r"disk .*--force"):
        render(RenderRequest(stage=project / "scene.usda", out=tmp_path / "out", device="cpu"))
    assert not (tmp_path / "out").exists()


def test_raw_passes_are_written_uncompressed_only_while_transient_and_the_disk_has_room(monkeypatch):
    from lfusd.render import request
    from lfusd.render.request import RAW_BYTES_PER_PIXEL, RAW_FRAMES_ON_DISK, RenderRequest, raw_codec

    rigs = [("a", 81, 1024, 1024)]
    need = 81 * 1024 * 1024 * RAW_BYTES_PER_PIXEL[True] * RAW_FRAMES_ON_DISK  # 30 GB: the reference rig
    req = RenderRequest(stage=Path("s.usda"), out=Path("o"), motion=True)
    monkeypatch.setattr(request, "_free_disk", lambda path: 4 * need)
    assert raw_codec(req, rigs) == "NONE"
    assert raw_codec(RenderRequest(stage=Path("s.usda"), out=Path("o"), motion=True, keep_raw=True), rigs) == "ZIP"  # kept files
    monkeypatch.setattr(request, "_free_disk", lambda path: 4 * need - 1)
    assert raw_codec(req, rigs) == "ZIP"
    monkeypatch.setattr(request, "_free_disk", lambda path: None)
    assert raw_codec(req, rigs) == "ZIP"


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
    for p in (out / "manifest.json", out / "objects.json", frame_dir(out, "main", 1) / "frame.json",
              frame_dir(out, "main", 1) / "00_00" / VIEW_RECORD):
        mode = stat.S_IMODE(p.stat().st_mode)
        assert mode & 0o044 == 0o044, (p, oct(mode))


def test_derived_motion_is_readable_by_group_and_others(whole):
    """motion.npz and its record are written under temporary names (0600) and then shared."""
    d = frame_dir(whole, "main", 2) / "00_00"
    for p in (d / MOTION_FILE, d / VIEW_RECORD):
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

    from lfusd import exports as export
    from lfusd.data import formats

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

    with pytest.raises(LfusdError, match="No space left"):
        export.export(ds, "pfm", dest)
    assert not dest.exists() and not list(tmp_path.glob(".exp*"))
    monkeypatch.setattr(formats, "write_pfm", real)
    files = export.export(ds, "pfm", dest)
    assert files and all(p.is_file() and dest in p.parents for p in files)


def test_an_os_error_anywhere_is_one_line_with_exit_2(capsys, monkeypatch, tmp_path, project, fake_render):
    """A failure of the machine (here: a full disk while `lfusd derive` writes) is no bug: one line, exit 2."""
    from lfusd.truth import derive

    out = tmp_path / "out"
    assert render(capsys, project / "scene.usda", out)[0] == 0

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device", str(out / "main"))

    monkeypatch.setattr(derive, "derive_dataset", full)
    code, _, err = run_cli(capsys, "derive", out)
    assert_one_line_error(code, err, "No space left on device", "free disk space")
    assert code == 2


# == content, ranges, shutdown (cases 2, 4, 5, 7) ==================================================

ROOT = Path(__file__).resolve().parents[1]
W, H = 128, 96  # verify needs this much: at 64x48 silhouettes make 1-2 % of occlusion pixels disagree


# -- a worker's output is checked before commit (case 2: full disk) -----------------------------


def _write_exr(path: Path, channels: dict[str, np.ndarray]) -> None:
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, channels).write(str(path))


def _worker_files(scratch: Path, key: str, w: int = W, h: int = H) -> None:
    """What a Blender worker writes for one view: rgb_<key>.exr and passes_<key>.exr (multilayer names)."""
    scratch.mkdir(parents=True, exist_ok=True)
    _write_exr(scratch / f"rgb_{key}.exr", {"RGB": np.full((h, w, 3), 0.5, np.float32)})
    ch = {"ViewLayer.Depth.Z": np.full((h, w), 3.0, np.float32), "ViewLayer.Object Index.X": np.ones((h, w), np.float32)}
    for name, comps in (("Normal", "XYZ"), ("Position", "XYZ"), ("Vector", "XYZW")):
        ch.update({f"ViewLayer.{name}.{c}": np.zeros((h, w), np.float32) for c in comps})
    _write_exr(scratch / f"passes_{key}.exr", ch)


def _unit() -> WorkUnit:
    return WorkUnit(unit=0, rig="main", stage="/s.usda", cameras={"00_00": "/Rigs/main/cam_00_00"}, frames=[1], width=W, height=H,
                    samples=1, device="cpu", instances={}, threads=1, motion=False, has_dome=False, stage_range=[1, 1])


@pytest.mark.parametrize("damage", ["empty", "cut", "size"])
def test_damaged_worker_output_is_refused_not_committed(tmp_path, damage):
    """On a full disk Blender wrote 0-byte and cut-off EXRs and reported success: they must not become a view."""
    scratch = tmp_path / "scratch"
    _worker_files(scratch, "00_00", *((W + 2, H) if damage == "size" else (W, H)))
    p = scratch / "passes_00_00.exr"
    if damage == "empty":
        p.write_bytes(b"")
    elif damage == "cut":
        p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])
    with pytest.raises(LfusdError) as e:
        executors.commit_view(tmp_path, "main", 1, "00_00", scratch, _unit())
    assert "_00_00.exr" in str(e.value) and "rerun" in str(e.value) and "\n" not in str(e.value)
    assert not (frame_dir(tmp_path, "main", 1) / "00_00").exists()


def test_committed_view_carries_a_record_that_catches_damage(tmp_path):
    scratch = tmp_path / "scratch"
    _worker_files(scratch, "00_00")
    executors.commit_view(tmp_path, "main", 1, "00_00", scratch, _unit())
    d = frame_dir(tmp_path, "main", 1) / "00_00"
    rec = json.loads((d / VIEW_RECORD).read_text())
    assert set(rec["files"]) == set(integrity.RENDER_FILES)
    assert rec["files"][PASSES_EXR]["size"] == (d / PASSES_EXR).stat().st_size
    assert integrity.view_complete(d)
    data = bytearray((d / RGB_EXR).read_bytes())
    data[-1] ^= 0xFF  # same size, one bit pattern changed: only the checksum sees it
    (d / RGB_EXR).write_bytes(bytes(data))
    assert integrity.render_problems(d) == [f"{RGB_EXR} differs from its recorded checksum"]
    assert integrity.render_problems(d, deep=False) == []
    (d / PASSES_EXR).write_bytes(b"")
    assert any(PASSES_EXR in p and "0 bytes" in p for p in integrity.render_problems(d))
    # a new render of the damaged view replaces it
    _worker_files(scratch, "00_00")
    executors.commit_view(tmp_path, "main", 1, "00_00", scratch, _unit())
    assert integrity.view_complete(d)
    assert not list(d.parent.glob(".00_00.tmp*"))


# -- tiny renders ------------------------------------------------------------------------------

VIDEO_RIG = RigSpec(name="main", rows=1, cols=2, width=W, height=H, baseline=0.1, at=(0.3, -5.0, 1.8), look_at=(0.0, 0.5, 0.6))
FRAMES = 4
TINY = ("--samples", "1", "--device", "cpu", "--quiet")
MOTION_KEYS = ("flow_fwd", "flow_bwd", "scene_flow", "disparity_change", "valid_fwd", "valid_bwd", "occlusion_fwd", "occlusion_bwd")


def _cli(*argv) -> tuple[int, str, str]:
    """The CLI in a subprocess (as a user runs it)."""
    p = subprocess.run([sys.executable, "-m", "lfusd.cli", *map(str, argv)], env={**os.environ, "PYTHONPATH": str(ROOT)},
                       capture_output=True, text=True, timeout=600)
    return p.returncode, p.stdout, p.stderr


@pytest.fixture(scope="module")
def stage(tmp_path_factory):
    from support.scenes import write_motion_stage

    path = tmp_path_factory.mktemp("faults") / "movers.usda"
    write_motion_stage(path, VIDEO_RIG, FRAMES, (0.05, -0.03, 0.0))
    return path


@pytest.fixture(scope="module")
def whole(stage):
    """Frames 1-4 rendered in one run."""
    out = stage.parent / "whole"
    # --keep-raw: the raw passes stay on disk, so a repair here renders no neighbour again
    # (tests/render/test_repair.py repairs the default, raw passes removed)
    code, _, err = _cli("render-video", stage, "-o", out, *TINY, "--keep-raw")
    assert code == 0, err
    return out


def _same_motion(a: Dataset, b: Dataset, frames) -> None:
    for f in frames:
        for v in a.views:
            for key in MOTION_KEYS:
                x, y = a.read(f, v, key), b.read(f, v, key)
                if np.issubdtype(x.dtype, np.floating):
                    np.testing.assert_allclose(x, y, rtol=1e-6, atol=1e-6, equal_nan=True, err_msg=f"{f} {v} {key}")
                else:
                    np.testing.assert_array_equal(x, y, err_msg=f"{f} {v} {key}")


@pytest.mark.render
def test_ranges_rendered_in_pieces_join_without_a_seam(stage, whole):
    """Case 4: --frames 1-2 then 3-4 gives the arrays of one 1-4 run; frame 2 gets its forward flow."""
    out = stage.parent / "pieces"
    assert _cli("render-video", stage, "-o", out, "--frames", "1-2", *TINY)[0] == 0
    assert not Dataset(out).read(2, (0, 0), "valid_fwd").any()  # the end of a range: masked, as CONVENTIONS says
    code, text, err = _cli("render-video", stage, "-o", out, "--frames", "3-4", *TINY)
    assert code == 0, err
    assert "motion derived for 6 views" in text, text  # frames 3, 4 and the boundary frame 2, of both views
    ds = Dataset(out)
    assert ds.frames == [1, 2, 3, 4]
    assert ds.read(2, (0, 0), "valid_fwd").mean() > 0.5
    _same_motion(ds, Dataset(whole), ds.frames)
    code, text, err = _cli("verify", out)
    assert code == 0, text + err


def _stat(d: Path) -> dict[str, tuple]:
    return {p.name: (p.stat().st_ino, p.stat().st_mtime_ns) for p in d.iterdir() if p.is_file()}


@pytest.mark.render
@pytest.mark.parametrize("overwrite", [False, True])
def test_damaged_files_are_repaired_by_a_rerun(stage, whole, tmp_path, overwrite):
    """Case 2 and the acceptance test: truncate or delete any one file of a finished dataset; the same
    command repairs exactly that view (and the motion next to it), and verify passes again."""
    out = tmp_path / "out"
    shutil.copytree(whole, out)
    damaged = {
        (2, "00_00"): lambda d: (d / PASSES_EXR).write_bytes((d / PASSES_EXR).read_bytes()[:53]),
        (3, "00_01"): lambda d: (d / MOTION_FILE).unlink(),
        (4, "00_00"): lambda d: (d / RGB_EXR).unlink(),
        (1, "00_01"): lambda d: (d / MOTION_FILE).write_bytes(b""),
    }
    for (f, key), damage in damaged.items():
        damage(frame_dir(out, "main", f) / key)
    before = {(f, k): _stat(frame_dir(out, "main", f) / k) for f in range(1, FRAMES + 1) for k in ("00_00", "00_01")}

    code, text, _ = _cli("verify", out, "--integrity")
    assert code == 1
    for f, key in damaged:
        assert f"frame {f} view {int(key[:2])},{int(key[3:])}:" in text, text

    code, text, err = _cli("render-video", stage, "-o", out, *TINY, "--keep-raw", *(["--overwrite"] if overwrite else []))
    assert code == 0, err
    assert "warning: rendering again 2 view(s)" in err, err
    for (f, key), stats in before.items():
        d = frame_dir(out, "main", f) / key
        assert integrity.view_complete(d), (f, key)
        if (f, key) == (2, "00_00"):
            assert _stat(d)[PASSES_EXR] != stats.get(PASSES_EXR), (f, key)  # damaged: rendered again
        else:
            assert _stat(d)[PASSES_EXR] == stats[PASSES_EXR], (f, key)  # left alone (frame 4's, beside its lost image, too)
        if key == "00_01" and f in (2, 4):
            assert _stat(d)[MOTION_FILE] == stats[MOTION_FILE], (f, key)  # a view far from any damage keeps its motion
    assert _cli("verify", out, "--integrity")[0] == 0
    code, text, err = _cli("verify", out)
    assert code == 0, text + err
    _same_motion(Dataset(out), Dataset(whole), range(1, FRAMES + 1))


@pytest.mark.render
def test_verify_fails_on_a_missing_motion_file_or_view(whole, tmp_path):
    """Case 5: a deleted motion.npz or view folder is a failure line, not skipped."""
    out = tmp_path / "out"
    shutil.copytree(whole, out)
    (frame_dir(out, "main", 2) / "00_01" / MOTION_FILE).unlink()
    shutil.rmtree(frame_dir(out, "main", 3) / "00_00")
    code, text, err = _cli("verify", out)
    assert code == 1, text + err
    fails = [ln for ln in text.splitlines() if ln.startswith("FAIL ")]
    assert any("frame 2 view 0,1" in ln and MOTION_FILE in ln for ln in fails), text
    assert any("frame 3 view 0,0" in ln and "no depth" in ln for ln in fails), text
    assert "all checks passed" not in text


# -- clean shutdown (case 7) ---------------------------------------------------------------------


def _start(*argv) -> subprocess.Popen:
    """The CLI in its own session, as a terminal runs it (Ctrl-C goes to its whole process group).
    SIGINT is reset to its default first: a test run started in the background by a shell without
    job control inherits it ignored, and Python then installs no KeyboardInterrupt handler."""
    return subprocess.Popen([sys.executable, "-m", "lfusd.cli", *map(str, argv)], env={**os.environ, "PYTHONPATH": str(ROOT)},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


WORKER, POOL = "lfusd.render.worker", "spawn_main"  # command-line marks of a Blender worker and a derivation pool process


def _wait_for_child(proc: subprocess.Popen, needle: str, count: int = 1, timeout: float = 120.0) -> list:
    """The descendants of ``proc`` once ``count`` of them have ``needle`` in their command line."""
    import psutil

    parent, end = psutil.Process(proc.pid), time.time() + timeout
    while time.time() < end:
        assert proc.poll() is None, f"lfusd ended before {count} {needle} processes started: {proc.communicate()}"
        try:
            kids = parent.children(recursive=True)
            if sum(needle in " ".join(k.cmdline()) for k in kids) >= count:
                return kids
        except psutil.Error:
            pass
        time.sleep(0.05)
    raise AssertionError(f"no {needle} process within {timeout} s")


def _render_args(stage, out, *extra):
    return ("render-video", stage, "-o", out, "--resolution", "64x48", *TINY, *extra)


@pytest.mark.render
def test_sigterm_stops_the_workers_and_exits_143(stage, tmp_path):
    proc = _start(*_render_args(stage, tmp_path / "out", "--workers", "2"))
    kids = _wait_for_child(proc, WORKER)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert err.splitlines()[-1] == "lfusd: terminated; rerun the same command to resume" and "Traceback" not in err, err
    assert not alive(kids, 5), "workers outlived lfusd"


@pytest.mark.render
def test_ctrl_c_during_derivation_stops_the_pool_and_exits_130(stage, tmp_path):
    proc = _start(*_render_args(stage, tmp_path / "out", "--workers", "2"))
    kids = _wait_for_child(proc, POOL, count=2)
    os.killpg(proc.pid, signal.SIGINT)  # as a terminal's Ctrl-C: the whole process group
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert err.splitlines()[-1] == "lfusd: interrupted; rerun the same command to resume" and "Traceback" not in err, err
    assert not alive(kids, 5), "derivation processes outlived lfusd"


@pytest.mark.render
def test_ctrl_c_under_ray_exits_130_and_leaves_no_ray_or_blender_process(stage, tmp_path):
    """Ray's local cluster (GCS, raylet, its workers) and the Blender workers all end with lfusd."""
    proc = _start(*_render_args(stage, tmp_path / "out", "--workers", "2", "--executor", "ray"))
    kids = _wait_for_child(proc, WORKER)
    os.killpg(proc.pid, signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert err.splitlines()[-1] == "lfusd: interrupted; rerun the same command to resume" and "Traceback" not in err, err
    assert not _reap(kids), "Ray or Blender processes outlived lfusd"


def _reap(procs: list) -> list[str]:
    """Kill what is still alive (a failed test must not leave it running); their command lines."""
    left = alive(procs, 3)
    for p in left:
        p.kill()
    return [" ".join(p.cmdline())[:120] for p in left]


PARENT = """
import os, subprocess, sys, time
r = int(sys.argv[1])
env = {**os.environ, "LFUSD_PARENT_PID": str(os.getpid())}
subprocess.Popen([sys.executable, "-m", "lfusd.render.worker"], stdin=r, pass_fds=(r,), env=env)
time.sleep(600)
"""


@pytest.mark.render
def test_a_blender_worker_dies_with_its_parent():
    """SIGKILL: no clean-up runs in lfusd. A Blender worker that writes nothing for a while (a long
    frame: the pipe it would die on is not written) must not render on; here it waits for its job on
    a stdin the test keeps open, and must die when its parent does."""
    r, w = os.pipe()
    try:
        parent = subprocess.Popen([sys.executable, "-c", PARENT, str(r)], pass_fds=(r,), env={**os.environ, "PYTHONPATH": str(ROOT)})
        kids = _wait_for_child(parent, WORKER)
        worker = next(k for k in kids if WORKER in " ".join(k.cmdline()))
        end = time.time() + 60
        while "bpy" not in " ".join(m.path for m in worker.memory_maps()) and time.time() < end:
            time.sleep(0.2)  # Blender loaded: the worker is in main(), waiting for its job
        time.sleep(1)
        assert worker.is_running()
        parent.kill()
        parent.wait()
        assert not _reap([worker])
    finally:
        os.close(r)
        os.close(w)


@pytest.mark.render
def test_killed_lfusd_takes_its_derivation_pool_along(stage, tmp_path):
    """SIGKILL during derivation with --workers 2: the pool processes, which hold both ends of their
    task queue and would wait on it forever, die with lfusd."""
    proc = _start(*_render_args(stage, tmp_path / "out", "--workers", "2"))
    kids = _wait_for_child(proc, POOL, count=2)
    proc.kill()
    proc.communicate(timeout=60)
    assert not _reap(kids)
