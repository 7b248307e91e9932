"""`lfusd render-video` against the fair floor: one bare Blender multiview render of beauty plus data passes.

    .venv/bin/python benchmarks/bench_render_video.py [--grid 3x3] [--resolution 512x512] [--frames 3]
        [--samples 1,16] [--repeat 3] [--memory-frames 2,8] [--memory-grid 2x2] [--memory-resolution 96x96]

The floor is what a bare bpy script needs for the same views, frames and samples: ONE render call
per frame with multiview, writing the beauty (Combined) and the data passes lfusd needs (Depth,
Normal, Position, Vector, Object Index) into one multilayer EXR per view, with Blender's defaults
for that format (float32, ZIP). It does not do the second, exact data render at the pixel centres
(1 sample, 0 bounces), the motion AOVs, the derivation of the motion keys, the PNGs or the
integrity records: that is lfusd's overhead.

Prints, per sample count, from runs interleaved side by side (floor, lfusd, floor, lfusd, ...):
wall seconds of each (best of --repeat), views per second, the ratio of the bests, the median
of the per-pair ratios and the ratio of CPU seconds (the machine may be shared), and the peak
resident memory of the largest process and of the whole process tree (polled with psutil); then the
CPU account of lfusd's last run per sample count (core-seconds per phase, scaled to a 1024x1024
view, as bench_reference.py prints it). Then the peak memory of lfusd for two
video lengths (flat in frames is the goal).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil

ROOT = Path(__file__).resolve().parents[1]

FLOOR = r"""
import json, sys, time, bpy
bpy.utils.expose_bundled_modules()
job = json.loads(sys.argv[-1])
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.wm.usd_import(filepath=job["stage"], set_frame_range=False)
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
vl = sc.view_layers[0]
vl.use_pass_combined = vl.use_pass_z = vl.use_pass_normal = vl.use_pass_position = True
vl.use_pass_vector = vl.use_pass_object_index = True
sc.cycles.samples = job["samples"]; sc.cycles.use_denoising = False; sc.cycles.use_adaptive_sampling = False
sc.cycles.device = "CPU"
r.image_settings.media_type = "MULTI_LAYER_IMAGE"  # Blender's defaults: float32, ZIP
for f in range(job["first"], job["last"] + 1):
    sc.frame_set(f)
    r.filepath = f"{job['out']}/f{f:06d}_"
    bpy.ops.render.render(write_still=True)
"""


def make_stage(path: Path, frames: int, grid: tuple[int, int], resolution: tuple[int, int]) -> None:
    """The bundled static box stage, with its crate sliding and turning over ``frames`` frames."""
    from pxr import Gf, Usd, UsdGeom

    from lfusd.author.rigs import add_rig
    from lfusd.camera import RigSpec

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
    add_rig(stage, RigSpec(name="main", rows=rows, cols=cols, baseline=0.1, width=resolution[0], height=resolution[1],
                           at=(0.5, -7.0, 2.2), look_at=(0.0, 1.0, 0.6)))
    stage.Save()


# The phases of lfusd.cpu_account, in pipeline order, with the process that charges them; the two
# "trace" phases are Cycles' path tracing, everything else is the CPU cost outside it.
PHASES = [
    ("parent", "startup parent", "imports, stage checks, planning (once per run)"),
    ("lane", "startup lane", "imports, numba kernels, Open3D (once per derivation process)"),
    ("worker", "startup worker", "Blender start-up, stage import, scene set-up (once per worker)"),
    ("worker", "scene", "frame evaluation, motion AOV attributes"),
    ("worker", "geometry", "triangles for exact occlusion (geometry.npz)"),
    ("worker", "beauty sync", "Blender/Cycles scene sync of the beauty render call"),
    ("worker", "beauty trace", "Cycles path tracing, beauty"),
    ("worker", "beauty write", "writing rgb.exr"),
    ("worker", "data sync", "Blender/Cycles scene sync of the data render call"),
    ("worker", "data trace", "Cycles path tracing, data passes"),
    ("worker", "data write", "raw-pass writing (passes.exr)"),
    ("parent", "raw check", "decoding the worker's files before commit"),
    ("*", "read", "reading raw passes and images (lanes)"),
    ("*", "occluders", "loading geometry.npz, building the ray-casting scene"),
    ("*", "derive", "motion kernel (numba)"),
    ("*", "visibility", "exact occlusion rays"),
    ("*", "mixed", "mixed-footprint rays"),
    ("*", "encode", "encoding and writing gt.exr, motion.exr, rgb.png"),
    ("*", "read-back", "reading back gt.exr, motion.exr"),
    ("*", "hashing", "digests of files: sha256, XXH3 for the raw passes"),
    ("*", "commit", "moving files, writing records"),
]
TRACE = ("beauty trace", "data trace")


def cpu_account(folder: Path, views: int, pixels: int, tree_cpu: float) -> str:
    """The per-view CPU account of one run from the records lfusd.cpu_account wrote in ``folder``:
    core-seconds per 1024x1024 view (scaled by pixels) per phase, summed over all processes; what a
    process spent outside any phase is its "other" (Python and module start-up, planning, waiting)."""
    from lfusd.cpu_account import collect

    records = collect(folder)
    scale = 1024 * 1024 / pixels / views
    phases: dict[str, float] = {}
    other: dict[str, float] = {}
    for r in records:
        for k, v in r["phases"].items():
            k = f"startup {r['role']}" if k == "startup" else k
            phases[k] = phases.get(k, 0.0) + v
        other[r["role"]] = other.get(r["role"], 0.0) + r["process"] - sum(r["phases"].values())
    recorded = sum(r["process"] for r in records)
    rows = [f"{'phase':<14}{'core-s/view':>12}  (per 1024x1024 view, {views} views; process CPU time)"]
    known = {p for _, p, _ in PHASES}
    for _, name, what in PHASES + [("*", k, "") for k in sorted(phases) if k not in known]:
        if name in phases:
            rows.append(f"{name:<14}{phases[name] * scale:12.3f}  {what}")
    for role, v in sorted(other.items()):
        rows.append(f"{'other ' + role:<14}{v * scale:12.3f}  outside any phase")
    rows.append(f"{'unrecorded':<14}{(tree_cpu - recorded) * scale:12.3f}  process tree CPU not in any record (psutil - records)")
    outside = tree_cpu - sum(phases.get(k, 0.0) for k in TRACE)
    once = sum(v for k, v in phases.items() if k.startswith("startup"))
    rows.append(f"total outside Cycles' path tracing: {outside * scale:.3f} core-s per 1024x1024 view "
                f"(tree {tree_cpu * scale:.3f}, path tracing {sum(phases.get(k, 0.0) for k in TRACE) * scale:.3f})")
    rows.append(f"  without the once-per-process start-up ({once * scale:.3f} here, amortised over a whole video): {(outside - once) * scale:.3f}")
    # A view has motion in two directions inside a video, one at its first and last frame: a
    # run of few frames does fewer directions than a long video. Each direction's exact occlusion is
    # one "visibility" block; the motion kernel ("derive") does both directions in one call, and is
    # scaled by the directions done (its fixed part is then counted twice: an overestimate).
    directions = sum(r.get("counts", {}).get("visibility", 0) for r in records)
    if directions:
        extra = (2 * views - directions) / directions * (phases.get("visibility", 0.0) + phases.get("derive", 0.0))
        rows.append(f"  in a long video (both motion directions at every view; {directions / views:.2f} per view here): "
                    f"{(outside - once + extra) * scale:.3f}")
    rows.append(f"  of it lfusd's own work after the render calls (parent and derivation): "
                f"{sum(v for k, v in phases.items() if k not in {p for role, p, _ in PHASES if role == 'worker'}) * scale:.3f}")
    return "\n".join(rows)


def timed(cmd: list[str], what: str, cwd=None, env=None) -> tuple[float, float, float, float]:
    """Run ``cmd``; (wall seconds, peak RSS of its largest process, peak RSS summed over its process
    tree, CPU seconds of the tree), memory in MiB, polled every 50 ms (CPU as last seen per process)."""
    t = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=cwd, env=env)
    root = psutil.Process(proc.pid)
    largest = total = 0
    cpu: dict[int, float] = {}
    while proc.poll() is None:
        try:
            tree = [root, *root.children(recursive=True)]
            rss = []
            for p in tree:
                try:
                    rss.append(p.memory_info().rss)
                    c = p.cpu_times()
                    cpu[p.pid] = c.user + c.system
                except psutil.Error:
                    pass
            largest, total = max(largest, max(rss, default=0)), max(total, sum(rss))
        except psutil.Error:
            pass
        time.sleep(0.05)
    wall = time.perf_counter() - t
    err = proc.stderr.read()
    if proc.returncode:
        sys.exit(f"{what} failed: {err.strip()[-800:]}")
    return wall, largest / 2**20, total / 2**20, sum(cpu.values())


def run_floor(stage: Path, out: Path, samples: int, frames: int, resolution) -> tuple[float, float, float, float]:
    job = {"stage": str(stage), "samples": samples, "first": 1, "last": frames, "out": str(out),
           "width": resolution[0], "height": resolution[1]}
    shutil.rmtree(out, ignore_errors=True)
    return timed([sys.executable, "-c", FLOOR, json.dumps(job)], "the bare Blender render")


def run_lfusd(stage: Path, out: Path, samples: int, frames: int, workers: int = 1, account: Path | None = None) -> tuple[float, float, float, float]:
    """One render-video; with ``account``, its CPU account goes there (lfusd.cpu_account, emptied first)."""
    shutil.rmtree(out, ignore_errors=True)
    cmd = [sys.executable, "-m", "lfusd", "render-video", str(stage), "-o", str(out), "--samples", str(samples),
           "--device", "cpu", "--quiet", "--frames", f"1-{frames}", "--workers", str(workers)]
    env = None
    if account is not None:
        shutil.rmtree(account, ignore_errors=True)
        account.mkdir()
        env = {**os.environ, "LFUSD_CPU_ACCOUNT": str(account)}
    return timed(cmd, "lfusd render-video", cwd=ROOT, env=env)


def pair(text: str) -> tuple[int, int]:
    a, b = text.lower().split("x")
    return int(a), int(b)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grid", type=pair, default=(3, 3))
    ap.add_argument("--resolution", type=pair, default=(512, 512))
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--samples", default="1,16", help="sample counts, comma separated")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--workers", type=int, default=1, help="lfusd's --workers")
    ap.add_argument("--memory-frames", default="2,8", help="video lengths for the memory check ('' to skip)")
    ap.add_argument("--memory-grid", type=pair, default=(2, 2))
    ap.add_argument("--memory-resolution", type=pair, default=(96, 96))
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="lfusd-bench-"))
    try:
        stage = tmp / "bench.usda"
        make_stage(stage, args.frames, args.grid, args.resolution)
        views = args.grid[0] * args.grid[1] * args.frames
        print(f"static_boxes, crate moving; {args.grid[0]}x{args.grid[1]} views, {args.resolution[0]}x{args.resolution[1]}, "
              f"{args.frames} frames ({views} views), CPU, lfusd --workers {args.workers}; best of {args.repeat}, interleaved")
        print(f"{'samples':>7} {'floor s':>8} {'lfusd s':>8} {'floor v/s':>9} {'lfusd v/s':>9} {'ratio':>6} {'median':>6}"
              f" {'CPU ratio':>9} {'floor MiB max/sum':>18} {'lfusd MiB max/sum':>18}")
        account_of: dict[int, str] = {}
        for samples in (int(s) for s in args.samples.split(",")):
            floors, runs = [], []
            for _ in range(args.repeat):
                floors.append(run_floor(stage, tmp / "floor", samples, args.frames, args.resolution))
                runs.append(run_lfusd(stage, tmp / "lfusd", samples, args.frames, args.workers, account=tmp / "cpu"))
            fb, lb = min(r[0] for r in floors), min(r[0] for r in runs)
            med = statistics.median(r[0] / f[0] for f, r in zip(floors, runs))
            cpu = min(r[3] for r in runs) / min(f[3] for f in floors)  # CPU seconds: what a loaded machine distorts least
            fm = f"{max(r[1] for r in floors):.0f}/{max(r[2] for r in floors):.0f}"
            lm = f"{max(r[1] for r in runs):.0f}/{max(r[2] for r in runs):.0f}"
            print(f"{samples:7d} {fb:8.2f} {lb:8.2f} {views / fb:9.2f} {views / lb:9.2f} {lb / fb:6.3f} {med:6.3f} {cpu:9.3f} {fm:>18} {lm:>18}",
                  flush=True)
            account_of[samples] = cpu_account(tmp / "cpu", views, args.resolution[0] * args.resolution[1], runs[-1][3])
        for samples, text in account_of.items():
            print(f"CPU account of the last lfusd run at {samples} samples:\n{text}")
        if args.memory_frames:
            lengths = [int(x) for x in args.memory_frames.split(",")]
            print(f"memory of lfusd render-video, {args.memory_grid[0]}x{args.memory_grid[1]} views, "
                  f"{args.memory_resolution[0]}x{args.memory_resolution[1]}, 1 sample:")
            peaks = []
            for n in lengths:
                s = tmp / f"mem{n}.usda"
                make_stage(s, n, args.memory_grid, args.memory_resolution)
                w, largest, total, _ = run_lfusd(s, tmp / f"mem{n}", 1, n, args.workers)
                peaks.append(largest)
                print(f"  {n:4d} frames: {w:7.1f} s, peak RSS largest process {largest:7.1f} MiB, process tree {total:7.1f} MiB")
            if len(peaks) > 1:
                print(f"  peak ratio {lengths[-1]} / {lengths[0]} frames: {peaks[-1] / peaks[0]:.3f}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
