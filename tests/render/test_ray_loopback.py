"""The Ray instance lfusd starts (``--executor ray`` without ``--ray-address``) listens on
loopback only, and lfusd never recommends disabling Ray's authentication (issue 29, item 4)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[2]

# Ray imported first, as a library user's program would: lfusd must still keep it on loopback.
PROBE = """
import json, logging, psutil, ray
from lfusd.cli import configure_logging
from lfusd.render.executors import start_local_ray
configure_logging()
start_local_ray(1)
listening = set()
for p in psutil.Process().children(recursive=True):
    try:
        listening |= {(p.name(), c.laddr.ip) for c in p.net_connections(kind="inet") if c.status == psutil.CONN_LISTEN}
    except psutil.Error:
        pass
print("LISTEN " + json.dumps(sorted(listening)), flush=True)
ray.shutdown()
"""


def _probe(**env) -> tuple[list, str]:
    env = {**{k: v for k, v in os.environ.items() if not k.startswith("RAY_")}, "PYTHONPATH": str(ROOT), **env}
    r = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, env=env, timeout=240)
    assert r.returncode == 0, r.stderr[-2000:]
    line = next(ln for ln in r.stdout.splitlines() if ln.startswith("LISTEN "))
    return json.loads(line[7:]), r.stderr


@pytest.mark.parametrize("auth", ["default", "disabled"])
def test_the_local_ray_listens_on_loopback_only(auth):
    listening, err = _probe(**({"RAY_AUTH_MODE": "disabled"} if auth == "disabled" else {}))
    names = {name for name, _ in listening}
    assert {"gcs_server", "raylet"} <= names, listening  # Ray's servers were seen
    assert all(ip in ("127.0.0.1", "::1", "::ffff:127.0.0.1") for _, ip in listening), listening
    assert "RAY_AUTH_MODE=disabled to opt out" not in err  # Ray's advice, hidden
    said = [ln for ln in err.splitlines() if "authentication is disabled" in ln]
    if auth == "disabled":
        assert said == [ln for ln in said if ln.startswith("lfusd: warning: ")] and len(said) == 1, err
    else:
        assert not said, err
