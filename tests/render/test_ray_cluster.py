"""`render-video --executor ray` on a two-node Ray cluster (issue 14, item 5): units run on both
nodes, and killing a node mid-run loses at most its frame in flight.

Both nodes are separate `ray start --block` processes on this machine, each in its own session (so
its process group holds its raylet, workers and Blender processes), with 1 CPU each: a node runs
one unit at a time, so of the 4 units the second goes to the other node while the first renders,
whatever the timing. Each attempt of a unit records its node and frames (OUT/logs/*.ray.jsonl).
node_b's Blender workers pause after each frame (LFUSD_TEST_FRAME_DELAY), so the SIGKILL of its
process group, sent once its first frame is committed, lands mid-unit. Everything listens on
loopback only. Ray
resolves 127.0.0.1 to the machine's address unless RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0 (head,
driver) or, for the joining node, whose start refuses that setting, `resolve_ip_for_localhost` is
left out (the shim below). Teardown kills the nodes' process groups rather than `ray stop`, which
stops every Ray of this user on the machine (other people's included).
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil
import pytest
from support.processes import alive

from lfusd.camera import RigSpec
from lfusd.data import integrity
from lfusd.layout import RGB_EXR, frame_dir

pytestmark = [pytest.mark.render, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[2]
RAY = [sys.executable, "-c", "from ray.scripts.scripts import main; main()"]
# The joining node: `ray start --address=127.0.0.1:PORT` as is, except that the loopback address
# stays loopback (Ray would turn it into this machine's network address, where nothing listens).
RAY_JOIN = [sys.executable, "-c", "import ray._private.services as s; s.resolve_ip_for_localhost = lambda h: h\n"
            "from ray.scripts.scripts import main; main()"]
# 128x96: verify's motion checks need this much (tests/test_faults.py). Two views, --workers 2 and
# Ray's 10 frames per unit: 4 units (2 frame chunks x 2 views).
RIG = RigSpec(name="main", rows=1, cols=2, width=128, height=96, baseline=0.1, at=(0.3, -5.0, 1.8), look_at=(0.0, 0.5, 0.6))
FRAMES = 20
# node_b's Blender workers pause this long after each frame (lfusd.render.worker's test hook): a
# tiny frame takes a fraction of a second, and the kill must land between a unit's first and last.
FRAME_DELAY = 3.0
TIMEOUT = 240.0  # seconds for each wait; a loaded 2-core machine is slow, a hang still fails


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait(what: str, check, timeout: float = TIMEOUT, procs=(), every: float = 0.2):
    """Poll ``check()`` until it returns something truthy; fail if a process in ``procs`` ended."""
    end = time.time() + timeout
    while time.time() < end:
        value = check()
        if value:
            return value
        for p in procs:
            assert p.poll() is None, f"{p.args[-1] if p.args else p} ended with {p.returncode} while waiting for {what}"
        time.sleep(every)
    raise AssertionError(f"no {what} within {timeout:.0f} s")


def _tree(proc: subprocess.Popen) -> list[psutil.Process]:
    try:
        root = psutil.Process(proc.pid)
        return [root, *root.children(recursive=True)]
    except psutil.Error:
        return []


def _command(p: psutil.Process) -> str:
    try:
        return " ".join(p.cmdline())[:100]
    except psutil.Error:
        return f"pid {p.pid}"


class Cluster:
    """A head node and a second node, each a `ray start --block` in its own session."""

    def __init__(self, temp: Path):
        self.temp = temp
        self.port = _free_port()
        self.env = {
            **os.environ, "PYTHONPATH": str(ROOT), "RAY_USAGE_STATS_ENABLED": "0",
            # Token authentication, with a token of this cluster only (not ~/.ray/auth_token).
            "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": os.urandom(16).hex(),
            # A dead node is declared dead after a few seconds, not Ray's default half minute.
            "RAY_health_check_period_ms": "1000", "RAY_health_check_timeout_ms": "1000",
            "RAY_health_check_failure_threshold": "3",
        }
        self.nodes: dict[str, subprocess.Popen] = {}
        self.seen: list[psutil.Process] = []  # every process of the nodes seen so far
        self.run = 0  # start-up tries so far (each has its own temp folder and output files)

    def _start(self, name: str, argv: list[str], env: dict) -> None:
        ports = [f"--node-manager-port={_free_port()}", f"--object-manager-port={_free_port()}",
                 f"--dashboard-agent-listen-port={_free_port()}", f"--dashboard-agent-grpc-port={_free_port()}",
                 f"--metrics-export-port={_free_port()}", f"--runtime-env-agent-port={_free_port()}"]
        low = 30000 + _free_port() % 20000  # not Ray's default worker ports, which another Ray here may use
        self.nodes[name] = subprocess.Popen(
            [*argv, "--block", "--num-cpus=1", f"--resources={json.dumps({name: 1})}", "--disable-usage-stats",
             f"--temp-dir={self.temp / f'{name}{self.run}'}", "--object-store-memory=100000000",
             f"--min-worker-port={low}", f"--max-worker-port={low + 40}", *ports],
            env=env, start_new_session=True, stdout=open(self.temp / f"{name}{self.run}.out", "w"), stderr=subprocess.STDOUT)

    def start(self, tries: int = 3) -> None:
        """Start both nodes. Each port is picked free and then handed to Ray, so another process of a
        busy machine can take one in between (CI saw the head exit with 1): a node that ends while
        starting is started again, both nodes afresh on new ports, at most ``tries`` times. The
        test's subject (where units run, what a dead node loses) begins only after this."""
        for attempt in range(tries):
            try:
                self._start("node_a", [*RAY, "start", "--head", f"--port={self.port}", "--node-ip-address=127.0.0.1",
                                       "--include-dashboard=false"],
                            {**self.env, "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"})
                _wait("the head node", lambda: self._started("node_a"), procs=self.nodes.values())
                self._start("node_b", [*RAY_JOIN, "start", f"--address={self.address}"],
                            {**self.env, "LFUSD_TEST_FRAME_DELAY": str(FRAME_DELAY)})
                _wait("the second node", lambda: self._started("node_b"), procs=self.nodes.values())
                return
            except AssertionError as e:
                ended = [n for n, p in self.nodes.items() if p.poll() is not None]
                logs = {n: self._log(n)[-2000:] for n in self.nodes}
                if not ended or attempt == tries - 1:
                    raise AssertionError(f"{e}; the nodes' output: {logs}") from None
                logging.getLogger(__name__).warning("%s ended while starting (try %d): %s", ended, attempt + 1, logs)
                self.stop()
                self.nodes.clear()
                self.port = _free_port()
                self.run += 1

    @property
    def address(self) -> str:
        """The head node's address (its port changes when a start is tried again)."""
        return f"127.0.0.1:{self.port}"

    def _log(self, name: str) -> str:
        path = self.temp / f"{name}{self.run}.out"
        return path.read_text(errors="replace") if path.exists() else ""

    def _started(self, name: str) -> bool:
        """`ray start` says so once its raylet has registered with the cluster."""
        return "Ray runtime started" in self._log(name)

    def processes(self, name: str | None = None) -> list[psutil.Process]:
        procs = [p for n, node in self.nodes.items() if name in (None, n) for p in _tree(node)]
        self.seen.extend(p for p in procs if p not in self.seen)
        return procs

    def kill(self, name: str) -> None:
        """SIGKILL a node's whole process group: raylet, its Ray workers and their Blender processes."""
        procs = self.processes(name)
        os.killpg(self.nodes[name].pid, signal.SIGKILL)
        self.nodes[name].wait(30)
        _wait(f"{name}'s processes to end", lambda: not alive(procs), timeout=30)

    def stop(self) -> list[str]:
        """Kill both nodes' process groups (as `ray stop --force` would, but only these); the
        command lines of processes that outlived that (killed one by one)."""
        self.processes()
        for node in self.nodes.values():
            try:
                os.killpg(node.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            node.wait(30)
        end = time.time() + 15
        while self.leftovers() and time.time() < end:
            time.sleep(0.2)
        left = self.leftovers()
        for p in left:
            p.kill()
        return [_command(p) for p in left]

    def leftovers(self) -> list[psutil.Process]:
        """Processes of this cluster still running: those seen in its process groups, and any other
        with its token in the environment (inherited by every Ray, lfusd and Blender process of it)."""
        token = self.env["RAY_AUTH_TOKEN"]
        found = list(self.seen)
        for p in psutil.process_iter():
            try:
                if p.pid != os.getpid() and p not in found and p.environ().get("RAY_AUTH_TOKEN") == token:
                    found.append(p)
            except psutil.Error:
                pass
        return alive(found)


@pytest.fixture
def cluster():
    temp = Path(tempfile.mkdtemp(prefix="lfr", dir="/tmp"))  # short: Ray's socket paths are limited to 107 bytes
    c = Cluster(temp)
    try:
        c.start()
        yield c
    finally:
        left = c.stop()
        shutil.rmtree(temp, ignore_errors=True)
    assert not left, f"processes outlived their Ray node: {left}"


def _attempts(out: Path) -> dict[int, list[dict]]:
    """unit -> its Ray attempts, from OUT/logs/<rig>-unit<n>.ray.jsonl."""
    found = {}
    for path in sorted((out / "logs").glob("*.ray.jsonl")):
        lines = [json.loads(ln) for ln in path.read_text().splitlines() if ln.strip()]
        if lines:
            found[lines[0]["unit"]] = lines
    return found


def _complete(out: Path, frame: int, views: list[str]) -> bool:
    return all(integrity.view_complete(frame_dir(out, RIG.name, frame) / v) for v in views)


def test_units_spread_over_two_nodes_and_a_dead_node_loses_at_most_its_frame_in_flight(cluster, tmp_path):
    from support.scenes import write_motion_stage

    stage, out = tmp_path / "movers.usda", tmp_path / "out"
    write_motion_stage(stage, RIG, FRAMES, (0.05, -0.03, 0.0))
    t0 = time.time()
    lfusd = subprocess.Popen(
        [sys.executable, "-m", "lfusd.cli", "render-video", str(stage), "-o", str(out), "--executor", "ray", "--ray-address",
         cluster.address, "--workers", "2", "--samples", "1", "--device", "cpu", "--quiet"],
        env={**cluster.env, "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"}, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True, start_new_session=True)
    try:
        # Which unit runs on node_b: the one whose Ray worker (pid in its record) is node_b's process.
        def unit_on_b():
            pids_b = {p.pid for p in cluster.processes("node_b")}
            cluster.processes()  # remember the head's workers and Blender processes for teardown
            return next((a[0] for a in _attempts(out).values() if a[0]["pid"] in pids_b), None)

        first = _wait("a unit on node_b", unit_on_b, procs=[lfusd], every=0.05)
        frames, views = first["frames"], first["views"]
        assert len(frames) == 10 and len(views) == 1, first
        _wait("node_b's first committed frame", lambda: _complete(out, frames[0], views), procs=[lfusd], every=0.05)
        # The teardown's leftover check sees this cluster's Blender processes (by their environment).
        assert any("lfusd.render.worker" in _command(p) for p in cluster.leftovers())
        cluster.kill("node_b")
        t_kill = time.time() - t0
        # What node_b committed before it died, as the files stand now (no process of it is left).
        kept = [f for f in frames if _complete(out, f, views)]
        before = {(f, v): (p.stat().st_ino, p.stat().st_mtime_ns)
                  for f in kept for v in views for p in [frame_dir(out, RIG.name, f) / v / RGB_EXR]}
        stdout, stderr = lfusd.communicate(timeout=TIMEOUT)
    finally:
        if lfusd.poll() is None:
            os.killpg(lfusd.pid, signal.SIGKILL)
            lfusd.wait()
    assert lfusd.returncode == 0, stderr
    print(f"killed node_b at {t_kill:.1f} s, run done at {time.time() - t0:.1f} s; node_b had committed frames {kept}")

    attempts = _attempts(out)
    assert len(attempts) == 4, attempts
    nodes = {a[0]["node_id"] for a in attempts.values()}
    assert len(nodes) == 2, f"all units ran on one node: {attempts}"  # spread over both nodes
    # node_b's unit was retried once, on the head (the other node id), with exactly the frames it
    # had not committed: what it committed is kept, and of what is rendered again only the frame in
    # flight had been started (a worker renders its frames in order, so kept is a prefix).
    retried = attempts[first["unit"]]
    print("attempts:", json.dumps(attempts))
    assert kept and kept == frames[:len(kept)] and len(kept) < len(frames), kept
    assert all(len(a) == 1 for u, a in attempts.items() if u != first["unit"]), attempts  # no other unit ran twice
    assert len(retried) == 2 and retried[1]["node_id"] != first["node_id"], retried
    assert retried[1]["frames"] == [f for f in frames if f not in kept], retried
    after = {(f, v): (p.stat().st_ino, p.stat().st_mtime_ns)
             for f in kept for v in views for p in [frame_dir(out, RIG.name, f) / v / RGB_EXR]}
    assert after == before, "a view committed before the node died was written again"
    # Blender's own account (the retry's log replaces the dead attempt's): the frames it rendered.
    log = (out / "logs" / f"{RIG.name}-unit{first['unit']:04d}.log").read_text()
    rendered = sorted({int(ln.split()[2]) for ln in log.splitlines() if ln.startswith("lfusd: frame ")})
    assert rendered == retried[1]["frames"], rendered
    assert all(_complete(out, f, [f"00_0{c}" for c in range(2)]) for f in frames)

    verify = subprocess.run([sys.executable, "-m", "lfusd.cli", "verify", str(out)], env=cluster.env,
                            capture_output=True, text=True, timeout=TIMEOUT)
    assert verify.returncode == 0, verify.stdout + verify.stderr
    compared = int(verify.stdout.split("(")[-1].split(" px")[0])
    print(verify.stdout.splitlines()[-1])
    assert compared > 0
