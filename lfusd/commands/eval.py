"""`lfusd eval --task disparity|flow|sceneflow|views --pred DIR --gt OUT [--protocol lfusd|hci|kitti|sintel|spring|basiclfsr|distgasr]`.

Prints the protocol's summary, one metric per line with how it was summarised (pooled or mean),
then the per-image rows where they fit the terminal, and writes JSON and CSV (default DIR/eval_<task>[_<protocol>].json and .csv).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..evaluation import score
from . import args as argtypes
from ..evaluation.protocols import PROTOCOLS
from ..evaluation.score import TASKS


def register(subparsers) -> None:
    p = subparsers.add_parser("eval", help="score predictions against a dataset's ground truth", description=score.__doc__.split("\n\n", 1)[1] + "\n" + __doc__.split("\n\n", 1)[1], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", required=True, choices=TASKS)
    p.add_argument("--pred", required=True, help="folder of predictions named <frame>_<row>_<col>.<ext>")
    p.add_argument("--gt", required=True, help="dataset folder (output of `lfusd render`), or a KITTI folder written by `lfusd export kitti` (with --protocol kitti)")
    p.add_argument("--protocol", default="lfusd", choices=PROTOCOLS, help="whose masks, NaN policy, percentiles, pooling and metric names to use (default lfusd, the native protocol)")
    p.add_argument("--json", default=None, help="write results as JSON here (default: PRED/eval_<task>[_<protocol>].json)")
    p.add_argument("--csv", default=None, help="write results as CSV here (default: PRED/eval_<task>[_<protocol>].csv)")
    argtypes.add_rig_option(p, "dataset")
    p.set_defaults(func=run)


def _cell(v) -> str:
    if isinstance(v, float):
        return f"{v:.4f}" if abs(v) < 1e6 or v != v else f"{v:.4g}"
    return str(v)


def format_table(scores: score.Scores, width: int, csv_path=None) -> str:
    """The summary one metric per line (metric, value, how it was summarised), which fits any
    terminal, then the per-image rows where they fit in ``width`` columns (else where to find them)."""
    how = {"pooled": "pooled over pixels", "mean": "mean of images"}
    metrics = [k for k in scores.summary if k not in ("scene", "frame", "row", "col", "pixels")]
    lines = [f"lfusd eval: {scores.task}, {scores.protocol} protocol, {len(scores)} image(s), "
             f"{scores.summary['pixels']} px compared"]
    name_w = max([len("metric"), *map(len, metrics)])
    vals = [_cell(scores.summary[k]) for k in metrics]
    val_w = max([len("summary"), *map(len, vals)])
    lines.append(f"{'metric':<{name_w}}  {'summary':>{val_w}}  summarised as")
    lines += [f"{k:<{name_w}}  {v:>{val_w}}  {how.get(scores.aggregation.get(k), '')}" for k, v in zip(metrics, vals)]
    cols = ["frame", "row", "col", *metrics, "pixels"]
    cells = [[_cell(r.get(k, "")) for k in cols] for r in scores]
    widths = [max(len(c), *(len(row[i]) for row in cells)) for i, c in enumerate(cols)]
    if sum(widths) + 2 * (len(cols) - 1) <= width:
        lines.append("")
        lines.append("  ".join(f"{c:>{w}}" for c, w in zip(cols, widths)))
        lines += ["  ".join(f"{c:>{w}}" for c, w in zip(row, widths)) for row in cells]
    elif csv_path is not None:
        lines += [f"the {len(scores)} per-image rows are too wide for {width} columns; they are in", f"  {csv_path}"]
    return "\n".join(lines)


def print_table(scores: score.Scores, csv_path=None) -> None:
    import shutil

    print(format_table(scores, shutil.get_terminal_size((80, 24)).columns, csv_path))


def run(args) -> int:
    scores = score.evaluate(args.gt, args.pred, args.task, rig=args.rig, protocol=args.protocol)
    pred = Path(args.pred)
    stem = f"eval_{args.task}" + ("" if args.protocol == "lfusd" else f"_{args.protocol}")
    csv_path = args.csv or pred / f"{stem}.csv"
    score.write_results(scores, args.json or pred / f"{stem}.json", csv_path)
    print_table(scores, csv_path)
    return 0
