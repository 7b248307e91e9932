"""The test markers and what enforces them: a test that starts Blender says so (`blender`), and
`make test-fast` starts none; every test has a time limit (pytest-timeout).

Every test that starts Blender (the render worker, a `lfusd render*` command, a script importing
bpy, or a fixture doing any of that) carries ``@pytest.mark.blender``; ``render`` (renders with
Blender) implies it. When the run deselects them (``-m "not blender ..."``, as `make test-fast`
does, or ``LFUSD_NO_BLENDER=1``), the guard puts a stand-in ``bpy`` first on the module path of
this process and of every process it starts (PYTHONPATH): importing it records the process in a
log and fails, so Blender never starts, and the test that caused it fails naming the marker to add.

Time limits: pytest's ``timeout`` option (pyproject.toml, 300 s) holds for a plain test; a test
marked ``blender`` or ``slow`` gets :data:`LONG_TIMEOUT` (a render on two busy cores, a numba
compilation), and ``@pytest.mark.timeout(N)`` on a test overrides both.

Order under xdist (``make test``, ``--dist loadgroup``): the groups of :func:`xdist_group` are handed
out longest first, by :func:`group_cost` (xdist's own order, most tests first, started the
two-test tests/test_interrupts.py, 40 interrupted runs and a 72-view render, 99th of 106 groups,
and the one-test render modules last: one worker running them while the other idled).

Loaded by tests/conftest.py; a pytest run elsewhere loads it with ``-p support.markers``.
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from pathlib import Path

import pytest

MARKERS = (
    "blender: starts a Blender process (bpy, the render worker, an lfusd render command); make test-fast deselects it",
    "render: renders with Blender (tiny images, seconds each); implies blender",
)
LONG_TIMEOUT = 1200  # seconds, for tests marked blender or slow (setup included: a session fixture renders)
LOG_ENV = "LFUSD_BLENDER_STARTS"  # the stand-in's log: one line per process that imported it

STAND_IN = '''"""A stand-in for bpy (tests/support/markers.py): this run deselects the tests that start Blender."""
import os, sys
with open(os.environ["{log}"], "a") as f:
    f.write(f"{{os.getpid()}} {{' '.join(sys.argv)}}\\n")
raise ImportError("Blender is blocked in this run (tests marked blender are deselected); mark the test @pytest.mark.blender")
'''


def active(config) -> bool:
    """True when the run deselects the tests that start Blender."""
    expr = (config.getoption("markexpr", "") or "").replace(" ", "")
    return os.environ.get("LFUSD_NO_BLENDER", "") not in ("", "0") or "notblender" in expr


def pytest_configure(config) -> None:
    for line in MARKERS:
        config.addinivalue_line("markers", line)
    if getattr(config.option, "loadscopereorder", None):
        # the scheduler keeps the workers' collection order, which longest_groups_first sets
        config.option.loadscopereorder = False
    if hasattr(config, "workerinput") and not config.pluginmanager.has_plugin("lfusd-order"):
        config.pluginmanager.register(_Order(), "lfusd-order")  # an xdist worker: its collection order is the scheduler's
    if not active(config):
        return
    folder = Path(tempfile.mkdtemp(prefix="lfusd-no-blender-"))
    log = folder / "starts.log"
    log.touch()
    (folder / "bpy.py").write_text(STAND_IN.format(log=LOG_ENV))
    os.environ[LOG_ENV] = str(log)
    os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (str(folder), os.environ.get("PYTHONPATH", "")) if p)
    sys.path.insert(0, str(folder))
    # read through a descriptor with os.fstat/os.pread: tests monkeypatch pathlib and open
    config._lfusd_blender_log = os.open(log, os.O_RDONLY)
    config._lfusd_blender_folder = folder


def pytest_unconfigure(config) -> None:
    """Remove the stand-in and its log (the run's processes have ended)."""
    fd = getattr(config, "_lfusd_blender_log", None)
    if fd is not None:
        os.close(fd)
        shutil.rmtree(config._lfusd_blender_folder, ignore_errors=True)


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items) -> None:
    """``render`` implies ``blender``, before -m deselects anything (tryfirst); long tests get
    :data:`LONG_TIMEOUT` unless they name their own."""
    for item in items:
        if item.get_closest_marker("render") and not item.get_closest_marker("blender"):
            item.add_marker(pytest.mark.blender)
        if (item.get_closest_marker("blender") or item.get_closest_marker("slow")) and not item.get_closest_marker("timeout"):
            item.add_marker(pytest.mark.timeout(LONG_TIMEOUT))
        if not item.get_closest_marker("xdist_group"):
            item.add_marker(pytest.mark.xdist_group(xdist_group(item)))
    if getattr(config.option, "loadgroup", False):
        for item in items:
            _suffix_group(item)


def _suffix_group(item) -> None:
    """Append ``@group`` to the node id in an xdist worker, as xdist's own hook means to: xdist 3.8
    sets ``item._nodeid``, which pytest 9 no longer reads (its node id is ``item._id``), so under
    pytest 9 no test had its group and ``--dist loadgroup`` spread every file over both workers
    (module fixtures rendered twice, Ray tests side by side). A suffix already there is kept."""
    try:
        from _pytest.nodeid import NodeId
    except ImportError:  # pytest 8: xdist's suffix works
        return
    if not isinstance(getattr(item, "_id", None), NodeId) or "@" in item.nodeid.rpartition("]")[2]:
        return
    item._id = NodeId.parse(f"{item.nodeid}@{_group_name(item)}")


class _Order:
    """Orders an xdist worker's collection by :func:`longest_groups_first`, after ``-m`` and ``-k``
    deselected what they do (a wrapper: its second half runs after every other hook)."""

    @pytest.hookimpl(wrapper=True)
    def pytest_collection_modifyitems(self, config, items):
        result = yield
        items[:] = longest_groups_first(items)
        return result


def _guarded(item):
    fd = getattr(item.config, "_lfusd_blender_log", None)
    if fd is None:
        return (yield)
    before = os.fstat(fd).st_size
    try:
        return (yield)
    finally:
        grown = os.fstat(fd).st_size - before
        started = os.pread(fd, grown, before).decode(errors="replace").strip().splitlines() if grown > 0 else []
        if started:
            pytest.fail(f"{item.nodeid} started Blender ({started[0]}) but is not marked blender; "
                        "add @pytest.mark.blender (or render) to it", pytrace=False)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_setup(item):
    return (yield from _guarded(item))


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item):
    return (yield from _guarded(item))


@pytest.hookimpl(wrapper=True)
def pytest_runtest_teardown(item, nextitem):
    return (yield from _guarded(item))



# Tests that start a Ray instance or cluster run one after another on one xdist worker: their Ctrl-C
# timings and process sweeps are measured on a machine not also starting another Ray. Whole files
# where most tests do (or share a module fixture that a Ray test needs), single tests elsewhere, so
# that the rest of their file runs beside the ray group (test_faults.py: its one Ray test needs only
# the stage file of its module fixture; its renders are not Ray's). tests/test_markers.py checks
# that every test starting Ray is in one of them.
RAY_FILES = frozenset({"test_ray_shutdown.py", "test_ray_cluster.py", "test_ray_loopback.py", "test_executors.py",
                       "test_render_video.py"})
RAY_TESTS = frozenset({("test_faults.py", "test_ctrl_c_under_ray_exits_130_and_leaves_no_ray_or_blender_process")})


TESTS = Path(__file__).resolve().parents[1]


def xdist_group(item) -> str:
    """The group whose tests one xdist worker runs in order (``--dist loadgroup``): the test's
    file (relative to tests/), so that its module fixtures render once; ``ray`` for :data:`RAY_FILES`
    and :data:`RAY_TESTS`; ``bench`` for tests/bench/."""
    name = item.path.name
    test = getattr(item, "originalname", None) or item.name
    if name in RAY_FILES or (name, test) in RAY_TESTS:
        return "ray"
    if item.path.parent.name == "bench":
        return "bench"  # its files share the session fixture tiny_bench (`lfusd bench make tiny`, about 30 s)
    path = Path(item.path)
    return str(path.relative_to(TESTS)) if path.is_relative_to(TESTS) else str(path)


# Rough seconds of one test on a busy 2-core machine, by marker: a plain test, one that starts
# Blender (or is in a module whose fixture renders), one marked slow (a long sweep, a compilation).
PLAIN_COST, BLENDER_COST, SLOW_COST = 1.0, 10.0, 30.0


def group_cost(items) -> float:
    """A group's expected run time, from its tests' markers (the schedule's order, not a limit)."""
    return sum(SLOW_COST if it.get_closest_marker("slow") else BLENDER_COST if it.get_closest_marker("blender") else PLAIN_COST
               for it in items)


def _group_name(item) -> str:
    mark = item.get_closest_marker("xdist_group")
    return (mark.args[0] if mark.args else mark.kwargs.get("name", "")) if mark else xdist_group(item)


def longest_groups_first(items) -> list:
    """``items`` with whole groups ordered by :func:`group_cost`, highest first (ties keep the
    collection order), each group's tests in their own order: with ``--dist loadgroup`` the longest
    groups start first and the short ones fill in at the end (longest-processing-time scheduling)."""
    groups: dict[str, list] = {}
    for it in items:
        groups.setdefault(_group_name(it), []).append(it)
    ordered = sorted(groups.values(), key=group_cost, reverse=True)  # stable: ties keep collection order
    return [it for g in ordered for it in g]


def pytest_xdist_auto_num_workers(config) -> int:
    """Workers for ``-n auto``: one per two cores, at least two, at most eight (a Blender render
    uses every core it gets; more workers than that only make them wait for each other)."""
    return max(2, min(8, (os.cpu_count() or 2) // 2))
