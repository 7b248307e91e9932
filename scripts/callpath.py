"""Count the module hops and climbs of one tiny `render_video` request (issue 39 item 21).

Runs lfusd.render_video on a 1x2-view, 16x16-pixel, 2-frame stage (1 sample) under
``sys.setprofile`` and follows every call from one lfusd function into another in the parent
process (the render workers are not traced). A *hop* is a call into another lfusd module; a
*climb* is a call into a module that is already further up the stack (a callback re-entering a
module that called down); a *callback* is a call of a closure whose defining function is up the
stack but is not the caller (``then=finish`` handed to ``_render`` and called back). Prints the modules passed through, the distinct climbs and callbacks (caller ->
callee), and how many of them re-enter lfusd/render/job.py.

    PYTHONPATH=$PWD .venv/bin/python scripts/callpath.py

(The certificate step is left out: traced, verify takes many minutes. That the render-video
command calls one library function is checked statically, tests/render/test_job_structure.py.)
"""

from __future__ import annotations

import sys
import tempfile
import threading
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


COMPREHENSIONS = ("<listcomp>", "<setcomp>", "<dictcomp>", "<genexpr>")


def _function(code) -> str:
    """The qualified name of the function a frame runs, a comprehension counting as its function's."""
    name = code.co_qualname
    while name.endswith(COMPREHENSIONS):
        name = name.rsplit(".<locals>", 1)[0]
    return name


def _module(frame) -> str | None:
    name = frame.f_globals.get("__name__", "")
    return name if name == "lfusd" or name.startswith("lfusd.") else None


class Tracer:
    """Distinct lfusd -> lfusd call edges, split into hops and climbs."""

    def __init__(self):
        self.modules: set[str] = set()
        self.hops: set[tuple[str, str]] = set()
        self.climbs: set[tuple[str, str]] = set()
        self.callbacks: set[tuple[str, str]] = set()
        self.lock = threading.Lock()

    def __call__(self, frame, event, arg):
        # a module body running on import is no call; a comprehension is part of its function
        if event != "call" or frame.f_code.co_name == "<module>" or frame.f_code.co_name in COMPREHENSIONS:
            return
        callee = _module(frame)
        if callee is None:
            return
        chain = []  # the lfusd frames up the stack, nearest first: (module, qualified name)
        f = frame.f_back
        while f is not None:
            m = _module(f)
            if m is not None and f.f_code.co_name != "<module>":
                chain.append((m, _function(f.f_code)))
            f = f.f_back
        if not chain:
            return
        caller, caller_fn = chain[0]
        name = _function(frame.f_code)
        with self.lock:
            self.modules.add(callee)
            # a function defined inside another one that is up the stack, called by something
            # below its definer: a closure handed down and called back up
            if "<locals>" in name:
                outer = name.rsplit(".<locals>", 1)[0]
                if (callee, outer) in chain[1:] and chain[0] != (callee, outer):
                    self.callbacks.add((f"{caller}.{caller_fn}", f"{callee}.{name}"))
            if caller == callee:
                return
            edge = (f"{caller}.{caller_fn}", f"{callee}.{name}")
            self.hops.add(edge)
            if any(m == callee for m, _ in chain[1:]):
                self.climbs.add(edge)


def main() -> int:
    sys.path.insert(0, str(ROOT / "tests"))
    from support.scenes import write_motion_stage

    from lfusd.camera import RigSpec
    from lfusd.render.job import render_video
    from lfusd.render.request import RenderRequest

    rig = RigSpec(name="main", rows=1, cols=2, width=16, height=16, baseline=0.1, at=(0.3, -5.0, 1.8), look_at=(0.0, 0.5, 0.6))
    with tempfile.TemporaryDirectory() as tmp:
        stage = Path(tmp) / "movers.usda"
        write_motion_stage(stage, rig, 2, (0.05, -0.03, 0.0))
        req = RenderRequest(stage=stage, out=Path(tmp) / "out", samples=1, device="cpu", quiet=True, workers=1)
        tracer = Tracer()
        threading.setprofile(tracer)
        sys.setprofile(tracer)
        try:
            render_video(req)
        finally:
            sys.setprofile(None)
            threading.setprofile(None)
    job = sorted(c for c in tracer.climbs if c[1].startswith("lfusd.render.job."))
    print(f"modules passed through: {len(tracer.modules)}")
    print(f"distinct hops (calls into another module): {len(tracer.hops)}")
    print(f"distinct climbs (calls into a module already up the stack): {len(tracer.climbs)}")
    print(f"climbs into lfusd/render/job.py: {len(job)}")
    print(f"closures called back up (defined in a function up the stack, called from below it): {len(tracer.callbacks)}")
    for a, b in sorted(tracer.climbs):
        print(f"  climb {a} -> {b}")
    for a, b in sorted(tracer.callbacks):
        print(f"  callback {a} -> {b}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
