"""Executors and the worker protocol, with a stand-in worker (no Blender)."""

from __future__ import annotations

import json
import logging
import sys

from lfusd.render import executors
from lfusd.render.plan import WorkUnit

STAND_IN = """
import json, sys
job = json.loads(sys.stdin.read())
print("Blender chatter")
print("LFUSD " + json.dumps({"event": "ready", "device": "cpu"}))
print("LFUSD " + json.dumps({"event": "warning", "message": "material Foo has no surface; rendered grey"}))
print("LFUSD " + json.dumps({"event": "warning", "message": "unit " + str(job["unit"]) + " of rig " + job["rig"]}))
"""


def unit(**kw) -> WorkUnit:
    base = dict(unit=7, rig="main", stage="/s.usda", cameras={}, frames=[1], width=4, height=4, samples=1, device="cpu",
                instances={}, threads=1, motion=False, has_dome=False, stage_range=[1, 1])
    return WorkUnit(**{**base, **kw})


def test_worker_warnings_reach_the_parent_log(tmp_path, monkeypatch, caplog):
    monkeypatch.setattr(executors, "WORKER", [sys.executable, "-c", STAND_IN])
    with caplog.at_level(logging.WARNING, logger="lfusd.render.executors"):
        assert executors.run_unit(unit(), tmp_path) == "cpu"
    messages = [r.getMessage() for r in caplog.records]
    assert any("material Foo has no surface" in m for m in messages), messages
    assert any("unit 7 of rig main" in m for m in messages), messages  # the job crossed as JSON, typed
    assert all("chatter" not in m for m in messages)


def test_work_unit_round_trips_through_json():
    u = unit(cameras={"00_01": "/Rigs/main/cam_00_01"}, scratch="/tmp/x", threads=3)
    assert WorkUnit.from_json(json.loads(json.dumps(u.to_json()))) == u


def test_a_finished_pool_does_not_stop_later_workers(tmp_path, monkeypatch, caplog):
    """Stopping one pool kills only workers started while it stops, not those of a later run in
    the same process (a library user renders twice in one session)."""
    from types import SimpleNamespace

    monkeypatch.setattr(executors, "WORKER", [sys.executable, "-c", STAND_IN])
    req = SimpleNamespace(workers=1, out=tmp_path / "a")
    assert executors.run_local([], req, SimpleNamespace(advance=lambda n: None)) == "cpu"
    with caplog.at_level(logging.WARNING, logger="lfusd.render.executors"):
        assert executors.run_unit(unit(), tmp_path / "b") == "cpu"
    assert any("material Foo has no surface" in r.getMessage() for r in caplog.records)


def test_a_retried_ray_unit_renders_only_its_incomplete_frames(tmp_path, monkeypatch):
    """Ray runs a unit again when its node died: frames whose views of the unit are all complete
    are not rendered again (a node loss costs at most its frame in flight), and every attempt
    records its node and frames in OUT/logs/<rig>-unit<n>.ray.jsonl."""
    from types import SimpleNamespace

    import ray

    from lfusd.data import integrity
    from lfusd.layout import frame_dir

    def complete(frame, key):
        d = frame_dir(tmp_path, "main", frame) / key
        d.mkdir(parents=True)
        for name in integrity.RENDER_FILES:
            (d / name).write_bytes(b"rendered")
        integrity.record_render(d)

    complete(1, "00_00"), complete(1, "00_01"), complete(2, "00_00")  # frame 2 lacks view 00_01
    rendered = []
    monkeypatch.setattr(executors, "run_unit", lambda u, out: rendered.append(u.frames) or "cuda")
    monkeypatch.setattr(ray, "get_runtime_context", lambda: SimpleNamespace(get_node_id=lambda: "node-1"))
    u = unit(cameras={"00_00": "/Rigs/main/cam_00_00", "00_01": "/Rigs/main/cam_00_01"}, frames=[1, 2, 3])
    assert executors._ray_unit(u, str(tmp_path)) == "cuda"
    assert rendered == [[2, 3]]
    complete(2, "00_01"), complete(3, "00_00"), complete(3, "00_01")
    assert executors._ray_unit(u, str(tmp_path)) is None  # nothing left: no Blender started
    assert rendered == [[2, 3]]
    lines = [json.loads(ln) for ln in (tmp_path / "logs" / "main-unit0007.ray.jsonl").read_text().splitlines()]
    assert [(a["node_id"], a["frames"]) for a in lines] == [("node-1", [2, 3]), ("node-1", [])]


def test_ray_shutdown_runs_to_its_end_after_a_ctrl_c_latched_during_ray_init(tmp_path, monkeypatch):
    """A Ctrl-C during ray.init is latched by the CLI, which raises it again at every later import
    (lfusd.cli._RaiseAtImport). ray.shutdown imports: raised there, it cut the clean-up short, so
    Ray's processes were never killed and its agents ran on, orphaned (issue 26). The clean-up must
    run to its end, kill the processes ray.init started, and the latched Ctrl-C still stop the run."""
    import subprocess
    from types import SimpleNamespace

    import pytest

    from lfusd import cli

    (tmp_path / "ray_shutdown_helper_mod.py").write_text("X = 1\n")  # a module ray.shutdown has not imported yet
    monkeypatch.syspath_prepend(str(tmp_path))
    steps = []

    def shutdown():
        steps.append("shutdown started")
        __import__("ray_shutdown_helper_mod")
        steps.append("shutdown finished")

    fake_ray = SimpleNamespace(cancel=lambda ref, force: steps.append("cancelled"), shutdown=shutdown)
    head = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])  # stands for a server ray.init started
    monkeypatch.setattr(cli._Interrupt, "pending", True)  # the Ctrl-C that interrupted ray.init
    monkeypatch.setattr(sys, "meta_path", [cli._RaiseAtImport, *sys.meta_path])
    try:
        executors._stop_ray(fake_ray, {"ref": None}, shutdown=True, main=True, ray_processes={head.pid})
        assert head.wait(timeout=10) == -9  # killed by the clean-up, not left running
    finally:
        if head.poll() is None:
            head.kill()
    # a local instance's tasks end with it: cancelling them raced inside Ray's driver (a crash, exit 1)
    assert steps == ["shutdown started", "shutdown finished"]
    with pytest.raises(KeyboardInterrupt):  # the latch holds after the clean-up: the run still stops
        __import__("ray_shutdown_helper_mod_2")


def test_tasks_on_a_joined_cluster_are_cancelled_and_the_cluster_is_left_running():
    """--ray-address: lfusd cancels its own tasks there and shuts nothing down (the cluster is the user's)."""
    from types import SimpleNamespace

    steps = []
    fake_ray = SimpleNamespace(cancel=lambda ref, force: steps.append(("cancelled", ref, force)),
                               shutdown=lambda: steps.append("shutdown"))
    executors._stop_ray(fake_ray, {"a": None, "b": None}, shutdown=False, main=True)
    assert steps == [("cancelled", "a", True), ("cancelled", "b", True)]


def test_stops_held_during_a_clean_up_are_delivered_after_it():
    import signal

    from lfusd import processes

    got = []
    previous = signal.signal(signal.SIGTERM, lambda s, f: got.append(s))
    try:
        with processes.hold_stops():
            assert processes.holding()
            signal.raise_signal(signal.SIGTERM)
            signal.raise_signal(signal.SIGTERM)
            assert got == []  # held, not lost
        assert got == [signal.SIGTERM]  # once, to the handler it was meant for
        assert not processes.holding()
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_a_ctrl_c_while_the_local_ray_starts_is_held_until_it_has_started(monkeypatch):
    """Raised inside ray.init, a Ctrl-C cut the start short or landed in Python's at-fork hooks of
    Ray's process starts (printed as a traceback there, and lost); held, it stops the run once the
    instance is up, and the clean-up shuts that instance down."""
    import signal
    from types import SimpleNamespace

    import pytest
    import ray

    steps = []

    def start(workers):
        signal.raise_signal(signal.SIGINT)  # the Ctrl-C, in the middle of the start
        steps.append("started")

    monkeypatch.setattr(executors, "start_local_ray", start)
    monkeypatch.setattr(ray, "shutdown", lambda: steps.append("shut down"))
    req = SimpleNamespace(ray_address=None, workers=1, out="/nonexistent")
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            executors.run_ray([], req, SimpleNamespace(advance=lambda n: None))
    finally:
        signal.signal(signal.SIGINT, previous)
    assert steps == ["started", "shut down"]
