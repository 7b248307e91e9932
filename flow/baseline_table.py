"""Classical baselines on an lfusd dataset, printed as a results table in the literature's style.

    .venv/bin/python flow/baseline_table.py OUT [--frames 1 2] [--views all|cross] [--planes 64] [--asr 7]
    .venv/bin/python flow/baseline_table.py BENCH --submission SUB [--planes 48]   # = lfusd bench baseline BENCH -o SUB

Disparity: plane sweep over the views (PyTorch; CUDA when present), scored with the HCI metrics
(MSE x100, BadPix, Q25) over pixels with a surface. Optical flow: OpenCV DIS on the centre view
(EPE, Fl-all, >1px). Scene flow from the two disparity maps and DIS (EPE3D, Acc3DS/R, Outlier3D and
KITTI D1/D2/Fl/SF). View synthesis 2x2 -> NxN on the central NxN views: a plane sweep at each novel
view over the four corners, and angular blending, as PSNR/SSIM on Y (BT.601).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lfusd import LfusdError  # noqa: E402
from lfusd.evaluation.baselines import format_table, run_baselines  # noqa: E402
from lfusd.data.dataset import open_dataset  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("out", help="dataset folder")
    p.add_argument("--frames", type=int, nargs="*", default=None, help="frames to use (default: all)")
    p.add_argument("--views", default="all", choices=["all", "cross"], help="views for the disparity sweep")
    p.add_argument("--planes", type=int, default=64, help="disparity planes of the sweep")
    p.add_argument("--window", type=int, default=9, help="cost aggregation window of the disparity sweep")
    p.add_argument("--asr", type=int, default=7, help="N of the 2x2 -> NxN view-synthesis task")
    p.add_argument("--device", default=None, help="torch device (default: cuda if available)")
    p.add_argument("--rig", default=None, help="rig name, for a dataset with several rigs")
    p.add_argument("--json", default=None, help="also write the numbers here")
    p.add_argument("--submission", default=None, metavar="SUB",
                   help="OUT is a benchmark folder (lfusd bench make): write baseline (a) on its test split as a submission to SUB")
    a = p.parse_args(argv)
    if a.submission:
        from lfusd.bench.baseline import write_baseline

        try:
            n = write_baseline(a.out, a.submission, n_planes=a.planes, window=a.window, device=a.device)
        except LfusdError as e:
            print(f"baseline_table: error: {e}", file=sys.stderr)
            return 2
        print(f"{a.submission}: {n} files; score them with `lfusd bench score {a.submission} --bench {a.out}`")
        return 0
    try:
        ds = open_dataset(a.out, a.rig)
        t0 = time.time()
        res = run_baselines(ds, frames=a.frames, views=a.views, n_planes=a.planes, asr=a.asr, window=a.window, device=a.device, log=lambda m: print(m, file=sys.stderr))
    except LfusdError as e:
        print(f"baseline_table: error: {e}", file=sys.stderr)
        return 2
    print(format_table(res, f"Baselines on {Path(a.out).name} ({ds.rig.rows}x{ds.rig.cols} views, {ds.rig.width}x{ds.rig.height}, {time.time() - t0:.1f} s)"))
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
