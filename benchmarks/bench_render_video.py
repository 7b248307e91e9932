"""`lfusd render-video` against a bare Blender multiview render of the same views, frames, samples.

    .venv/bin/python benchmarks/bench_render_video.py [--frames 10] [--grid 3x3] [--resolution 256x256]
        [--samples 16] [--memory-frames 10,150] [--memory-grid 2x2] [--memory-resolution 96x96]

Prints, from one run side by side:
- wall time of `lfusd render-video` (beauty + exact data passes + motion AOVs + derived motion)
  and of a bare bpy script rendering only the beauty images with multiview, and their ratio;
- views per second of each;
- peak resident memory (parent and largest Blender worker) for short and long videos.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LFUSD = [sys.executable, "-m", "lfusd"]

BARE = r"""
import json, sys, time, bpy
bpy.utils.expose_bundled_modules()
job = json.loads(sys.argv[-1])
t0 = time.time()
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.wm.usd_import(filepath=job["stage"])
sc = bpy.context.scene
cams = [o for o in bpy.data.objects if o.type == "CAMERA" and o.name.startswith("cam_")]
for o in cams:
    o.name = "V" + o.name[3:]
sc.camera = cams[0]
r = sc.render
r.engine = "CYCLES"; r.resolution_x, r.resolution_y = job["width"], job["height"]; r.resolution_percentage = 100
r.use_multiview = True; r.views_format = "MULTIVIEW"
for v in r.views: v.use = False
for o in cams:
    v = r.views.new(o.name[1:]); v.camera_suffix = o.name[1:]
sc.cycles.samples = job["samples"]; sc.cycles.use_denoising = False; sc.cycles.use_adaptive_sampling = False
sc.cycles.device = "CPU"
r.image_settings.file_format = "PNG"
for f in range(job["first"], job["last"] + 1):
    sc.frame_set(f)
    r.filepath = f"{job['out']}/f{f:06d}_"
    bpy.ops.render.render(write_still=True)
print("BARE", time.time() - t0)
"""


def make_stage(path: Path, frames: int, grid: tuple[int, int], resolution: tuple[int, int]) -> None:
    """The bundled static box stage, with its crate sliding and turning over ``frames`` frames."""
    from pxr import Gf, Usd, UsdGeom

    from lfusd.camera import RigSpec
    from lfusd.author.rigs import add_rig

    shutil.copy(ROOT / "stages" / "static_boxes.usda", path)
    stage = Usd.Stage.Open(str(path))
    stage.SetEndTimeCode(frames)
    crate = UsdGeom.Xformable(stage.GetPrimAtPath("/World/Crate"))
    ops = {op.GetOpName(): op for op in crate.GetOrderedXformOps()}
    for f in range(1, frames + 1):
        ops["xformOp:translate"].Set(Gf.Vec3d(-1.0 + 0.02 * f, 0.0, 0.5), f)
        ops["xformOp:rotateXYZ"].Set(Gf.Vec3f(0.0, 0.0, 25.0 + 2.0 * f), f)
    stage.RemovePrim("/Rigs/main")
    rows, cols = grid
    add_rig(stage, RigSpec(name="main", rows=rows, cols=cols, baseline=0.1, width=resolution[0], height=resolution[1], at=(0.5, -7.0, 2.2), look_at=(0.0, 1.0, 0.6)))
    stage.Save()


def run_lfusd(stage: Path, out: Path, samples: int, frames: int) -> tuple[float, float, float]:
    """(wall seconds, parent peak MiB, largest worker peak MiB) of one render-video run."""
    code = (
        "import resource, sys, time; from lfusd.cli import main; t = time.time(); "
        f"rc = main(['render-video', {str(stage)!r}, '-o', {str(out)!r}, '--samples', '{samples}', '--device', 'cpu', '--quiet', '--frames', '1-{frames}']); "
        "print('WALL', time.time() - t, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss); sys.exit(rc)"
    )
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    if p.returncode:
        sys.exit(f"render-video failed: {p.stderr.strip().splitlines()[-1]}")
    _, wall, parent, child = next(ln for ln in p.stdout.splitlines() if ln.startswith("WALL")).split()
    return float(wall), int(parent) / 1024, int(child) / 1024


def run_bare(stage: Path, out: Path, samples: int, frames: int, resolution) -> float:
    job = {"stage": str(stage), "samples": samples, "first": 1, "last": frames, "out": str(out), "width": resolution[0], "height": resolution[1]}
    t = time.time()
    p = subprocess.run([sys.executable, "-c", BARE, json.dumps(job)], capture_output=True, text=True)
    if p.returncode:
        sys.exit(f"bare Blender render failed: {p.stderr.strip()[-500:]}")
    return time.time() - t


def pair(text: str) -> tuple[int, int]:
    a, b = text.lower().split("x")
    return int(a), int(b)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--grid", type=pair, default=(3, 3))
    ap.add_argument("--resolution", type=pair, default=(256, 256))
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--memory-frames", default="10,150")
    ap.add_argument("--memory-grid", type=pair, default=(2, 2))
    ap.add_argument("--memory-resolution", type=pair, default=(96, 96))
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="lfusd-bench-"))
    try:
        stage = tmp / "bench.usda"
        make_stage(stage, args.frames, args.grid, args.resolution)
        views = args.grid[0] * args.grid[1] * args.frames
        print(f"stage: static_boxes scene, crate moving; {args.grid[0]}x{args.grid[1]} views, {args.resolution[0]}x{args.resolution[1]}, {args.frames} frames, {args.samples} samples, CPU")
        bare = run_bare(stage, tmp / "bare", args.samples, args.frames, args.resolution)
        wall, _, _ = run_lfusd(stage, tmp / "lfusd", args.samples, args.frames)
        print(f"bare Blender multiview (beauty only): {bare:7.2f} s  {views / bare:6.2f} views/s")
        print(f"lfusd render-video (all outputs):     {wall:7.2f} s  {views / wall:6.2f} views/s")
        print(f"overhead ratio lfusd / bare: {wall / bare:.3f}")
        print(f"memory ({args.memory_grid[0]}x{args.memory_grid[1]} views, {args.memory_resolution[0]}x{args.memory_resolution[1]}, 1 sample):")
        peaks = []
        for n in (int(x) for x in args.memory_frames.split(",")):
            s = tmp / f"mem{n}.usda"
            make_stage(s, n, args.memory_grid, args.memory_resolution)
            w, parent, child = run_lfusd(s, tmp / f"mem{n}", 1, n)
            peaks.append(max(parent, child))
            print(f"  {n:4d} frames: {w:7.1f} s, peak RSS parent {parent:7.1f} MiB, largest worker {child:7.1f} MiB")
        if len(peaks) > 1:
            print(f"  peak ratio {args.memory_frames.split(',')[-1]} / {args.memory_frames.split(',')[0]} frames: {peaks[-1] / peaks[0]:.3f}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
