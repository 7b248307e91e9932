"""The reference configuration: K frames of a 9x9 rig at 1024x1024 on the default scene, every key.

    .venv/bin/python benchmarks/bench_reference.py [--frames 2] [--first 70] [--samples 16]
        [--device cpu|cuda|optix|auto] [--stage stages/street_dynamic_00.usda] [--pose rig_00]
        [--grid 9x9] [--resolution 1024x1024] [--workers 1] [--out DIR]

A rig of the reference shape (the default rig of ``lfusd rig add``: 0.125 m baseline, 39 mm lens on a 36 mm
sensor) is authored at the pose of ``--pose`` (a rig of the stage) in a layer over the stage, and
``lfusd render-video`` renders frames first..first+K-1 of it with the default settings (RGB and
every ground-truth key, format version 2, samples as render-video's default). Prints
views per second, seconds per frame, the worker's own split of each frame (beauty render, data
render, scene evaluation), bytes per view and per pixel on disk, peak resident memory of the
largest process and of the whole process tree (polled with psutil), and the hours and terabytes
that 150 frames would take at the measured rate. Then the CPU account: core-seconds per 1024x1024
view of every phase (lfusd.cpu_account, summed over the worker, the parent and the derivation
processes), and the total outside Cycles' path tracing (the issue-28 budget: <= 1.0). ``lfusd verify`` then checks the output (its
pixel count is printed) unless ``--no-verify``.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_render_video import cpu_account, pair, timed  # noqa: E402  (one memory/CPU poller and CPU account for the benchmarks)
from lfusd.layout import PASSES_EXR as PASSES  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
VIDEO_FRAMES = 150

PHASE = re.compile(r"^lfusd: frame (\d+) views (\d+) seconds (.*)$")


def reference_layer(stage: Path, pose: str, out: Path, grid: tuple[int, int], resolution: tuple[int, int]) -> None:
    """Write ``out``, a layer over ``stage`` holding rig ``reference``: the reference rig shape at the pose of rig ``pose``."""
    from lfusd.author.rigs import add_rig, rigs
    from lfusd.author.stage import layer_over
    from lfusd.camera import RigSpec
    from pxr import Usd

    found = rigs(Usd.Stage.Open(str(stage)))
    if pose not in found:
        sys.exit(f"stage {stage} has no rig {pose!r} (its rigs: {', '.join(sorted(found))})")
    at, look_at = found[pose].spec.at, found[pose].spec.look_at
    layer = layer_over(stage, out)
    add_rig(layer, RigSpec(name="reference", rows=grid[0], cols=grid[1], width=resolution[0], height=resolution[1], at=at, look_at=look_at))
    layer.Save()


def phases(logs: Path) -> dict[str, float]:
    """Seconds per phase over the workers' logs. A worker prints one line per chunk of views,
    "lfusd: frame N views V seconds beauty .. data ..", with the frame's totals so far: the last
    line of each frame counts."""
    last: dict[tuple[str, int], dict[str, float]] = {}
    for f in logs.glob("*.log"):
        for line in f.read_text(errors="replace").splitlines():
            m = PHASE.match(line)
            if m:
                words = m.group(3).split()
                last[(f.name, int(m.group(1)))] = {k: float(v) for k, v in zip(words[::2], words[1::2])}
    total: dict[str, float] = {}
    for frame in last.values():
        for k, v in frame.items():
            total[k] = total.get(k, 0.0) + v
    return total


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stage", type=Path, default=ROOT / "stages" / "street_dynamic_00.usda")
    ap.add_argument("--pose", default="rig_00", help="the stage's rig whose pose the reference rig takes")
    ap.add_argument("--frames", type=int, default=2, help="K frames rendered (>= 2: motion needs a neighbour)")
    ap.add_argument("--first", type=int, default=70)
    ap.add_argument("--samples", type=int, default=16, help="Cycles samples (render-video's default: 16)")
    ap.add_argument("--device", default="cpu", choices=["cpu", "cuda", "optix", "auto"])
    ap.add_argument("--grid", type=pair, default=(9, 9))
    ap.add_argument("--resolution", type=pair, default=(1024, 1024))
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--out", type=Path, help="keep the dataset here, and its stage layer as OUT.usda (default: a temporary folder, removed)")
    ap.add_argument("--no-verify", action="store_true")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="lfusd-ref-"))
    out = args.out or tmp / "out"
    try:
        layer = out.parent / f"{out.name}.usda" if args.out else tmp / "reference.usda"  # kept with a kept dataset (verify reads it)
        reference_layer(args.stage.resolve(), args.pose, layer, args.grid, args.resolution)
        last = args.first + args.frames - 1
        views = args.grid[0] * args.grid[1]
        w, h = args.resolution
        print(f"{args.stage.name}, rig 'reference' at {args.pose}'s pose: {args.grid[0]}x{args.grid[1]} views of {w}x{h}, "
              f"frames {args.first}-{last}, {args.samples} samples, device {args.device}, --workers {args.workers}", flush=True)
        cmd = [sys.executable, "-m", "lfusd", "render-video", str(layer), "-o", str(out), "--rig", "reference",
               "--frames", f"{args.first}-{last}", "--samples", str(args.samples), "--device", args.device,
               "--workers", str(args.workers), "--quiet"]
        account = tmp / "cpu"
        account.mkdir()
        wall, largest, total, cpu = timed(cmd, "lfusd render-video", cwd=ROOT, env={**os.environ, "LFUSD_CPU_ACCOUNT": str(account)})
        files = [p for p in (out / "reference").rglob("*") if p.is_file()]
        size = sum(p.stat().st_size for p in files)
        rendered = views * args.frames
        by_name: dict[str, int] = {}
        for p in files:
            by_name[p.name] = by_name.get(p.name, 0) + p.stat().st_size
        split = phases(out / "logs")
        print(f"wall {wall:.1f} s, CPU {cpu:.1f} s: {rendered / wall:.3f} views/s, {wall / args.frames:.1f} s per frame")
        print("worker seconds per frame: " + ", ".join(f"{k} {v / args.frames:.1f}" for k, v in split.items() if not k.endswith("_cpu")))
        # passes.exr stays only while a neighbouring frame of the stage may still be rendered (a
        # range inside the stage's): a whole video leaves none, so the extrapolation counts without it.
        kept = size - by_name.get(PASSES, 0)
        print(f"disk now: {size / 1e9:.3f} GB, {size / rendered / (w * h):.2f} bytes per pixel ("
              + ", ".join(f"{k} {v / rendered / (w * h):.2f}" for k, v in sorted(by_name.items())) + ")")
        per_view = kept / rendered
        print(f"dataset (without the raw passes a whole video removes): {per_view / 1e6:.2f} MB per view, {per_view / (w * h):.2f} bytes per pixel")
        print(cpu_account(account, rendered, w * h, cpu))
        print(f"peak RSS: largest process {largest / 1024:.2f} GiB, process tree {total / 1024:.2f} GiB")
        hours = wall / args.frames * VIDEO_FRAMES / 3600
        tb = per_view * views * VIDEO_FRAMES / 1e12
        print(f"{VIDEO_FRAMES} frames at this rate: {hours:.1f} hours, {tb:.3f} TB")
        if not args.no_verify:
            v = subprocess.run([sys.executable, "-m", "lfusd", "verify", str(out)], cwd=ROOT, capture_output=True, text=True)
            summary = [line for line in (v.stdout + v.stderr).splitlines() if "compared" in line]
            print(f"lfusd verify: exit {v.returncode}; " + (summary[-1] if summary else "(no summary line)"))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
