"""Training-loader throughput: lfusd.torch.LightFieldVideoDataset over a dataset folder against the
same loader over a training cache (``lfusd export cache``), side by side in one run.

Usage: .venv/bin/python benchmarks/bench_loader.py [--items-slow 2] [--items-fast 400] [--size-a 512] [--grid-a 9]
       [--size-b 256] [--grid-b 3] [--keep DIR]

No Blender: each case SYNTHESISES a format-version-2 dataset folder with the library's own writers
(lfusd.data.store for gt.exr and motion.exr, OpenEXR half RGB for rgb.exr as Blender writes it,
lfusd.data.integrity's completion records, the manifest, object table and frame.json a render
writes), filled with the closed-form scene of tests/support/fake.py (a textured wall and a moving
textured square, every key exact). Rendering 9x9 views at 512x512 on two cores would take hours.
The cache is then made with ``lfusd.exports.export(ds, "cache", ...)`` and both loaders are timed
in this process with no DataLoader workers (one core: items/s is items/s per core), through
``lfusd.torch.data_loader`` (batches of 8 for the cache, 1 for the folder, collation included;
the cache after one untimed pass that maps its pages into the process):

(a) 9x9 views, random 64x64 crops of 512x512 images, rgb + disparity (DistgDisp-style training);
(b) 3x3 views, whole 256x256 images, the scene-flow key set (rgb, depth, disparity,
    disparity_change, flow_fwd, flow_bwd, scene_flow, valid_fwd/bwd, occlusion_fwd/bwd).

Per core = per CPU second of this process (``time.process_time``: user and system time, page
faults included), which a machine shared with other work does not distort; the wall-clock rate
is printed too. MB/s counts the bytes of the items delivered (the tensors, rgb as float32; the last columns with
``uint8_rgb=True``, rgb as the stored uint8, a quarter of its bytes). The cache's files were
just written, so they are in the page cache (a training run on a machine whose memory holds the
cache reads the same way; a cold disk adds its read time). The last lines give the cache's bytes
per view against the decoded size of its keys (Dataset.read's arrays).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
import uuid
from pathlib import Path

import numpy as np
import OpenEXR

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))
from lfusd import Dataset, keys as keyreg, layout  # noqa: E402
from lfusd.data import integrity, store  # noqa: E402
from lfusd.files import atomic_write  # noqa: E402

RGB_DISP = ("rgb", "disparity")
SCENE_FLOW = ("rgb", "depth", "disparity", "disparity_change", "flow_fwd", "flow_bwd", "scene_flow", "valid_fwd", "valid_bwd",
              "occlusion_fwd", "occlusion_bwd")
STORED_GT = ("depth", "normal", "instance")
STORED_MOTION = ("flow_fwd", "flow_bwd", "scene_flow", "disparity_change", "valid_fwd", "valid_bwd", "occlusion_fwd", "occlusion_bwd")


def synthesise(root: Path, grid: int, size: int, frames, motion: bool) -> Dataset:
    """A format-version-2 dataset folder of the closed-form scene (see the module docstring)."""
    from support.fake import FakeDataset

    fake = FakeDataset(root, rows=grid, cols=grid, width=size, height=size, frames=tuple(frames))
    rig = fake.rig
    name = rig.name
    wanted = ["rgb", "rgb_linear", "depth", "normal", "position", "instance", "semantic", "disparity", "depth_euclidean"]
    wanted += list(STORED_MOTION) if motion else []
    root.mkdir(parents=True)
    manifest = {"format": layout.FORMAT, "version": layout.FORMAT_VERSION, "id": uuid.uuid4().hex, "rigs": [name], "frames": list(frames),
                "settings": {"rigs": {name: rig.to_dict()}, "motion": motion, "keys": wanted, "keep_raw": False},
                "complete": {name: list(frames)}}
    atomic_write(root / layout.MANIFEST, json.dumps(manifest))
    objects = [{"id": 1, "prim_path": "/World/Wall", "label": "wall", "class_id": 1}, {"id": 2, "prim_path": "/World/Box", "label": "box", "class_id": 2}]
    atomic_write(root / layout.OBJECTS, json.dumps({"classes": fake.classes, "objects": objects}))
    for t in frames:
        fd = layout.frame_dir(root, name, t)
        fd.mkdir(parents=True)
        meta = {"frame": t, "time_code": t, "cam_to_world": {layout.view_key(v): fake.cam_to_world(t, v).tolist() for v in rig.views},
                "object_poses": {o["prim_path"]: fake.objects[o["id"]].poses[t].tolist() for o in objects}}
        atomic_write(fd / layout.FRAME_META, json.dumps(meta))
        for v in rig.views:
            d = fd / layout.view_key(v)
            d.mkdir()
            lin = ((fake.read(t, v, "rgb").astype(np.float32) / 255.0) ** 2.2).astype(np.float16)  # a linear render, as half
            OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, {"RGB": lin}).write(str(d / layout.RGB_EXR))
            store.write(d / layout.GT_FILE, {k: fake.read(t, v, k) for k in STORED_GT})
            files = {layout.RGB_EXR: {}, layout.GT_FILE: {}}
            if motion:
                arrays = {k: fake.read(t, v, k) for k in STORED_MOTION}
                for k in ("flow_fwd", "flow_bwd", "scene_flow", "disparity_change"):  # stored quantised, NaN where undefined -> 0
                    arrays[k] = np.nan_to_num(arrays[k])
                store.write(d / layout.MOTION_FILE, arrays)  # quantised by its lfusd.keys.Storage
                files[layout.MOTION_FILE] = {}
            integrity.record_files(d, files)
    return Dataset(root)


def item_bytes(item) -> int:
    return sum(v.numel() * v.element_size() for v in item.values() if hasattr(v, "numel"))


def time_loader(dataset, n: int, batch: int, warm: bool = False) -> tuple[float, float, float]:
    """(items per CPU second, MB per CPU second, items per wall second) of ``n`` items through
    lfusd.torch.data_loader with no workers (one core); ``warm``: after an untimed pass of ``n``
    items (the maps' pages mapped into the process, as they are after the first minutes of a
    training run)."""
    from lfusd.torch import data_loader

    loader = data_loader(dataset, batch_size=batch, shuffle=True, num_workers=0)
    for rep in range(2 if warm else 1):
        got = nbytes = 0
        t0, c0 = time.perf_counter(), time.process_time()
        while got < n:
            for b in loader:
                got += len(b["frames"])
                nbytes += item_bytes(b)
                if got >= n:
                    break
        dt, cpu = time.perf_counter() - t0, time.process_time() - c0
    return got / cpu, nbytes / cpu / 1e6, got / dt


def run_case(label: str, folder: Path, grid: int, size: int, frames, keys, crop, n_slow: int, n_fast: int, rows: list) -> None:
    import torch

    from lfusd import exports
    from lfusd.data.cache import TrainingCache
    from lfusd.torch import LightFieldVideoDataset

    motion = any(keyreg.get(k).stage == keyreg.MOTION for k in keys)
    t0 = time.perf_counter()
    # a kept folder (--keep) is reused: the dataset as it is, the cache completed (lfusd export cache resumes)
    ds = Dataset(folder / "dataset") if (folder / "dataset").is_dir() else synthesise(folder / "dataset", grid, size, frames, motion)
    t1 = time.perf_counter()
    exports.export(ds, "cache", folder / "cache", keys=",".join(keys))
    t2 = time.perf_counter()
    cache = TrainingCache(folder / "cache")
    print(f"{label}: synthesised (or reused) {len(frames)} frames of {grid}x{grid} views at {size}x{size} in {t1 - t0:.1f} s; "
          f"cache made in {t2 - t1:.1f} s ({(t2 - t1) / len(frames) / grid**2 * 1e3:.0f} ms per view)", flush=True)
    torch.manual_seed(0)
    kw = dict(keys=keys, views="all", crop=crop, random_crop=crop is not None)
    slow = time_loader(LightFieldVideoDataset(ds, **kw), n_slow, 1)
    fast = time_loader(LightFieldVideoDataset(cache, **kw), n_fast, 8, warm=True)
    fast8 = time_loader(LightFieldVideoDataset(cache, uint8_rgb=True, **kw), n_fast, 8, warm=True)
    decoded = sum(ds.read(frames[1], (0, 0), k).nbytes for k in keys)
    on_disk = sum((folder / "cache" / f"{frames[1]:06d}" / f"{k}.npy").stat().st_size for k in keys) / grid**2
    rows.append((label, slow, fast, fast8, decoded, on_disk))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--items-slow", type=int, default=2, help="items timed from the dataset folder (seconds each at 9x9)")
    ap.add_argument("--items-fast", type=int, default=400, help="items timed from the cache")
    ap.add_argument("--size-a", type=int, default=512)
    ap.add_argument("--grid-a", type=int, default=9)
    ap.add_argument("--size-b", type=int, default=256)
    ap.add_argument("--grid-b", type=int, default=3)
    ap.add_argument("--keep", default=None, help="keep the synthesised datasets and caches in this folder (a rerun reuses them)")
    a = ap.parse_args()
    import torch

    torch.set_num_threads(1)  # one core, as a DataLoader worker runs
    base = Path(a.keep) if a.keep else Path(tempfile.mkdtemp(prefix="bench_loader_"))
    rows: list = []
    try:
        run_case(f"(a) {a.grid_a}x{a.grid_a}, 64x64 crops of {a.size_a}x{a.size_a}, rgb+disparity", base / "a", a.grid_a, a.size_a,
                 [1, 2], RGB_DISP, 64, a.items_slow, a.items_fast, rows)
        run_case(f"(b) {a.grid_b}x{a.grid_b}, {a.size_b}x{a.size_b}, scene-flow keys", base / "b", a.grid_b, a.size_b,
                 [1, 2, 3, 4], SCENE_FLOW, None, a.items_slow, a.items_fast // 4, rows)
    finally:
        if not a.keep:
            shutil.rmtree(base, ignore_errors=True)
    print()
    print("per core: items and MB per CPU second of this process (user + system, one thread); wall: items per second of the clock")
    print(f"{'case':<58} {'folder items/s':>14} {'cache items/s':>14} {'ratio':>8} {'folder MB/s':>12} {'cache MB/s':>11}"
          f" {'cache, uint8 rgb: items/s':>26} {'MB/s':>7} {'wall items/s: folder/cache/uint8':>33}")
    for label, slow, fast, fast8, _, _ in rows:
        print(f"{label:<58} {slow[0]:>14.2f} {fast[0]:>14.1f} {fast[0] / slow[0]:>7.0f}x {slow[1]:>12.1f} {fast[1]:>11.1f}"
              f" {fast8[0]:>26.1f} {fast8[1]:>7.1f} {f'{slow[2]:.2f} / {fast[2]:.1f} / {fast8[2]:.1f}':>33}")
    print()
    print(f"{'case':<58} {'decoded B/view':>14} {'cache B/view':>14} {'ratio':>8}")
    for label, _, _, _, decoded, on_disk in rows:
        print(f"{label:<58} {decoded:>14,d} {on_disk:>14,.0f} {on_disk / decoded:>8.4f}")
    print(f"\none core (torch threads 1, no DataLoader workers); goals: (a) >= 200 items/s, (b) >= 50 items/s per core; cache <= 2x decoded. "
          f"{os.cpu_count()} CPUs on this machine, load average {os.getloadavg()[0]:.1f} at the end")
    return 0


if __name__ == "__main__":
    sys.exit(main())
