"""Wall time of `make test` (``pytest -n auto --dist loadgroup``) under two orders of handing out the
xdist groups, side by side, from the measured time of every test of one real run:

- xdist's own order (``--loadscope-reorder``, its default): groups with the most tests first;
- tests/support/markers.py's order (:func:`longest_groups_first`): groups by their tests' markers,
  expected longest first.

    # once, the full suite with per-test times (setup and teardown included: junit's default):
    .venv/bin/python -m pytest -q -n auto --dist loadgroup --junitxml=/tmp/suite.xml
    .venv/bin/python benchmarks/bench_test_schedule.py /tmp/suite.xml [--workers 2]

A simulation, not a second run: xdist's loadgroup scheduler replayed (each worker starts with one
group, and is given the next group in the queue whenever two or fewer of its tests are left, as
xdist.scheduler.loadscope does) with each test taking its measured time. A module fixture's time
lands on the test that first used it in that run, so a group's total is right and is what the order
moves. Prints the simulated wall time of both orders, their ratio, the lower bound (the longest
group, or the total over the workers) and the last groups each order starts.
"""

from __future__ import annotations

import argparse
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))


def _collect() -> list[tuple[str, str, float]]:
    """(nodeid, group, marker cost) of every test in collection order, as `make test` collects them."""
    from support import markers

    rows: list = []

    class Grab:
        @pytest.hookimpl(trylast=True)
        def pytest_collection_modifyitems(self, items):
            rows.extend((it.nodeid, markers._group_name(it), markers.group_cost([it])) for it in items)

    code = pytest.main(["--collect-only", "-q", "-n", "0", "-p", "no:cacheprovider", str(ROOT / "tests")], plugins=[Grab()])
    if code != 0:
        raise SystemExit(f"collection failed (exit {code})")
    return rows


def _junit_times(path: Path) -> dict[str, float]:
    """nodeid -> seconds, from a junit XML (classname 'tests.render.test_x' or with a class; name with params)."""
    out: dict[str, float] = {}
    for case in ET.parse(path).getroot().iter("testcase"):
        parts = case.get("classname", "").split(".")
        # the module is the longest prefix that is a file under the repository
        for i in range(len(parts), 0, -1):
            f = "/".join(parts[:i]) + ".py"
            if (ROOT / f).is_file():
                name = case.get("name", "")
                name = name.rsplit("@", 1)[0] if "@" in name else name  # loadgroup's "@group" suffix
                nodeid = "::".join([f, *parts[i:], name])
                out[nodeid] = out.get(nodeid, 0.0) + float(case.get("time", 0.0))
                break
    return out


def simulate(groups: list[tuple[str, list[float]]], workers: int) -> tuple[float, list[str]]:
    """Wall time of xdist's loadscope scheduler handing out ``groups`` (name, test seconds) in order,
    and the names of the groups in the order they were started."""
    queue = list(groups)
    pending: list[list[float]] = [[] for _ in range(workers)]
    clock = [0.0] * workers
    started: list[str] = []

    def assign(w: int) -> None:
        name, tests = queue.pop(0)
        started.append(name)
        pending[w].extend(tests)

    for w in range(workers):
        if queue:
            assign(w)
    for w in range(workers):  # "at least two work units if possible"
        if queue and len(pending[w]) <= 2:
            assign(w)
    while any(pending):
        w = min((w for w in range(workers) if pending[w]), key=lambda w: clock[w] + pending[w][0])
        clock[w] += pending[w].pop(0)
        if queue and len(pending[w]) <= 2:  # else, with the queue empty, xdist shuts the worker down
            assign(w)
    return max(clock), started


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("junit", type=Path, help="junit XML of one full run (pytest --junitxml)")
    ap.add_argument("--workers", type=int, default=2, help="xdist workers (make test on 2 cores: 2)")
    args = ap.parse_args()
    times = _junit_times(args.junit)
    rows = _collect()
    missing = [n for n, _, _ in rows if n not in times]
    groups: dict[str, list] = {}
    for nodeid, group, cost in rows:
        groups.setdefault(group, []).append((times.get(nodeid, 0.0), cost))
    named = [(g, [t for t, _ in tests]) for g, tests in groups.items()]
    xdist_order = sorted(named, key=lambda g: -len(g[1]))  # xdist's --loadscope-reorder (stable)
    ours = [g for _, g in sorted(((sum(c for _, c in groups[g[0]]), g) for g in named), key=lambda x: -x[0])]
    total = sum(sum(t) for _, t in named)
    longest = max(named, key=lambda g: sum(g[1]))
    a, start_a = simulate(xdist_order, args.workers)
    b, start_b = simulate(ours, args.workers)
    print(f"{len(rows)} tests in {len(named)} groups, {total:.0f} s of tests; {len(missing)} collected tests without a time in the XML")
    print(f"lower bound with {args.workers} workers: {max(total / args.workers, sum(longest[1])):.0f} s "
          f"(longest group {longest[0].replace(str(ROOT) + '/', '')}: {sum(longest[1]):.0f} s)")
    print(f"{'order':<36}{'simulated wall s':>18}")
    print(f"{'xdist (most tests first)':<36}{a:>18.0f}")
    print(f"{'markers.longest_groups_first':<36}{b:>18.0f}")
    print(f"ratio xdist / longest-first: {a / b:.3f}  (saves {a - b:.0f} s)")
    for label, started in (("xdist", start_a), ("longest-first", start_b)):
        last = [f"{g.replace(str(ROOT) + '/', '')} ({sum(dict(named)[g]):.0f} s)" for g in started[-5:]]
        print(f"last groups started, {label}: {', '.join(last)}")


if __name__ == "__main__":
    main()
