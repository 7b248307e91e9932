"""Cost of `lfusd verify` per view: an older verifier (default: main's) against this tree's, side by side.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_verify.py [--dataset DIR] [--before main]
        [--stage stages/street_dynamic_00.usda] [--rig rig_00] [--grid 1x2] [--frames 68-70] [--resolution 96x96]
        [--check 69-69] [--views '1,1;0,0'] [--repeat 2] [--marginal]

Without ``--dataset``, renders a small dataset of the default scene first (``lfusd render-video``, 1
sample, CPU) into a temporary folder. The older verifier is ``lfusd/truth/verify.py`` as committed at
``--before`` (``git show REV:lfusd/truth/verify.py``), loaded as a module of this tree's
``lfusd.truth`` package: its relative imports resolve to this tree's modules, so the two differ only in
verify.py itself and its compiled kernels (``_verify_numba.py`` at ``--before``, loaded beside this
tree's when they differ; numba compiles them once, cached in a folder named by their content). Both verify the same frames and views in one process, interleaved (before, after,
before, ...), each ``--repeat`` times; the best of each is reported.

Prints per verifier: core-seconds per view (process CPU time: every thread of Open3D's ray casts
counted), wall seconds per view, core-seconds per 1024x1024 view extrapolated linearly in pixels
(verify's work is per pixel: a cast per pixel, per corner and per neighbour frame; the stage's
meshes, read once per frame for all views, are counted in too, so small views overstate it), the
ratio to this tree's verifier, each verdict and its failure lines. Older revisions check less
(main's verifier predates issue 37's checks of normals, validity, mixed and bias), so the ratio is
the cost of the whole verifier, not of the same work. The issue-37 budget: at most 1 core-s per
1024x1024 view.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import revisions  # noqa: E402  (benchmarks/revisions.py, beside this script)


def load_verifier(rev: str):
    """lfusd/truth/verify.py at git revision ``rev``, as a module inside this tree's lfusd.truth; with
    its own compiled kernels (``_verify_numba.py`` at ``rev``) where they differ from this tree's."""
    src = revisions.source_at(rev, "lfusd/truth/verify.py")
    kernels = revisions.source_at(rev, "lfusd/truth/_verify_numba.py")
    if kernels != (ROOT / "lfusd" / "truth" / "_verify_numba.py").read_text():
        mod = revisions.module_at(rev, "lfusd.truth", "_verify_numba", kernels)
        src = src.replace("from . import _verify_numba as _numba", f"from . import {mod.__name__.rsplit('.', 1)[1]} as _numba")
    return revisions.module_at(rev, "lfusd.truth", "verify", src)


def render(stage: str, rig: str, frames: str, resolution: str, out: Path) -> None:
    cmd = [sys.executable, "-m", "lfusd", "render-video", stage, "-o", str(out), "--rig", rig, "--frames", frames,
           "--resolution", resolution, "--samples", "1", "--device", "cpu", "--quiet"]
    subprocess.run(cmd, check=True, env={**os.environ, "PYTHONPATH": str(ROOT)})


def run(mod, path: Path, frames, views):
    from lfusd import Dataset

    ds = Dataset(path)
    c0, w0 = time.process_time(), time.perf_counter()
    rep = mod.verify_dataset(ds, frames=frames, views=views)
    return time.process_time() - c0, time.perf_counter() - w0, rep


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--dataset", type=Path, help="a rendered dataset (default: render one)")
    p.add_argument("--before", default="main", help="git revisions of older verifiers, comma-separated (default main)")
    p.add_argument("--stage", default=str(ROOT / "stages" / "street_dynamic_00.usda"))
    p.add_argument("--rig", default="rig_00")
    p.add_argument("--grid", default=None, help="ROWSxCOLS: render a rig of this shape at --rig's pose instead (bench_reference.py's "
                   "reference rig), e.g. 1x2 with --resolution 1024x1024 --frames 69-71: issue 37's acceptance case")
    p.add_argument("--frames", default="68-70", help="rendered frames A-B; the middle ones are verified (both neighbours)")
    p.add_argument("--resolution", default="96x96")
    p.add_argument("--check", default=None, help="frames to verify A-B (default: every rendered frame but the first and last)")
    p.add_argument("--views", default=None, help="views to verify, e.g. '1,1;0,0' (default: all)")
    p.add_argument("--repeat", type=int, default=2)
    p.add_argument("--marginal", action="store_true", help="also time each verifier on the first view alone: the cost of "
                   "the other views over it is the per-pixel work (the stage read and meshes, once per run and frame, left out), "
                   "extrapolated to 1024x1024 without the fixed costs that small views overstate")
    a = p.parse_args()

    from lfusd.truth import verify as after

    mods = [(f"before ({rev})", load_verifier(rev)) for rev in a.before.split(",")] + [("after (this tree)", after)]
    tmp = None
    path = a.dataset
    if path is None:
        tmp = tempfile.TemporaryDirectory(prefix="bench_verify_")
        path = Path(tmp.name) / "ds"
        stage, rig = a.stage, a.rig
        if a.grid:
            sys.path.insert(0, str(ROOT / "benchmarks"))
            from bench_reference import reference_layer

            stage, rig = str(Path(tmp.name) / "reference.usda"), "reference"
            reference_layer(Path(a.stage).resolve(), a.rig, Path(stage), tuple(int(x) for x in a.grid.split("x")),
                            tuple(int(x) for x in a.resolution.split("x")))
        render(stage, rig, a.frames, a.resolution, path)
    from lfusd import Dataset

    ds = Dataset(path)
    frames = ds.frames[1:-1] if len(ds.frames) > 2 else ds.frames
    if a.check:
        lo, hi = (int(x) for x in a.check.split("-"))
        frames = [f for f in ds.frames if lo <= f <= hi]
    views = [tuple(int(x) for x in v.split(",")) for v in a.views.split(";")] if a.views else list(ds.views)
    H, W = ds.read(frames[0], views[0], "depth").shape[:2]
    n = len(frames) * len(views)
    best = {name: (float("inf"), float("inf")) for name, _ in mods}
    reports = {}
    every: dict[str, list[float]] = {name: [] for name, _ in mods}  # each repeat's core-s (the spread)
    for _ in range(a.repeat):
        for name, mod in mods:
            cpu, wall, rep = run(mod, path, frames, views)
            best[name] = (min(best[name][0], cpu), min(best[name][1], wall))
            every[name].append(cpu)
            reports[name] = rep
    scale = 1024 * 1024 / (H * W)
    after_name = mods[-1][0]
    print(f"dataset {path}: {W}x{H}, frames {frames[0]}-{frames[-1]}, {len(views)} views: {n} views verified, best of {a.repeat}")
    print(f"{'verifier':<28}{'core-s/view':>12}{'wall-s/view':>12}{'core-s/1024^2 view':>20}{'x after':>9}  ok  failures")
    for name, _ in mods:
        cpu, wall = best[name]
        print(f"{name:<28}{cpu / n:>12.3f}{wall / n:>12.3f}{cpu / n * scale:>20.2f}{cpu / best[after_name][0]:>9.2f}  "
              f"{str(reports[name].ok):<5} {len(reports[name].failures())}")
    if a.marginal and len(views) > 1:
        one = {name: float("inf") for name, _ in mods}
        ones: dict[str, list[float]] = {name: [] for name, _ in mods}
        for _ in range(a.repeat):
            for name, mod in mods:
                cpu1 = run(mod, path, frames, views[:1])[0]
                one[name] = min(one[name], cpu1)
                ones[name].append(cpu1)
        m = len(frames) * (len(views) - 1)
        print(f"marginal: the {len(views) - 1} view(s) after the first, per view (fixed costs out)")
        print(f"{'verifier':<28}{'core-s/view':>12}{'core-s/1024^2 view':>20}{'x after':>9}  spread/1024^2 view (repeat by repeat)")
        marg = {name: (best[name][0] - one[name]) / m for name, _ in mods}
        for name, _ in mods:
            each = [(x - y) / m * scale for x, y in zip(every[name], ones[name])]
            print(f"{name:<28}{marg[name]:>12.3f}{marg[name] * scale:>20.2f}{marg[name] / marg[after_name]:>9.2f}  "
                  f"{min(each):.2f}-{max(each):.2f}")
    for name, _ in mods:
        for line in reports[name].failures()[:5]:
            print(f"  {name}: {line}")
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
