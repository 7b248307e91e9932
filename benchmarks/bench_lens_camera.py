"""The extra render cost of lens distortion (issue 40 item 4): Cycles' pinhole camera against the OSL
custom camera of lfusd.render.lens (the Brown-Conrady ray of every sample), side by side in one run.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_lens_camera.py [--template room] [--resolution 96x72]
        [--samples 16] [--repeat 3]

Generates one scene (lfusd.author.scenes.generate), imports it into Blender once, then renders one view
of its rig with the pinhole and with the lens camera (k1 -0.25, k2 0.05, p1 0.003, p2 -0.004), each as
the beauty (--samples, Blackman-Harris 1.5 px) and as the data render (one sample, box filter, the
data passes on), interleaved round by round (benchmarks/interleave.py: each round starting with the
other camera). Prints the best render seconds per configuration and the lens/pinhole ratios: the
camera itself, where bench_camera_effects.py's ``lens`` measures all of render-video --lens.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

PROBE = r"""
import json, sys, time
import bpy
sys.path.insert(0, sys.argv[6])
from interleave import rounds
from lfusd.camera import Distortion, RigSpec
from lfusd.render.lens import osl_source
from lfusd.render.worker import distort_camera
stage, w, h, samples, repeat = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5])
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.wm.usd_import(filepath=stage)
scene = bpy.context.scene
scene.render.engine = "CYCLES"
scene.cycles.device = "CPU"
scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = w, h, 100
scene.cycles.use_denoising = False
cams = sorted((o for o in bpy.data.objects if o.type == "CAMERA"), key=lambda o: o.name)
pin = cams[0]
lens = pin.copy()
lens.data = pin.data.copy()
scene.collection.objects.link(lens)
spec = RigSpec(width=w, height=h)
distort_camera(lens.data, osl_source(Distortion(k1=-0.25, k2=0.05, p1=0.003, p2=-0.004), spec.intrinsics(), w, h))
vl = scene.view_layers[0]
times = {}
cams_of = {"pinhole": pin, "lens": lens}
for r, names in rounds(["pinhole", "lens"], repeat):
    order = [(name, cams_of[name]) for name in names]
    for render in ("beauty", "data"):
        cyc = scene.cycles
        if render == "beauty":
            cyc.samples, cyc.pixel_filter_type, cyc.filter_width = samples, "BLACKMAN_HARRIS", 1.5
        else:
            cyc.samples, cyc.pixel_filter_type, cyc.filter_width = 1, "BOX", 0.01
        for p in ("use_pass_z", "use_pass_normal", "use_pass_position", "use_pass_object_index"):
            setattr(vl, p, render == "data")
        for name, cam in order:
            scene.camera = cam
            t0 = time.perf_counter()
            bpy.ops.render.render()
            times.setdefault(f"{render} {name}", []).append(time.perf_counter() - t0)
print("TIMES" + json.dumps(times))
"""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--template", default="room")
    ap.add_argument("--resolution", default="96x72")
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    import json

    from lfusd.author.scenes import generate

    w, h = (int(x) for x in args.resolution.split("x"))
    tmp = Path(tempfile.mkdtemp(prefix="lfusd_bench_lens"))
    try:
        stage = tmp / "scene.usda"
        generate(args.template, stage, 0, frames=1, rigs=1, grid=(1, 1), resolution=(w, h), dynamic=False)
        (tmp / "probe.py").write_text(PROBE)
        out = subprocess.run([sys.executable, str(tmp / "probe.py"), str(stage), str(w), str(h), str(args.samples), str(args.repeat),
                              os.path.dirname(os.path.abspath(__file__))],
                             capture_output=True, text=True, check=True).stdout
        times = json.loads(next(ln for ln in out.splitlines() if ln.startswith("TIMES"))[5:])
        print(f"{args.template}, one view of {w}x{h}, beauty {args.samples} samples, data 1 sample; best of {args.repeat} interleaved rounds")
        print(f"{'render':<8} {'pinhole s':>10} {'lens s':>8} {'lens/pinhole':>13}")
        for render in ("beauty", "data"):
            a, b = min(times[f"{render} pinhole"]), min(times[f"{render} lens"])
            print(f"{render:<8} {a:10.3f} {b:8.3f} {b / a:13.3f}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
