"""The CPU account of a run: process CPU seconds per phase, in every lfusd process (issue 28).

Each process keeps its own totals; :func:`phase` blocks nest, and a phase is charged only its own
seconds (a nested phase's are taken off the one around it). Process CPU time counts every thread of
the process, so the thread pools of numba and Open3D are charged to the phase that ran them.
Nothing is written unless the environment names a folder in :data:`ENV` (the benchmarks set it):
then :func:`flush` writes this process's totals there as ``cpu-<pid>.json``, read back by
:func:`collect`. Users' datasets never hold it. No pxr, bpy or torch.
"""

from __future__ import annotations

import contextlib
import json
import os
import time
from pathlib import Path

ENV = "LFUSD_CPU_ACCOUNT"

_TOTALS: dict[str, float] = {}
_COUNTS: dict[str, int] = {}  # blocks per phase (visibility: one per direction of a view's motion)
_STACK: list[list] = []  # [name, start, seconds of nested phases]


@contextlib.contextmanager
def phase(name: str):
    """Charge the process CPU time spent inside the block to ``name`` (less that of nested phases)."""
    _STACK.append([name, time.process_time(), 0.0])
    try:
        yield
    finally:
        name, start, nested = _STACK.pop()
        spent = time.process_time() - start
        _TOTALS[name] = _TOTALS.get(name, 0.0) + spent - nested
        _COUNTS[name] = _COUNTS.get(name, 0) + 1
        if _STACK:
            _STACK[-1][2] += spent


def add(name: str, seconds: float) -> None:
    """Charge ``seconds`` measured elsewhere (the Blender worker's render-call split) to ``name``."""
    _TOTALS[name] = _TOTALS.get(name, 0.0) + seconds
    if _STACK:
        _STACK[-1][2] += seconds


def startup() -> None:
    """Charge all of this process's CPU time so far to "startup" (imports, a stage's import into
    Blender, planning, loading or compiling the numba kernels, whatever phase ran them): a cost per
    process, not per view. Call it once, where the per-view work begins."""
    _TOTALS.clear()
    _COUNTS.clear()
    _TOTALS["startup"] = time.process_time()


def totals() -> dict[str, float]:
    """This process's seconds per phase so far."""
    return dict(_TOTALS)


def flush(role: str) -> None:
    """Write this process's totals (and its whole CPU time so far) to the folder :data:`ENV` names, if any."""
    folder = os.environ.get(ENV)
    if not folder:
        return
    record = {"pid": os.getpid(), "role": role, "process": time.process_time(), "phases": _TOTALS, "counts": _COUNTS}
    path = Path(folder) / f"cpu-{os.getpid()}.json"
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(record))
    os.replace(tmp, path)


def collect(folder: str | Path) -> list[dict]:
    """Every process's last record in ``folder`` (see :func:`flush`)."""
    return [json.loads(p.read_text()) for p in sorted(Path(folder).glob("cpu-*.json"))]
