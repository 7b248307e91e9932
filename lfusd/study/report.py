"""Rank a study's arrangements and report them: terminal table, report.md, heat maps, plots.

Ranking, per task (an arrangement's scores are means over positions and frames):

- ``disparity``: lowest relative disparity error of the centre view (all depth bands);
- ``sceneflow``: lowest scene-flow end-point error (EPE3D);
- ``views``: the least redundant arrangement whose views can still be recovered: arrangements
  whose mean held-out PSNR reaches ``--min-psnr`` come first, least redundant (lowest PSNR, the
  most new content per camera) first; the rest follow, best recovered first.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .. import layout
from ..files import atomic_write
from .score import Bands, finite_mean

SCALARS = ("disp_err", "disp_bad", "psnr", "ssim", "coverage", "holes", "outside", "parallax_nn", "parallax_far", "epe3d", "outlier3d")
LISTS = ("disp_err_band", "disp_bad_band", "psnr_band", "psnr_views", "ssim_views", "coverage_views")
COUNTS = ("n_disp_px", "n_views_px", "n_visibility_px", "n_parallax_px", "n_sceneflow_px", "n_band_px")


def _mean_lists(lists: list[list]) -> list:
    return [finite_mean(col) for col in zip(*lists)] if lists else []


def aggregate(entries: list[dict]) -> dict:
    """One arrangement's scores over its (position, frame) entries: means, elementwise means of lists, summed pixel counts."""
    out = {}
    for k in SCALARS:
        vals = [e[k] for e in entries if k in e]
        if vals:
            out[k] = finite_mean(vals)
    for k in LISTS:
        vals = [e[k] for e in entries if k in e]
        if vals:
            out[k] = _mean_lists(vals)
    for k in COUNTS:
        vals = [e[k] for e in entries if k in e]
        if vals:
            out[k] = [int(sum(c)) for c in zip(*vals)] if isinstance(vals[0], list) else int(sum(vals))
    return out


def sort_key(task: str, min_psnr: float):
    big = float("inf")

    def key(row):
        if task == "views":
            p = row.get("psnr")
            p = -big if p is None else p
            return (0, p) if p >= min_psnr else (1, -p)
        v = row.get("epe3d" if task == "sceneflow" else "disp_err")
        return (0, big if v is None else v)

    return key


def rank(candidates, results: dict[str, dict], frames, task: str, min_psnr: float, bands: Bands) -> list[dict]:
    """Arrangement rows, best first, each with its scores and ``rank``."""
    rows = {}
    for c in candidates:
        a = c.arrangement
        row = rows.setdefault(a.name, {"arrangement": a.name, **a.to_dict(), "grid": [c.spec.rows, c.spec.cols], "_entries": []})
        row["_entries"] += [results[c.name][str(t)] for t in frames if str(t) in results[c.name]]
    out = []
    for row in rows.values():
        entries = row.pop("_entries")
        row |= aggregate(entries)
        if task == "views":
            row["recovered"] = row.get("psnr") is not None and row["psnr"] >= min_psnr
        out.append(row)
    out.sort(key=sort_key(task, min_psnr))
    for i, row in enumerate(out, 1):
        row["rank"] = i
    return out


def _f(v, fmt="{:.1f}") -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else fmt.format(v)


COLUMNS = [  # header, key, format
    ("disp err %", "disp_err", "{:.1f}"), ("bad %", "disp_bad", "{:.1f}"), ("held-out PSNR", "psnr", "{:.1f}"),
    ("SSIM", "ssim", "{:.3f}"), ("coverage %", "coverage", "{:.1f}"), ("holes %", "holes", "{:.1f}"),
    ("parallax nn px", "parallax_nn", "{:.2f}"), ("parallax far px", "parallax_far", "{:.1f}"),
]


def _columns(task: str):
    return COLUMNS + ([("EPE3D m", "epe3d", "{:.3f}")] if task == "sceneflow" else [])


def table(ranked: list[dict], task: str, top: int | None = None):
    """A rich Table of the ranked arrangements."""
    from rich.table import Table

    t = Table(title=f"rig study, task {task} (best first)")
    t.add_column("#", justify="right")
    t.add_column("arrangement")
    for head, _, _ in _columns(task):
        t.add_column(head, justify="right")
    for row in ranked[:top]:
        t.add_row(str(row["rank"]), row["arrangement"], *[_f(row.get(k), fmt) for _, k, fmt in _columns(task)])
    return t


def markdown(req, ranked: list[dict], skipped, bands: Bands, cameras: int, views_total: int) -> str:
    task = req.task
    lines = [f"# Rig study of `{req.stage}`", "",
             f"Task **{task}**; grid {req.grid[0]}x{req.grid[1]} at {req.resolution[0]}x{req.resolution[1]} px, {req.samples} samples; "
             f"baselines {', '.join(f'{b:g}' for b in req.baselines)} m; spacings {', '.join(req.spacings)}; layouts {', '.join(req.layouts)}; "
             f"axes {', '.join(req.axes)}; frames {', '.join(map(str, req.frames or []) ) or 'the first'}.",
             f"{len(ranked)} arrangements, {views_total} views, {cameras} distinct cameras rendered.", "",
             "Ranking: " + {"disparity": "lowest relative disparity error of the centre view.",
                            "sceneflow": "lowest scene-flow end-point error.",
                            "views": f"least redundant first among arrangements whose held-out views are recovered "
                                     f"(mean PSNR >= {req.min_psnr:g} dB), then the rest."}[task], "",
             "| # | arrangement | " + " | ".join(h for h, _, _ in _columns(task)) + " |",
             "|---|---|" + "---:|" * len(_columns(task))]
    for row in ranked:
        lines.append(f"| {row['rank']} | {row['arrangement']} | " + " | ".join(_f(row.get(k), fmt) for _, k, fmt in _columns(task)) + " |")
    counts = ranked[0] if ranked else {}
    lines += ["", f"Pixels compared (first row): disparity {counts.get('n_disp_px', 0)}, held-out views {counts.get('n_views_px', 0)}, "
                  f"visibility {counts.get('n_visibility_px', 0)}" + (f", scene flow {counts.get('n_sceneflow_px', 0)}" if task == "sceneflow" else "") + ".", ""]
    per_band = ", ".join(f"{lab} {n}" for lab, n in zip(bands.labels, counts.get("n_band_px", [0] * len(bands.labels))))
    lines += ["## By depth band", "",
              "Relative disparity error (%) of the centre view / held-out PSNR (dB) of all views, by true depth. "
              f"Centre-view pixels per band (first row): {per_band}.", "",
              "| arrangement | " + " | ".join(bands.labels) + " |",
              "|---|" + "---:|" * len(bands.labels)]
    for row in ranked:
        cells = [f"{_f(e)} / {_f(p)}" for e, p in zip(row.get("disp_err_band", []), row.get("psnr_band", []))]
        lines.append(f"| {row['arrangement']} | " + " | ".join(cells) + " |")
    if skipped:
        lines += ["", "## Impossible candidates", ""] + [f"- {n}: {why}" for n, why in skipped]
    lines += ["", f"![score against baseline]({layout.STUDY_PLOT})", "",
              f"Per-view redundancy (held-out PSNR over the grid): `{layout.STUDY_HEATMAPS}/<arrangement>.png`, "
              f"all of them in `{layout.STUDY_HEATMAPS}/overview.png`.", ""]
    return "\n".join(lines)


def _heatmap(ax, row, vmin, vmax):
    rows, cols = row["grid"]
    vals = np.array([np.nan if v is None else v for v in row.get("psnr_views", [])], float)
    im = ax.imshow(vals.reshape(rows, cols), vmin=vmin, vmax=vmax, cmap="magma")
    ax.set_xticks(range(cols))
    ax.set_yticks(range(rows))
    ax.tick_params(labelsize=5)
    return im


def plots(out: Path, ranked: list[dict], bands: Bands) -> None:
    """score_vs_baseline.png (per depth band) and the heat maps."""
    from matplotlib.figure import Figure

    nb = len(bands.labels)
    fig = Figure(figsize=(3.2 * nb, 6.0), constrained_layout=True)
    axs = fig.subplots(2, nb, squeeze=False)
    groups: dict[str, list[dict]] = {}
    for row in ranked:
        groups.setdefault(f"{row['spacing']}/{row['layout']}/{row['axes']}", []).append(row)
    for label, rows in sorted(groups.items()):
        rows = sorted(rows, key=lambda r: r["baseline"])
        b = [r["baseline"] for r in rows]
        for k in range(nb):
            for ax, key in ((axs[0, k], "disp_err_band"), (axs[1, k], "psnr_band")):
                y = [np.nan if r.get(key) is None or r[key][k] is None else r[key][k] for r in rows]
                ax.plot(b, y, marker="o", label=label)
    from matplotlib.ticker import NullLocator

    ticks = sorted({r["baseline"] for r in ranked})
    for k in range(nb):
        axs[0, k].set_title(f"depth {bands.labels[k]}")
        for ax in axs[:, k]:
            ax.set_xscale("log")
            ax.set_xticks(ticks, [f"{t:g}" for t in ticks])
            ax.xaxis.set_minor_locator(NullLocator())
            ax.set_xlabel("baseline (m)")
            if not ax.lines or all(np.all(np.isnan(ln.get_ydata())) for ln in ax.lines):
                ax.text(0.5, 0.5, "no pixels at this depth", transform=ax.transAxes, ha="center", fontsize=8)
    axs[0, 0].set_ylabel("relative disparity error (%)")
    axs[1, 0].set_ylabel("held-out view PSNR (dB)")
    axs[0, -1].legend(fontsize=6)
    _save(fig, out / layout.STUDY_PLOT)

    hm = out / layout.STUDY_HEATMAPS
    hm.mkdir(exist_ok=True)
    allv = [v for r in ranked for v in r.get("psnr_views", []) if v is not None]
    vmin, vmax = (min(allv), max(allv)) if allv else (0, 1)
    for row in ranked:
        fig = Figure(figsize=(3.6, 3.0), constrained_layout=True)
        ax = fig.subplots()
        im = _heatmap(ax, row, vmin, vmax)
        ax.set_title(f"#{row['rank']} {row['arrangement']}", fontsize=7)
        fig.colorbar(im, ax=ax, label="held-out PSNR (dB)")
        _save(fig, hm / f"{row['arrangement']}.png")
    n = len(ranked)
    cols = int(math.ceil(math.sqrt(n)))
    rws = int(math.ceil(n / cols))
    fig = Figure(figsize=(2.0 * cols + 1, 2.0 * rws), constrained_layout=True)
    axs = fig.subplots(rws, cols, squeeze=False)
    im = None
    for ax in axs.ravel():
        ax.axis("off")
    for ax, row in zip(axs.ravel(), ranked):
        ax.axis("on")
        im = _heatmap(ax, row, vmin, vmax)
        ax.set_title(f"#{row['rank']} {row['arrangement']}", fontsize=5)
    if im is not None:
        fig.colorbar(im, ax=axs, label="held-out PSNR (dB): redundancy")
    _save(fig, hm / "overview.png")


def write(req, ranked, candidates, skipped, bands: Bands, cameras: int, views_total: int) -> Path:
    """report.md and the figures in the study folder; returns the report's path."""
    plots(req.out, ranked, bands)
    path = req.out / layout.STUDY_REPORT
    atomic_write(path, markdown(req, ranked, skipped, bands, cameras, views_total))
    return path


def _save(fig, path: Path) -> None:
    """A figure as PNG, written whole under a new temporary name (never through a file found there)."""
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png", dpi=110))
