"""The CLI: `lfusd rig add`, `lfusd render`; one-line errors for bad input, nothing half-written."""

from __future__ import annotations

import json
import os
import re
import shutil

import pytest
from support.scenes import write_box_stage, write_motion_stage

from support.cli import assert_one_line_error, run_cli
from lfusd.camera import RigSpec
from lfusd.author.stage import open_stage
from lfusd.author.rigs import rigs


@pytest.fixture
def bare_stage(tmp_path):
    path = tmp_path / "bare.usda"
    write_box_stage(path, [])
    return path


def test_rig_add_writes_a_rig_with_the_default_reference_parameters(capsys, bare_stage):
    code, out, _ = run_cli(capsys, "rig", "add", bare_stage, "--name", "main")
    assert code == 0 and "added rig main" in out
    rig = rigs(open_stage(bare_stage))["main"]
    assert rig.spec == RigSpec(name="main")
    assert len(rig.cameras) == 81


def test_rig_add_sphere_defaults_to_converging_axes(capsys, bare_stage):
    code, _, _ = run_cli(
        capsys, "rig", "add", bare_stage, "--name", "s", "--grid", "3x5", "--layout", "sphere", "--radius", "6",
        "--spacing", "inverse", "--resolution", "32x24", "--at", "0,-6,1", "--look-at", "0,0,1",
    )
    assert code == 0
    spec = rigs(open_stage(bare_stage))["s"].spec
    assert (spec.rows, spec.cols, spec.layout, spec.axes, spec.radius, spec.spacing, spec.width, spec.height) == (3, 5, "sphere", "converge", 6.0, "inverse", 32, 24)


@pytest.mark.parametrize(
    "args,needles",
    [
        (["--grid", "9"], ["grid", "RxC"]),
        (["--grid", "0x3"], ["grid", "positive"]),
        (["--resolution", "1024"], ["resolution", "WxH"]),
        (["--resolution=-5x5"], ["resolution", "positive"]),
        (["--baseline", "abc"], ["--baseline", "invalid float"]),
        (["--baseline", "0"], ["baseline must be a positive"]),
        (["--baseline", "-0.1"], ["baseline must be a positive"]),
        (["--at", "1,2"], ["--at", "X,Y,Z"]),
        (["--spacing", "weird"], ["unknown spacing"]),
    ],
)
def test_rig_add_bad_input(capsys, bare_stage, args, needles):
    before = bare_stage.read_bytes()
    code, _, err = run_cli(capsys, "rig", "add", bare_stage, *args)
    assert_one_line_error(code, err, *needles)
    assert bare_stage.read_bytes() == before


def test_rig_add_missing_and_malformed_stage(capsys, tmp_path):
    code, _, err = run_cli(capsys, "rig", "add", tmp_path / "nope.usda")
    assert_one_line_error(code, err, "nope.usda", "does not exist")
    bad = tmp_path / "bad.usda"
    bad.write_text("#usda 1.0\ndef Xform \"A\" {\n  float x = \n")
    code, _, err = run_cli(capsys, "rig", "add", bad)
    assert_one_line_error(code, err, "bad.usda", "not a readable USD file")


def test_render_bad_input_writes_nothing(capsys, tmp_path, bare_stage):
    out = tmp_path / "out"
    code, _, err = run_cli(capsys, "render", tmp_path / "missing.usda", "-o", out)
    assert_one_line_error(code, err, "missing.usda", "does not exist")
    code, _, err = run_cli(capsys, "render", bare_stage, "-o", out)
    assert_one_line_error(code, err, "has no light-field rig", "lfusd rig add")
    assert run_cli(capsys, "rig", "add", bare_stage, "--name", "a", "--grid", "1x1", "--resolution", "8x8")[0] == 0
    assert run_cli(capsys, "rig", "add", bare_stage, "--name", "b", "--grid", "1x1", "--resolution", "8x8")[0] == 0
    code, _, err = run_cli(capsys, "render", bare_stage, "-o", out)
    assert_one_line_error(code, err, "2 rigs", "--rig")
    code, _, err = run_cli(capsys, "render", bare_stage, "-o", out, "--rig", "c")
    assert_one_line_error(code, err, "no rig named 'c'", "a, b")
    # Frames outside an animated stage's range are refused (a static stage, like bare_stage, takes any).
    moving = tmp_path / "moving.usda"
    write_motion_stage(moving, RigSpec(name="a", rows=1, cols=1, width=8, height=8), frames=3)
    code, _, err = run_cli(capsys, "render", moving, "-o", out, "--frame", "7")
    assert_one_line_error(code, err, "frame 7", "range 1-3")
    code, _, err = run_cli(capsys, "render", bare_stage, "-o", out, "--rig", "a", "--samples", "0")
    assert_one_line_error(code, err, "--samples")
    assert not out.exists()


def test_render_refuses_a_folder_holding_something_else(capsys, tmp_path, bare_stage):
    run_cli(capsys, "rig", "add", bare_stage, "--name", "a", "--grid", "1x1", "--resolution", "8x8")
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    code, _, err = run_cli(capsys, "render", bare_stage, "-o", out)
    assert_one_line_error(code, err, str(out), "not empty")
    (out / "notes.txt").unlink()
    (out / "manifest.json").write_text(json.dumps({"format": "lfusd-dataset", "id": "x", "settings": {"stage_id": "0" * 64, "samples": 16, "rigs": {}}}))
    code, _, err = run_cli(capsys, "render", bare_stage, "-o", out)
    assert_one_line_error(code, err, "holds a different dataset", "stage file bare.usda", "--overwrite")
    assert sorted(p.name for p in out.iterdir()) == ["manifest.json"]


@pytest.mark.render
def test_rerun_resumes_only_missing_views_and_settings_change_is_refused(capsys, tmp_path):
    stage = tmp_path / "s.usda"
    write_box_stage(stage, [RigSpec(name="main", rows=1, cols=3, width=16, height=12, at=(0, -5, 1), look_at=(0, 0, 0.5))])
    out = tmp_path / "out"
    assert run_cli(capsys, "render", stage, "-o", out, "--samples", "2", "--quiet", "--device", "cpu")[0] == 0
    frame = out / "main" / "f000001"
    keep = (frame / "00_00" / "gt.exr").stat().st_mtime_ns
    shutil.rmtree(frame / "00_02")
    (frame / ".00_02.tmp-999").mkdir()  # debris of a killed run
    (frame / ".00_02.tmp-999" / "rgb.exr").write_bytes(b"partial")
    code, _, err = run_cli(capsys, "render", stage, "-o", out, "--samples", "2", "--device", "cpu")
    assert code == 0
    assert "1/3" not in err and "3/3 views" in err  # only one view was rendered again
    assert (frame / "00_02" / "gt.exr").is_file() and not (frame / ".00_02.tmp-999").exists()
    assert (frame / "00_00" / "gt.exr").stat().st_mtime_ns == keep
    code, _, err = run_cli(capsys, "render", stage, "-o", out, "--samples", "3", "--device", "cpu")
    assert_one_line_error(code, err, "holds a different dataset", "samples")
    assert (frame / "00_00" / "gt.exr").stat().st_mtime_ns == keep
    code, _, _ = run_cli(capsys, "render", stage, "-o", out, "--samples", "3", "--quiet", "--device", "cpu", "--overwrite")
    assert code == 0 and json.loads((out / "manifest.json").read_text())["settings"]["samples"] == 3
    assert not any(p.name.startswith(".") for p in frame.iterdir())
    assert os.listdir(out / "main") == ["f000001"]


def test_rig_add_takes_negative_coordinates(capsys, bare_stage):
    code, _, err = run_cli(capsys, "rig", "add", bare_stage, "--name", "neg", "--grid", "1x1", "--at", "-0.05,0.6,3",
                           "--look-at", "-1,-2,0.5")
    assert code == 0, err
    spec = rigs(open_stage(bare_stage))["neg"].spec
    assert spec.at == pytest.approx((-0.05, 0.6, 3.0)) and spec.look_at == pytest.approx((-1.0, -2.0, 0.5))


def test_errors_are_one_line_and_traceback_shows_the_hidden_cause(capsys, monkeypatch, tmp_path):
    bad = tmp_path / "bad.usda"
    bad.write_text("#usda 1.0\ndef Xform \"A\" {\n  float x = \n")
    code, _, err = run_cli(capsys, "rig", "add", bad)
    assert_one_line_error(code, err, "not a readable USD file")
    assert "Traceback" not in err
    # open_stage raises `from None`: the pxr parse error is only visible with --traceback.
    for argv, env in ((["--traceback", "rig", "add", bad], None), (["rig", "add", bad, "--traceback"], None), (["rig", "add", bad], "1")):
        if env:
            monkeypatch.setenv("LFUSD_DEBUG", env)
        code, _, err = run_cli(capsys, *argv)
        assert code == 2 and "Traceback" in err and "ErrorException" in err
        assert "During handling of the above exception, another exception occurred" in err
        assert err.rstrip().splitlines()[-1].startswith("lfusd: error: stage")


def test_an_unexpected_exception_is_a_summary_line_and_a_traceback_file(capsys, monkeypatch):
    import lfusd.commands.derive as derive

    def bug(args):
        return {}["missing"]

    monkeypatch.setattr(derive, "run", bug)
    code, _, err = run_cli(capsys, "derive", "OUT")
    assert code == 3 and len(err.strip().splitlines()) == 1
    m = re.match(r"lfusd: internal error: KeyError: 'missing'; the traceback is in (\S+) \(please report it\)$", err.strip())
    assert m, err
    text = open(m.group(1)).read()
    os.unlink(m.group(1))
    assert "Traceback" in text and "in bug" in text


def test_warnings_are_logged_on_one_line(capsys, monkeypatch):
    import logging

    import lfusd.commands.derive as derive

    def chatty(args):
        log = logging.getLogger("lfusd.truth.derive")
        log.warning("something is off in %s", args.out)
        log.info("detail")
        return 0

    monkeypatch.setattr(derive, "run", chatty)
    code, _, err = run_cli(capsys, "derive", "OUT")
    assert code == 0 and err == "lfusd: warning: something is off in OUT\n"
    code, _, err = run_cli(capsys, "derive", "OUT", "-v")
    assert err == "lfusd: warning: something is off in OUT\nlfusd: info: detail\n"


def test_flow_is_the_old_name_of_derive_and_says_so_in_one_line(capsys, monkeypatch):
    import lfusd.commands.derive as derive

    seen = []
    monkeypatch.setattr("lfusd.truth.derive.derive_dataset", lambda out, rigs, frames, views, overwrite: seen.append((out, rigs, frames)) or 3)
    code, out, err = run_cli(capsys, "derive", "OUT", "--rig", "main", "--frames", "1-2")
    assert (code, err, seen) == (0, "", [("OUT", ["main"], [1, 2])]) and "motion derived for 3 views" in out
    code, out, err = run_cli(capsys, "flow", "OUT", "--rig", "main", "--frames", "1-2")
    assert code == 0 and seen[-1] == ("OUT", ["main"], [1, 2]) and "motion derived for 3 views" in out
    assert err == "lfusd: warning: 'lfusd flow' is deprecated; use 'lfusd derive' (same arguments)\n"
    assert derive.DEPRECATED == {"flow": "derive"}


def test_every_command_has_one_handler_name_and_the_one_rig_option():
    """Handlers are ``run`` (a command) or ``run_<action>`` (an action of a command group), and every
    --rig comes from the argument layer (commands/args.py), so it reads the same everywhere."""
    import argparse

    from lfusd.cli import build_parser
    from lfusd.commands.args import RIG_HELP

    todo, seen = [("lfusd", build_parser())], 0
    while todo:
        name, parser = todo.pop()
        func = parser.get_default("func")
        group = any(isinstance(a, argparse._SubParsersAction) for a in parser._actions)
        if name != "lfusd" and not (group and func is None):  # a group may leave an action to argparse
            assert func is not None and re.fullmatch(r"run(_[a-z_]+)?", func.__name__), (name, func)
            seen += 1
        rig = [a for a in parser._actions if "--rig" in a.option_strings]
        assert not rig or rig[0].help in RIG_HELP.values(), (name, rig[0].help)
        for a in parser._actions:
            if isinstance(a, argparse._SubParsersAction):
                todo += [(f"{name} {n}", p) for n, p in a.choices.items()]
    assert seen >= 15


FACADE = ("Dataset", "render_frame", "render_video", "generate", "add_rig", "add_person", "derive", "verify", "export", "evaluate")


@pytest.mark.parametrize("name", FACADE)
def test_facade_names_resolve_to_library_callables(name):
    import lfusd

    obj = getattr(lfusd, name)
    assert callable(obj) and obj.__module__.startswith("lfusd.") and name in lfusd.__all__
    with pytest.raises(AttributeError):
        lfusd.not_a_step


def test_a_stuck_exit_function_does_not_keep_a_stopped_program_alive():
    """A stopped program (exit 130) runs Python's exit functions, then exits: one that never returns
    (as once at the end of a stopped Ray run) delays it by lfusd.cli.EXIT_FUNCTIONS_SECONDS at most,
    and the exit code and the one line stay."""
    import subprocess
    import sys
    import time
    from pathlib import Path

    script = (
        "import atexit, sys, time\n"
        "from lfusd import cli\n"
        "cli.EXIT_FUNCTIONS_SECONDS = 1.0\n"
        "atexit.register(time.sleep, 3600)\n"
        "cli._main = lambda argv: cli._interrupted()\n"
        "sys.exit(cli.main())\n"
    )
    root = Path(__file__).resolve().parents[1]
    t = time.monotonic()
    p = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                       env={**os.environ, "PYTHONPATH": str(root)})
    assert time.monotonic() - t < 60
    assert p.returncode == 130
    assert p.stderr.strip().splitlines() == ["lfusd: interrupted; rerun the same command to resume"]


def test_verify_prints_a_line_per_view_only_with_verbose(capsys, monkeypatch):
    """Issue 39.14: `lfusd verify` without -v prints its table, not one line per view."""
    import lfusd.truth.verify
    from lfusd.cli import main

    class Report:
        ok = True

        def table(self):
            return "key  ok"

        def failures(self):
            return []

        def compared(self):
            return {"depth": 10}

    def fake_verify(out, progress=None, **kw):
        for v in ((0, 0), (0, 1), (1, 0)):
            if progress:
                progress(1, v)
        return {"": Report()}

    monkeypatch.setattr(lfusd.truth.verify, "verify", fake_verify)
    assert main(["verify", "/nowhere"]) == 0
    quiet = capsys.readouterr()
    assert "verifying frame" not in quiet.out + quiet.err and "all checks passed" in quiet.out
    assert main(["verify", "/nowhere", "-v"]) == 0
    loud = capsys.readouterr()
    assert loud.err.count("verifying frame 1 view") == 3


def test_rig_add_over_an_asset_reports_each_broken_arc_once_in_one_line(capfd, tmp_path):
    """Issue 39.19: `rig add -o` over an asset with broken references (as OpenChessSet's) printed
    every composition error twice (the asset's stage, then the layer over it)."""
    from lfusd.cli import main

    asset = tmp_path / "chess.usda"
    asset.write_text('#usda 1.0\n(\n    defaultPrim = "World"\n    upAxis = "Z"\n    metersPerUnit = 1\n)\n'
                     'def Xform "World"\n{\n    def Xform "Knight" (\n        references = @./missing_knight.usda@\n    )\n    {\n    }\n'
                     '    def Xform "Board" (\n        payload = @./missing_board.usda@\n    )\n    {\n    }\n}\n')
    assert main(["rig", "add", str(asset), "-o", str(tmp_path / "over.usda"), "--grid", "2x2"]) == 0
    err = [ln for ln in capfd.readouterr().err.splitlines() if ln.strip()]
    assert all(ln.startswith("lfusd: warning: USD: ") for ln in err), err  # nothing of pxr's own output
    assert sum("missing_knight.usda" in ln for ln in err) == 1 and sum("missing_board.usda" in ln for ln in err) == 1, err


def test_a_ctrl_c_inside_a_finaliser_is_the_one_line_and_exit_130():
    """A Ctrl-C that arrives while a finaliser runs (a ``__del__`` the garbage collector calls)
    cannot propagate; Python would print it as "Exception ignored in ..." with a traceback (CI saw
    it once among random Ctrl-Cs of `lfusd verify`). The run still stops with the one line."""
    import subprocess
    import sys
    from pathlib import Path

    script = (
        "import os, signal, sys\n"
        "from lfusd import cli\n"
        "class Finalised:\n"
        "    def __del__(self):\n"
        "        os.kill(os.getpid(), signal.SIGINT)\n"
        "        for _ in range(1000):\n"  # bytecodes inside the finaliser, where the handler runs
        "            pass\n"
        "def command(argv):\n"  # cli._main's handling, around a command that drops an object
        "    try:\n"
        "        Finalised()\n"
        "        print('carried on', file=sys.stderr)\n"
        "        import json\n"  # an import after a latched Ctrl-C raises it
        "        return 0\n"
        "    except KeyboardInterrupt:\n"
        "        return cli._interrupted()\n"
        "cli._main = command\n"
        "sys.exit(cli.main())\n"
    )
    root = Path(__file__).resolve().parents[1]
    p = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                       env={**os.environ, "PYTHONPATH": str(root)})
    assert p.returncode == 130, p.stderr
    lines = [ln for ln in p.stderr.strip().splitlines() if ln != "carried on"]
    assert lines == ["lfusd: interrupted; rerun the same command to resume"], p.stderr


def test_a_latched_ctrl_c_is_raised_at_the_main_threads_imports_only():
    """A Ctrl-C latched by lfusd is raised again at the next import of the main thread, where lfusd
    reports it; another thread's import goes on (raised there, it would end that thread with a
    traceback on stderr: "Exception in thread ...")."""
    import threading

    from lfusd import cli

    got = []
    cli._Interrupt.pending = True
    try:
        t = threading.Thread(target=lambda: got.append(cli._RaiseAtImport.find_spec("lfusd_not_a_module")))
        t.start()
        t.join()
        with pytest.raises(KeyboardInterrupt):
            cli._RaiseAtImport.find_spec("lfusd_not_a_module")
    finally:
        cli._Interrupt.pending = False
    assert got == [None]
