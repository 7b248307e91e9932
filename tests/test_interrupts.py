"""Ctrl-C at any moment of a run is one line and exit 130 (issue 29, item 7): the handlers are in
place before the heavy imports, and a Ctrl-C that a library swallows (pxr's module loader turns
it into a warning and carries on; NumPy's import into an ImportError) still stops the run.

Each case starts the command in its own session and sends SIGINT to its process group, as a
terminal's Ctrl-C does, at a random moment of its first two seconds. The moments start after the
Python interpreter's own start-up (measured here, as `python -c "import lfusd.cli"`): before that
no code of lfusd runs.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from support.scenes import write_box_stage

from lfusd.camera import RigSpec

pytestmark = [pytest.mark.render, pytest.mark.slow]
ROOT = Path(__file__).resolve().parents[1]
RUNS = 20
INTERRUPTED = "lfusd: interrupted; rerun the same command to resume"
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}


def _startup() -> float:
    t = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import lfusd.cli"], env=ENV, check=True)
    return time.perf_counter() - t


def _interrupt(argv: list, at: float) -> tuple[int, list[str]]:
    p = subprocess.Popen([sys.executable, "-m", "lfusd", *map(str, argv)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True, env=ENV, start_new_session=True)
    time.sleep(at)
    assert p.poll() is None, f"the command ended before {at:.2f} s: the case needs a longer run"
    os.killpg(p.pid, signal.SIGINT)
    _, err = p.communicate(timeout=120)
    # progress lines are the command's own output; everything else must be the one line
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("verifying frame") and " views, " not in ln]
    return p.returncode, lines


def _moments(seed: int) -> list[float]:
    first = min(_startup(), 1.0)
    rng = random.Random(seed)
    return sorted(rng.uniform(first, 2.0) for _ in range(RUNS))


def test_ctrl_c_in_the_first_two_seconds_of_render_video(tmp_path):
    stage = tmp_path / "scene.usda"
    write_box_stage(stage, [RigSpec(name="main", rows=1, cols=2, width=24, height=24, at=(0, -5, 1), look_at=(0, 0, 0.5))])
    bad = []
    for i, at in enumerate(_moments(29)):
        code, lines = _interrupt(["render-video", stage, "-o", tmp_path / f"out{i}", "--frames", "1-40", "--samples", "1",
                                  "--device", "cpu", "--quiet"], at)
        if code != 130 or lines != [INTERRUPTED]:
            bad.append(f"at {at:.2f} s: exit {code}, {lines[-3:]}")
    assert not bad, "\n".join(bad)


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    """A dataset whose verification takes several seconds (3 views at 128x128, 24 frames of motion)."""
    root = tmp_path_factory.mktemp("video")
    write_box_stage(root / "scene.usda", [RigSpec(name="main", rows=1, cols=3, width=128, height=128, at=(0, -5, 1), look_at=(0, 0, 0.5))])
    subprocess.run([sys.executable, "-m", "lfusd", "render-video", root / "scene.usda", "-o", root / "out", "--frames", "1-24",
                    "--samples", "1", "--device", "cpu", "--quiet"], env=ENV, check=True, capture_output=True)
    return root / "out"


def test_ctrl_c_in_the_first_two_seconds_of_verify(video):
    out = video  # verify only reads it
    bad = []
    for at in _moments(30):
        code, lines = _interrupt(["verify", out], at)
        if code != 130 or lines != [INTERRUPTED]:
            bad.append(f"at {at:.2f} s: exit {code}, {lines[-3:]}")
    assert not bad, "\n".join(bad)
