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
    u = unit(cameras={"00_01": "/Rigs/main/cam_00_01"}, scratch="/tmp/x", seed=3)
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
