"""Statistics of a dataset's motion and disparity: magnitudes, masks and disparity ranges (see flow/README.md)."""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

PCTS = (1, 50, 99, 100)


def _pcts(x: np.ndarray) -> dict:
    x = x[np.isfinite(x)]
    if x.size == 0:
        return {"count": 0}
    return {"count": int(x.size), **{f"p{p}": float(np.percentile(x, p)) for p in PCTS}}


def _read(ds, f, v, key):
    from lfusd.errors import LfusdError

    try:
        return ds.read(f, v, key)
    except (KeyError, FileNotFoundError, LfusdError):
        return None


def dataset_stats(ds, frames=None, views=None, baseline: float | None = None) -> dict:
    """Motion magnitudes, mask fractions and disparity ranges of a dataset reader.

    Disparity is read from the 'disparity' key when present, else computed as f_px * b / depth
    (``baseline`` or ``ds.baseline``). ``rig_span_px``: the largest disparity times the rig's span
    in baseline steps (cols - 1 on a uniform grid, taken from the views' column indices), the
    largest shift of a point between the outermost views.
    """
    frames = [int(f) for f in (frames or ds.frames)]
    views = [tuple(v) for v in (views or ds.views)]
    baseline = baseline if baseline is not None else getattr(ds, "baseline", None)
    acc: dict[str, list] = {k: [] for k in ("flow_fwd", "flow_bwd", "scene_flow", "disparity_change", "disparity")}
    fracs: dict[str, list] = {k: [] for k in ("valid_fwd", "valid_bwd", "occlusion_fwd", "occlusion_bwd")}
    per_view = {}
    for v in views:
        dmin, dmax = np.inf, -np.inf
        for f in frames:
            depth = _read(ds, f, v, "depth")
            fg = None if depth is None else np.isfinite(depth) & (np.asarray(depth) < 1e9)
            disp = _read(ds, f, v, "disparity")
            if disp is None and depth is not None and baseline:
                with np.errstate(divide="ignore"):
                    disp = float(np.asarray(ds.intrinsics(v))[0, 0]) * baseline / np.asarray(depth, np.float64)
            if disp is not None and fg is not None:
                d = np.asarray(disp)[fg]
                acc["disparity"].append(d)
                if d.size:
                    dmin, dmax = min(dmin, float(d.min())), max(dmax, float(d.max()))
            for key in ("flow_fwd", "flow_bwd", "scene_flow"):
                a = _read(ds, f, v, key)
                ok = _read(ds, f, v, "valid_bwd" if key == "flow_bwd" else "valid_fwd")
                if a is not None and ok is not None:
                    acc[key].append(np.linalg.norm(np.asarray(a, np.float64), axis=-1)[np.asarray(ok, bool)])
            a, ok = _read(ds, f, v, "disparity_change"), _read(ds, f, v, "valid_fwd")
            if a is not None and ok is not None:
                acc["disparity_change"].append(np.asarray(a, np.float64)[np.asarray(ok, bool)])
            for key in fracs:
                m = _read(ds, f, v, key)
                if m is not None and fg is not None and fg.any():
                    fracs[key].append(float(np.asarray(m, bool)[fg].mean()))
        per_view[f"{v[0]},{v[1]}"] = {"disparity_min": dmin, "disparity_max": dmax}
    out = {k: _pcts(np.concatenate(x)) if x else {"count": 0} for k, x in acc.items()}
    out["fractions_of_foreground"] = {k: float(np.mean(x)) if x else None for k, x in fracs.items()}
    cols = sorted({v[1] for v in views})
    span = (max(cols) - min(cols)) if cols else 0
    dmax = out["disparity"].get("p100")
    out["rig"] = {"views": len(views), "column_span_steps": span, "disparity_max_per_step": dmax, "rig_span_px": None if dmax is None else dmax * span}
    out["per_view"] = per_view
    return out


def main(argv: list[str] | None = None) -> int:
    from lfusd.camera import parse_frames, parse_view
    from lfusd.data.dataset import open_datasets
    from lfusd.errors import LfusdError

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("out", help="dataset folder")
    ap.add_argument("--frames", help="e.g. 1-10,15 (default: all)")
    ap.add_argument("--views", nargs="+", metavar="R,C")
    ap.add_argument("--rig", help="rig (default: every rig of the dataset)")
    ap.add_argument("--json", help="write the statistics as JSON here (one entry per rig)")
    a = ap.parse_args(argv)
    try:
        per_rig = {getattr(ds, "rig_name", "rig"): dataset_stats(ds, parse_frames(a.frames) if a.frames else None, [parse_view(v) for v in a.views] if a.views else None) for ds in open_datasets(a.out, a.rig)}
    except LfusdError as e:
        print(f"stats: error: {e}", file=sys.stderr)
        return 2
    for name, s in per_rig.items():
        print(f"rig {name}:")
        _print(s)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(per_rig, f, indent=1)
    return 0


def _print(s: dict) -> None:
    for key in ("flow_fwd", "flow_bwd", "scene_flow", "disparity_change", "disparity"):
        st = s[key]
        unit = "m" if key == "scene_flow" else "px"
        vals = "  ".join(f"p{p} {st[f'p{p}']:.4g}" for p in PCTS) if st["count"] else "no data"
        print(f"{key:<17} {unit:<3} n={st['count']:<9} {vals}")
    print("foreground fractions: " + ", ".join(f"{k} {v:.3f}" for k, v in s["fractions_of_foreground"].items() if v is not None))
    r = s["rig"]
    if r["disparity_max_per_step"] is not None:
        print(f"rig: {r['views']} views, column span {r['column_span_steps']} steps, max disparity {r['disparity_max_per_step']:.3g} px/step, "
              f"max shift between outermost views {r['rig_span_px']:.3g} px")


if __name__ == "__main__":
    sys.exit(main())
