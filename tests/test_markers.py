"""The `blender` marker's guard (tests/support/markers.py): with Blender's tests deselected, as
in `make test-fast`, a test that starts Blender without the marker fails naming the marker, and
Blender does not start; `render` implies `blender`."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

TESTS = Path(__file__).resolve().parent

PROBE = '''
import subprocess, sys
import pytest

def _start_blender():
    # the way the render worker and tests/support/blender_skin_probe.py start Blender: a process importing bpy
    return subprocess.run([sys.executable, "-c", "import bpy; print('BPY-LOADED')"], capture_output=True, text=True)

def test_unmarked_starts_blender():
    _start_blender()

@pytest.mark.blender
def test_marked_blender():
    assert "BPY-LOADED" in _start_blender().stdout

@pytest.mark.render
def test_marked_render():
    assert "BPY-LOADED" in _start_blender().stdout

def test_no_blender():
    assert subprocess.run([sys.executable, "-c", "import json"]).returncode == 0
'''


def _pytest(tmp_path, *args):
    (tmp_path / "test_probe.py").write_text(PROBE)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")])}
    env.pop("LFUSD_NO_BLENDER", None)
    return subprocess.run([sys.executable, "-m", "pytest", "-p", "support.markers", "-p", "no:cacheprovider", "-p", "no:dash",
                           "-rA", "--rootdir", str(tmp_path), str(tmp_path / "test_probe.py"), *args],
                          capture_output=True, text=True, cwd=tmp_path, env=env, timeout=240)


def test_test_fast_fails_an_unmarked_test_that_starts_blender_and_runs_the_rest(tmp_path):
    r = _pytest(tmp_path, "-m", "not blender and not slow")
    out = r.stdout
    assert r.returncode == 1, out + r.stderr
    assert "FAILED test_probe.py::test_unmarked_starts_blender" in out
    assert "test_probe.py::test_unmarked_starts_blender started Blender" in out and "add @pytest.mark.blender" in out
    assert "PASSED test_probe.py::test_no_blender" in out
    assert "1 failed, 1 passed, 2 deselected" in out  # render implies blender: both marked tests deselected
    assert "BPY-LOADED" not in out  # the stand-in bpy stopped it


def test_render_implies_blender_when_selecting(tmp_path):
    r = _pytest(tmp_path, "-m", "blender", "--collect-only", "-q")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "test_probe.py::test_marked_blender" in r.stdout and "test_probe.py::test_marked_render" in r.stdout
    assert "test_unmarked" not in r.stdout and "test_no_blender" not in r.stdout



def test_make_test_fast_deselects_blender_and_so_arms_the_guard():
    makefile = (TESTS.parent / "Makefile").read_text()
    recipe = makefile.split("\ntest-fast:", 1)[1].split("\n\n", 1)[0]
    assert '-m "not blender and not slow"' in recipe, recipe


def test_the_guard_survives_a_test_that_forbids_file_access(tmp_path):
    """The guard reads its log without pathlib or open, which tests monkeypatch (test_dataset's no-I/O test)."""
    (tmp_path / "test_probe.py").write_text(
        "import builtins, pathlib\n\n"
        "def test_no_io(monkeypatch):\n"
        "    for name in ('stat', 'exists', 'read_text'):\n"
        "        monkeypatch.setattr(pathlib.Path, name, lambda *a, **k: 1 / 0)\n"
        "    monkeypatch.setattr(builtins, 'open', lambda *a, **k: 1 / 0)\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")])}
    r = subprocess.run([sys.executable, "-m", "pytest", "-p", "support.markers", "-p", "no:cacheprovider", "-p", "no:dash",
                        "--rootdir", str(tmp_path), str(tmp_path / "test_probe.py"), "-m", "not blender"],
                       capture_output=True, text=True, cwd=tmp_path, env=env, timeout=240)
    assert r.returncode == 0 and "1 passed" in r.stdout, r.stdout + r.stderr


ORDER_PROBE = '''
import os
import pytest

def _log(request):
    with open(os.environ["ORDER_LOG"], "a") as f:
        f.write(request.node.name + "\\n")

def test_{name}_0(request):
    _log(request)

def test_{name}_1(request):
    _log(request)

def test_{name}_2(request):
    _log(request)
'''


def test_under_loadgroup_the_longest_group_starts_first_not_the_one_with_most_tests(tmp_path):
    """xdist's own order (most tests first) starts a module of a few slow tests last, leaving one
    worker to run it alone at the end; the order of markers.longest_groups_first starts it first."""
    (tmp_path / "test_many.py").write_text(ORDER_PROBE.format(name="many") + "\ndef test_many_3(request):\n    _log(request)\n")
    (tmp_path / "test_plain.py").write_text(ORDER_PROBE.format(name="plain"))
    # last in collection order, fewest tests: one marked slow, one marked blender (Blender never starts)
    slow = ORDER_PROBE.format(name="slow").split("def test_slow_2")[0]
    slow = slow.replace("def test_slow_0", "@pytest.mark.slow\ndef test_slow_0").replace("def test_slow_1", "@pytest.mark.blender\ndef test_slow_1")
    (tmp_path / "test_z_slow.py").write_text("import pytest\n" + slow)
    log = tmp_path / "order.log"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")]), "ORDER_LOG": str(log),
           "LFUSD_NO_BLENDER": "0"}
    r = subprocess.run([sys.executable, "-m", "pytest", "-p", "support.markers", "-p", "no:cacheprovider", "-p", "no:dash",
                        "-n", "1", "--dist", "loadgroup", "--rootdir", str(tmp_path), "-q", str(tmp_path)],
                       capture_output=True, text=True, cwd=tmp_path, env=env, timeout=240)
    assert r.returncode == 0 and "9 passed" in r.stdout, r.stdout + r.stderr
    # one worker runs the groups in the scheduler's order: slow+blender (40) > many (4) > plain (3)
    assert log.read_text().split() == ["test_slow_0", "test_slow_1", *(f"test_many_{i}" for i in range(4)),
                                       *(f"test_plain_{i}" for i in range(3))]


# how a test starts Ray: the CLI's Ray executor, or `ray start` (a cluster, a user's Ray)
STARTS_RAY = ('"--executor", "ray"', "ray.scripts")


def test_every_test_that_starts_ray_is_in_the_ray_group():
    """A test starting Ray outside the ray group would run beside another Ray test on the other
    worker (markers.RAY_FILES); a helper starting it outside RAY_FILES would hide which tests do."""
    import ast
    from types import SimpleNamespace

    from support.markers import RAY_FILES, xdist_group

    misplaced = []
    for path in sorted(TESTS.rglob("test_*.py")):
        if path.name in RAY_FILES or path.name == "test_markers.py":
            continue
        source = path.read_text()
        if not any(s in source for s in STARTS_RAY):
            continue
        for node in ast.parse(source).body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and any(s in ast.get_source_segment(source, node) for s in STARTS_RAY):
                item = SimpleNamespace(path=path, name=node.name, originalname=node.name)
                if not node.name.startswith("test_") or xdist_group(item) != "ray":
                    misplaced.append(f"{path.relative_to(TESTS)}::{node.name}")
    assert not misplaced, f"start Ray outside the ray group (tests/support/markers.py RAY_FILES / RAY_TESTS): {misplaced}"
    faults = TESTS / "test_faults.py"
    assert xdist_group(SimpleNamespace(path=faults, name="test_sigterm_stops_the_workers_and_exits_143",
                                       originalname="test_sigterm_stops_the_workers_and_exits_143")) == "test_faults.py"


def test_loadgroup_keeps_each_files_tests_on_one_worker(tmp_path):
    """Under ``-n 2 --dist loadgroup`` the tests of one file run on one worker (so that a module
    fixture renders once): with pytest 9 and xdist 3.8 they did not, until markers.py gave each
    node id its group itself."""

    (tmp_path / "conftest.py").write_text(
        f"import sys\nsys.path.insert(0, {str(TESTS)!r})\n"
        "from support.markers import pytest_collection_modifyitems, pytest_configure  # noqa: F401\n")
    for name in ("a", "b"):
        (tmp_path / f"test_{name}.py").write_text(
            "import os, time, pytest\n"
            "@pytest.mark.parametrize('k', range(6))\n"
            f"def test_one(k):\n    time.sleep(0.05)\n"
            f"    with open({str(tmp_path / name)!r} + os.environ['PYTEST_XDIST_WORKER'], 'a') as f:\n        f.write('x')\n")
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-n", "2", "--dist", "loadgroup", "-p", "no:cacheprovider",
                           "-p", "no:randomly", str(tmp_path)], cwd=tmp_path, capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    for name in ("a", "b"):
        ran = {p.name: len(p.read_text()) for p in tmp_path.glob(f"{name}gw*")}
        assert len(ran) == 1 and sum(ran.values()) == 6, (name, ran)
