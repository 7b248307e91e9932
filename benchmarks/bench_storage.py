"""Bytes per pixel of every ground-truth key, format version 1 against 2, and the accuracy version 2 keeps.

Usage: .venv/bin/python benchmarks/bench_storage.py [--size 1024] [--frames 1-3] [--samples 16] [--out DIR] [--verify]

Renders the centre view of the default scene's rig (stages/street_dynamic_00.usda, rig_00: a
one-view rig at its centre camera, in a layer over the stage) with ``render-video --keep-raw``,
so that Blender's raw passes stay beside the stored keys, then for the middle frame (which has
both neighbours):

1. bytes per pixel per key: version 1 (rgb.png, rgb.exr, passes.exr, motion.npz as lfusd wrote
   them) against version 2 (each key alone in an EXR with its lfusd.keys.Storage encoding, and
   the real files' totals), with the total against the goal of 20;
2. the error of every stored key against its float32 truth (the raw passes and the motion
   derived from them), with the pixels compared, against the key's storage bound and its verify
   limit;
3. the codec choice: the version 2 channels of gt.exr and motion.exr, and rgb.exr, under each
   OpenEXR compression and HDF5 gzip+shuffle (bytes per pixel; write and read ms).

``--verify`` then runs ``lfusd verify`` on the stored (compressed) dataset. ``--out`` keeps the
render (rerunning with the same folder resumes it).
"""

from __future__ import annotations

import argparse
import io
import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import OpenEXR

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from lfusd import Dataset, keys, layout  # noqa: E402
from lfusd.data import passes, store  # noqa: E402
from lfusd.data.formats import write_png  # noqa: E402

STAGE = ROOT / "stages" / "street_dynamic_00.usda"
CODECS = {"zip": OpenEXR.ZIP_COMPRESSION, "pxr24": OpenEXR.PXR24_COMPRESSION, "zips": OpenEXR.ZIPS_COMPRESSION, "piz": OpenEXR.PIZ_COMPRESSION,
          "zstd": OpenEXR.ZSTD_COMPRESSION, "htj2k": OpenEXR.HTJ2K256_COMPRESSION}


def centre_stage(folder: Path, size: int) -> Path:
    """A layer over the default stage with a one-view rig 'centre' at rig_00's centre camera."""
    from lfusd.author.rigs import add_rig, rigs
    from lfusd.author.stage import open_for_edit

    path = folder / "centre.usda"
    if not path.is_file():
        stage = open_for_edit(str(STAGE), str(path))  # a new layer over the stage, as `lfusd rig add -o` writes
        spec = rigs(stage)["rig_00"].spec
        add_rig(stage, replace(spec, name="centre", rows=1, cols=1, width=size, height=size))  # rig_00's centre camera
        stage.GetRootLayer().Save()
    return path


def exr_bytes(channels: dict, codec: str = "zip") -> tuple[int, float, float, bool]:
    """(bytes, write ms, read ms, whether every channel read back bit for bit) of channels in one EXR."""
    with tempfile.TemporaryDirectory() as tmp:
        p = os.path.join(tmp, "x.exr")
        t = time.perf_counter()
        OpenEXR.File({"compression": CODECS[codec], "type": OpenEXR.scanlineimage}, dict(channels)).write(p)
        tw = time.perf_counter() - t
        t = time.perf_counter()
        back = {k: c.pixels for k, c in OpenEXR.File(p).channels().items()}
        tr = time.perf_counter() - t
        exact = all(np.array_equal(np.asarray(back[k]).view(np.uint8), np.asarray(a).view(np.uint8)) for k, a in channels.items())
        return os.path.getsize(p), 1e3 * tw, 1e3 * tr, exact


def stored_bytes(channels: dict) -> int:
    """Bytes of channels in one EXR with the codec lfusd.data.store would choose for them."""
    return exr_bytes(channels, "pxr24" if store.compression_for(channels) == OpenEXR.PXR24_COMPRESSION else "zip")[0]


def h5_bytes(channels: dict) -> int:
    import h5py

    with tempfile.TemporaryDirectory() as tmp:
        p = os.path.join(tmp, "x.h5")
        with h5py.File(p, "w") as h:
            for k, a in channels.items():
                h.create_dataset(k.replace("/", "_"), data=a, chunks=(min(128, a.shape[0]), *a.shape[1:]), compression="gzip",
                                 compression_opts=4, shuffle=True)
        return os.path.getsize(p)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--frames", default="1-3")
    ap.add_argument("--samples", type=int, default=16, help="beauty samples (render-video's default: 16)")
    ap.add_argument("--out", default=None, help="dataset folder (kept; default: a temporary folder)")
    ap.add_argument("--verify", action="store_true", help="run lfusd verify on the stored dataset")
    args = ap.parse_args()
    first, last = (int(x) for x in args.frames.split("-"))
    tmp = None if args.out else tempfile.TemporaryDirectory()
    folder = Path(args.out or tmp.name)
    folder.mkdir(parents=True, exist_ok=True)
    out = folder / "ds"

    from lfusd.render.job import RenderRequest, render_video
    from lfusd.truth.derive import derive_view

    t = time.perf_counter()
    render_video(RenderRequest(stage=centre_stage(folder, args.size), out=out, rig="centre", frames=list(range(first, last + 1)),
                               samples=args.samples, device="cpu", quiet=True, keep_raw=True))
    print(f"rendered {args.size}x{args.size}, frames {first}-{last}, {args.samples} samples, centre view: {time.perf_counter() - t:.0f} s")
    ds = Dataset(out)
    f, v = (first + last) // 2, (0, 0)
    d = ds.view_dir(f, v)
    n = args.size * args.size
    raw = passes.read_raw(d / layout.PASSES_EXR)
    motion = derive_view(ds, f, v)  # float32 truth of the motion keys, from the raw passes
    truth = {**raw, **motion}

    # -- 1. bytes per pixel per key --------------------------------------------------------------
    rgb = passes.read_rgb_linear(d / layout.RGB_EXR)
    with tempfile.TemporaryDirectory() as t2:
        write_png(Path(t2) / "rgb.png", passes.linear_to_srgb8(rgb))
        png = os.path.getsize(Path(t2) / "rgb.png")
    npz = io.BytesIO()
    np.savez(npz, **motion)
    v1 = {"rgb.png": png, "rgb.exr": os.path.getsize(d / layout.RGB_EXR), "passes.exr": os.path.getsize(d / layout.PASSES_EXR),
          "motion.npz": npz.getbuffer().nbytes}
    v2_files = {name: os.path.getsize(d / name) for name in (layout.RGB_EXR, layout.GT_FILE, layout.MOTION_FILE)}
    print(f"\n## bytes per pixel, frame {f}, {args.size}x{args.size} ({n} px)\n")
    print("| key | v2 stored as | v2 B/px |")
    print("|---|---|---|")
    stored = keys.stored(keys.check_wanted(None, motion=True, keep_raw=False))
    masks = [k for k in stored if keys.KEYS[k].storage.encoding == "mask"]
    for k in keys.check_wanted(None, motion=True, keep_raw=False):
        key = keys.KEYS[k]
        if key.storage.encoding == "computed":
            size = "0 (computed)" if k != "rgb" else "0 (from rgb.exr)"
        elif key.storage.encoding == "image":
            size = f"{v2_files[layout.RGB_EXR] / n:.3f}"
        elif key.storage.encoding == "mask":
            size = f"{stored_bytes(store.encode({m: truth[m] for m in masks})) / n / len(masks):.3f} (1/{len(masks)} of `masks`)"
        else:
            size = f"{stored_bytes(store.encode({k: truth[k]})) / n:.3f}"
        print(f"| `{k}` | {key.storage.describe(key.unit)} | {size} |")
    total2 = sum(v2_files.values()) / n
    print("\n| files | v1 B/px | v2 B/px |")
    print("|---|---|---|")
    for a, b in (("rgb.png", None), ("rgb.exr", layout.RGB_EXR), ("passes.exr", layout.GT_FILE), ("motion.npz", layout.MOTION_FILE)):
        print(f"| {a} -> {b or '(computed)'} | {v1[a] / n:.2f} | {(v2_files[b] / n if b else 0):.2f} |")
    total1 = sum(v1.values()) / n
    print(f"| total | {total1:.2f} | {total2:.2f} (goal <= 20; {total1 / total2:.1f}x smaller) |")

    # -- 2. accuracy kept ---------------------------------------------------------------------------
    print(f"\n## error of the stored keys against their float32 truth (frame {f})\n")
    print("| key | values compared | max error | p99 error | storage bound | verify limit (p99) |")
    print("|---|---|---|---|---|---|")
    acc = keys.accuracies()
    units = keys.accuracy_units()
    for k in keys.check_wanted(None, motion=True, keep_raw=False):
        if keys.KEYS[k].stage == keys.IMAGE:
            continue
        got = ds.read(f, v, k)
        want = truth.get(k)
        if want is None:  # computed keys: against the same computation on the raw passes
            info = passes.ViewInfo(ds.intrinsics(v), ds.baseline, ds._class_of_instance, ds.cam_to_world(f, v))
            want = raw["position"] if k == "position" else passes.DERIVED[k](raw, info)
        g, w = np.asarray(got, np.float64), np.asarray(want, np.float64)
        fin = np.isfinite(w) & np.isfinite(g)
        if g.ndim == 3 and k != "position":  # storage bounds are per component
            err = np.abs(g - w)[fin]
        elif g.ndim == 3:
            fin = fin.all(-1)
            err = np.linalg.norm(g - w, axis=-1)[fin]
        else:
            with np.errstate(invalid="ignore"):
                err = np.abs(g - w)[fin]
        if units.get(k) == "rel" or k in ("position", "depth_euclidean"):
            scale = np.abs(w)[fin] if g.ndim == 2 else np.linalg.norm(w, axis=-1)[fin]
            err = err / np.maximum(scale, 1e-12)
        bound = keys.KEYS[k].storage.error
        note = " (relative)" if units.get(k) == "rel" or k in ("position", "depth_euclidean") else ""
        limit = f"{acc[k]:g} {units[k]}" if k in acc else ""
        ref = " vs Blender's position pass" if k == "position" else ""
        print(f"| `{k}` | {err.size} | {err.max(initial=0):.3g}{note}{ref} | {np.percentile(err, 99) if err.size else 0:.3g} | {bound:.3g} | {limit} |")

    # -- 3. codecs ------------------------------------------------------------------------------------
    print(f"\n## codecs: bytes per pixel (write / read ms), frame {f}\n")
    gt = store.encode({k: truth[k] for k in stored if keys.KEYS[k].file == layout.GT_FILE})
    mo = store.encode({k: truth[k] for k in stored if keys.KEYS[k].file == layout.MOTION_FILE})
    rgb_ch = {"RGB": rgb.astype(np.float16)}
    print("| channels | " + " | ".join(CODECS) + " | hdf5 gzip+shuffle |")
    print("|---|" + "---|" * (len(CODECS) + 1))
    for name, ch in (("gt.exr (depth, normal, instance)", gt), ("motion.exr (flow, scene flow, disparity change, masks)", mo),
                     ("gt + motion", {**gt, **mo}), ("rgb.exr (half RGB)", rgb_ch)):
        cells = []
        for c in CODECS:
            try:
                b, tw, tr, exact = exr_bytes(ch, c)
                cells.append(f"{b / n:.3f} ({tw:.0f}/{tr:.0f})" + ("" if exact else " lossy"))
            except Exception:  # a codec this OpenEXR cannot write for these pixel types
                cells.append("n/a")
        h5 = h5_bytes({k.replace('.', '_'): a for k, a in ch.items()}) / n if name != "rgb.exr (half RGB)" else h5_bytes({"RGB": rgb_ch["RGB"]}) / n
        print(f"| {name} | " + " | ".join(cells) + f" | {h5:.3f} |")

    if args.verify:
        from lfusd.truth.verify import verify

        t = time.perf_counter()
        reports = verify(out)
        rep = reports[next(iter(reports))]
        compared = rep.compared()
        print(f"\nlfusd verify on the stored dataset: {'passed' if rep.ok else 'FAILED'} ({time.perf_counter() - t:.0f} s; "
              f"pixels compared per key: {compared})")
        for line in rep.failures()[:10]:
            print("  " + line)
    if tmp:
        tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
