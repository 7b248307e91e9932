"""Throughput of lfusd.truth.motion.derive_motion against reading the raw passes from a multilayer EXR.

Usage: .venv/bin/python benchmarks/bench_flow.py [--size 1024] [--repeat 3] [--codec zip|none|piz|dwaa]

Writes a synthetic Blender-style multilayer EXR (depth, vector, position, object index and the
next/previous position AOVs, float32, the channel names Blender uses) with OpenEXR, times reading
it back (the inputs of one frame of one view), times deriving every motion key of one view from
three such frames in memory, and prints Mpixel/s of both and the ratio derive / read (goal <= 0.5);
then the same derivation with exact occlusion (visibility rays cast with Open3D against the frames'
triangles: the wall tessellated into ``--triangles`` triangles and the block's 12) and the ``mixed``
mask (one ray per pixel corner, shared by the four pixels around it), side by side, and the cost
per view in core-seconds of each.
Wall time is the figure of merit; "cpu ms" is process CPU time summed over all threads (numba's
parallel workers included, so it also counts their spin-waiting). NUMBA_NUM_THREADS=1 gives the
single-core cost.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import numpy as np
import OpenEXR

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
from lfusd.camera import Camera, backproject, pixel_grid, project  # noqa: E402
from lfusd.truth.motion import BACKEND, RawPasses, derive_motion  # noqa: E402

CODECS = {"zip": OpenEXR.ZIP_COMPRESSION, "none": OpenEXR.NO_COMPRESSION, "piz": OpenEXR.PIZ_COMPRESSION, "dwaa": OpenEXR.DWAA_COMPRESSION}


def synthetic_frames(n: int):
    """Three frames of a wall and a block sliding across it, camera static: raw passes per frame."""
    f = 1.1 * n
    K = np.array([[f, 0, (n - 1) / 2], [0, f, (n - 1) / 2], [0, 0, 1.0]])
    cam = Camera(K, np.eye(4))
    u, v = pixel_grid(n, n)

    def frame(shift):
        depth = np.full((n, n), 6.0, np.float32) + 0.0005 * v  # tilted wall
        inst = np.ones((n, n), np.int32)
        x0 = int(n * (0.3 + 0.02 * shift))
        block = (u >= x0) & (u < x0 + n // 3) & (v > n // 4) & (v < 3 * n // 4)
        depth[block] = 3.5
        inst[block] = 2
        pos = backproject(u, v, depth, cam)
        motion = np.where(block[..., None], np.array([0.02 * n * 3.5 / f * 1.0, 0, 0], np.float32), 0).astype(np.float32)
        nxt, prv = pos + motion, pos - motion
        nu, nv, _ = project(nxt, cam)
        pu, pv, _ = project(prv, cam)
        vec = np.stack([pu - u, -(pv - v), u - nu, nv - v], -1).astype(np.float32)
        # Rendered float data has busy low mantissa bits (it does not compress like a clean
        # ramp): perturb every value by a few ulps so ZIP sees a realistic entropy.
        rng = np.random.default_rng(shift + 2)
        ulps = lambda a: (a * (1 + rng.normal(0, 3e-7, a.shape))).astype(np.float32)  # noqa: E731
        return RawPasses(ulps(depth), ulps(vec), cam, ulps(pos), inst, ulps(nxt), ulps(prv))

    return frame(-1), frame(0), frame(1)


def synthetic_triangles(n: int, shift: int, count: int):
    """The synthetic scene's triangles at frame ``shift``: the tilted wall as a grid of about
    ``count`` triangles and the sliding block (what the render worker writes as geometry.npz)."""
    from lfusd.truth.visibility import Occluders

    f = 1.1 * n
    K = np.array([[f, 0, (n - 1) / 2], [0, f, (n - 1) / 2], [0, 0, 1.0]])
    cam = Camera(K, np.eye(4))
    k = max(1, int(np.sqrt(count / 2)))
    gu, gv = np.meshgrid(np.linspace(-0.5, n - 0.5, k + 1), np.linspace(-0.5, n - 0.5, k + 1))
    wall = backproject(gu, gv, 6.0 + 0.0005 * gv, cam).reshape(-1, 3)
    idx = np.arange((k + 1) * (k + 1)).reshape(k + 1, k + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    tris = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    x0 = int(n * (0.3 + 0.02 * shift))
    corners = np.array([[x0 - 0.5, n // 4 + 0.5], [x0 + n // 3 - 0.5, n // 4 + 0.5], [x0 + n // 3 - 0.5, 3 * n // 4 - 0.5], [x0 - 0.5, 3 * n // 4 - 0.5]])
    front = backproject(corners[:, 0], corners[:, 1], np.full(4, 3.5), cam)
    box = np.concatenate([front, front + [0, 0, 0.3]])
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 6, 5], [4, 7, 6], [0, 4, 5], [0, 5, 1], [1, 5, 6], [1, 6, 2], [2, 6, 7], [2, 7, 3], [3, 7, 4], [3, 4, 0]])
    return Occluders(np.concatenate([wall, box]), np.concatenate([tris, faces + len(wall)]))


def write_exr(path: str, p: RawPasses, codec) -> None:
    ch = {"ViewLayer.Depth.Z": p.depth}
    for i, c in enumerate("XYZW"):
        ch[f"ViewLayer.Vector.{c}"] = np.ascontiguousarray(p.vector[..., i])
    for name, arr in (("Position", p.position), ("next_position", p.next_position), ("prev_position", p.prev_position)):
        for i, c in enumerate("XYZ"):
            ch[f"ViewLayer.{name}.{c}"] = np.ascontiguousarray(arr[..., i])
    ch["ViewLayer.IndexOB.X"] = p.instance.astype(np.float32)
    header = {"compression": codec, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, ch).write(path)


def read_exr(path: str) -> dict[str, np.ndarray]:
    with OpenEXR.File(path) as f:
        return {k: np.asarray(v.pixels) for k, v in f.channels().items()}


def best_of(fn, repeat: int, clock=time.perf_counter) -> float:
    times = []
    for _ in range(repeat):
        t0 = clock()
        fn()
        times.append(clock() - t0)
    return min(times)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--codec", choices=sorted(CODECS), default="zip", help="EXR compression (Blender's default is zip)")
    ap.add_argument("--backend", default=BACKEND, choices=["numba", "numpy"], help="derivation backend (default: numba when installed)")
    ap.add_argument("--no-aov", action="store_true", help="derive by the vector+depth route only (no position AOVs)")
    ap.add_argument("--triangles", type=int, default=100_000, help="triangles of the scene the exact occlusion casts against")
    a = ap.parse_args()
    prv, cur, nxt = synthetic_frames(a.size)
    mpx = a.size * a.size / 1e6
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "frame.exr")
        write_exr(path, cur, CODECS[a.codec])
        size_mb = os.path.getsize(path) / 1e6
        read_exr(path)  # warm the page cache: measure decoding, not the disk
        t_read = best_of(lambda: read_exr(path), a.repeat)
        c_read = best_of(lambda: read_exr(path), a.repeat, time.process_time)
    if a.no_aov:  # the EXR still holds the AOVs: the read is the same file either way
        for p in (prv, cur, nxt):
            p.next_position = p.prev_position = None
    run = lambda: derive_motion(cur, nxt, prv, baseline=0.1, backend=a.backend)  # noqa: E731
    run()  # compile / load the numba cache outside the timing
    t_derive = best_of(run, a.repeat)
    c_derive = best_of(run, a.repeat, time.process_time)
    route = "vector+depth route" if a.no_aov else "position-AOV route"
    print(f"view {a.size}x{a.size}, EXR {a.codec} {size_mb:.1f} MB (16 float channels), {route}, backend {a.backend}, best of {a.repeat}")
    print(f"{'':18}{'wall ms':>9}{'Mpx/s':>8}{'cpu ms':>9}")
    print(f"{'read EXR inputs':<18}{t_read * 1e3:9.1f}{mpx / t_read:8.2f}{c_read * 1e3:9.1f}")
    print(f"{'derive motion':<18}{t_derive * 1e3:9.1f}{mpx / t_derive:8.2f}{c_derive * 1e3:9.1f}")
    print(f"ratio derive/read: wall {t_derive / t_read:.2f}, cpu {c_derive / c_read:.2f} (goal <= 0.5)")
    if not a.no_aov:
        occ = {"next": synthetic_triangles(a.size, 1, a.triangles), "prev": synthetic_triangles(a.size, -1, a.triangles),
               "here": synthetic_triangles(a.size, 0, a.triangles)}
        exact = lambda: derive_motion(cur, nxt, prv, baseline=0.1, backend=a.backend, occluders=occ)  # noqa: E731
        exact()
        t_exact = best_of(exact, a.repeat)
        c_exact = best_of(exact, a.repeat, time.process_time)
        print(f"{'derive + exact occlusion + mixed':<34}{t_exact * 1e3:9.1f} ms wall, {c_exact * 1e3:9.1f} ms cpu "
              f"({2 * a.size * a.size} visibility rays, {(a.size + 1) ** 2} corner rays, {occ['next'].triangles.shape[0]} triangles per frame)")
        print(f"core-seconds per view: image-space occlusion {c_derive:.3f}, exact occlusion and mixed {c_exact:.3f} "
              f"(ratio {c_exact / c_derive:.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
