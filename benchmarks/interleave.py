"""Interleaved timing shared by the benchmarks that compare configurations side by side in one run.

Round r runs the configurations rotated by r (``rounds``): none is always the first, cold run, and a
machine that grows busier slows every configuration alike. ``table`` reports per configuration the best
time, its ratio to the base's best and the median of the per-round ratios (robust to one slow round).
"""

from __future__ import annotations

import statistics


def rounds(names: list[str], repeat: int):
    """(round, the configurations in this round's order) for ``repeat`` rounds, each starting one later."""
    names = list(names)
    for r in range(repeat):
        k = r % len(names)
        yield r, names[k:] + names[:k]


def table(times: dict[str, list[float]], base: str) -> dict[str, tuple[float, float, float]]:
    """{name: (best, best / base's best, median over rounds of time / base's time in that round)}."""
    out = {}
    for name, ts in times.items():
        ratios = [a / b for a, b in zip(ts, times[base])]
        out[name] = (min(ts), min(ts) / min(times[base]), statistics.median(ratios))
    return out
