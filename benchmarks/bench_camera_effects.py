"""The extra cost of each camera effect of `lfusd render-video` (issue 40), side by side in one run.

    .venv/bin/python benchmarks/bench_camera_effects.py [--template room] [--grid 2x2] [--resolution 96x72]
        [--frames 3] [--samples 16] [--repeat 2] [--configs "none,lens,lens + fstop 2.8"]

Generates one dynamic scene (lfusd.author.scenes.generate), then renders it with `lfusd render-video`
(one worker, CPU) once per configuration: none, --shutter 0.5, --fstop 2.8 --focus 3, --materials,
--iso 800, --lens (OSL camera through Brown-Conrady distortion, and the NumPy route of the motion keys
it takes), --lens with --fstop 2.8 --focus 3 (the OSL camera as the thin lens), all but the lens, and
all of them, interleaved round by round (benchmarks/interleave.py), each round starting
one configuration later, so that a busy machine and a cold first render slow all alike. Prints per configuration the best wall seconds and process-tree CPU
seconds of the render, their ratios to `none`, and the median of the per-round wall ratios; then the
cost of reading `rgb_noisy` (the sensor model runs on read) against reading `rgb`, per view (with
`iso 800` among the configurations). ``--configs``: only these configurations (comma-separated names;
`none` is always rendered, as the reference).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, os.path.dirname(__file__))

from interleave import rounds, table  # noqa: E402  (benchmarks/, beside this script)

LENS = "-0.15,0.02,0.002,-0.002,0"  # k1, k2, p1, p2, k3: a moderate barrel with some decentring
CONFIGS = {
    "none": [],
    "shutter 0.5": ["--shutter", "0.5"],
    "fstop 2.8": ["--fstop", "2.8", "--focus", "3"],
    "materials": ["--materials"],
    "iso 800": ["--iso", "800"],
    "lens": ["--lens", LENS],
    "all": ["--shutter", "0.5", "--fstop", "2.8", "--focus", "3", "--materials", "--iso", "800"],
    "lens + fstop 2.8": ["--lens", LENS, "--fstop", "2.8", "--focus", "3"],
    "all with lens": ["--shutter", "0.5", "--fstop", "2.8", "--focus", "3", "--materials", "--iso", "800", "--lens", LENS],
}


def _children_cpu() -> float:
    t = os.times()
    return t.children_user + t.children_system + t.user + t.system


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--template", default="room")
    ap.add_argument("--grid", default="2x2")
    ap.add_argument("--resolution", default="96x72")
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--configs", default=None, help="comma-separated configuration names (default: all)")
    args = ap.parse_args()
    names = list(CONFIGS) if args.configs is None else ["none", *(n.strip() for n in args.configs.split(",") if n.strip() != "none")]
    unknown = [n for n in names if n not in CONFIGS]
    if unknown:
        ap.error(f"unknown configurations {unknown}; use some of {', '.join(CONFIGS)}")
    import numpy as np

    from lfusd import Dataset
    from lfusd.author.scenes import generate
    from lfusd.cli import main as lfusd

    rows, cols = (int(x) for x in args.grid.split("x"))
    w, h = (int(x) for x in args.resolution.split("x"))
    tmp = Path(tempfile.mkdtemp(prefix="lfusd_bench_effects"))
    try:
        stage = tmp / "scene.usda"
        generate(args.template, stage, 0, frames=args.frames, rigs=1, grid=(rows, cols), resolution=(w, h), dynamic=True)
        wall: dict[str, list[float]] = {k: [] for k in names}
        cpu: dict[str, list[float]] = {k: [] for k in names}
        for r, order in rounds(names, args.repeat):
            for name in order:
                extra = CONFIGS[name]
                out = tmp / f"out_{r}_{name.replace(' ', '_')}"
                c0, t0 = _children_cpu(), time.perf_counter()
                code = lfusd(["render-video", str(stage), "-o", str(out), "--samples", str(args.samples), "--device", "cpu",
                              "--quiet", "--rig", "all", *extra])
                wall[name].append(time.perf_counter() - t0)
                cpu[name].append(_children_cpu() - c0)
                if code != 0:
                    print(f"{name}: render-video exited {code}")
                    return 1
        views = rows * cols * args.frames
        print(f"{args.template}, {rows}x{cols} views of {w}x{h}, {args.frames} frames ({views} views), {args.samples} samples, "
              f"best of {args.repeat} interleaved rounds")
        print(f"{'effect':<20} {'wall s':>8} {'x none':>7} {'median x':>9} {'cpu s':>8} {'x none':>7}")
        walls, cpus = table(wall, "none"), table(cpu, "none")
        for name in names:
            best, ratio, median = walls[name]
            print(f"{name:<20} {best:8.2f} {ratio:7.3f} {median:9.3f} {cpus[name][0]:8.2f} {cpus[name][1]:7.3f}")
        if "iso 800" not in names:
            return 0
        ds = Dataset(tmp / "out_0_iso_800")
        frame, view = ds.frames[0], ds.views[0]
        for key in ("rgb", "rgb_noisy"):
            t0 = time.perf_counter()
            for _ in range(20):
                np.asarray(ds.read(frame, view, key))
            print(f"read {key:<10} {1000 * (time.perf_counter() - t0) / 20:7.2f} ms per view")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
