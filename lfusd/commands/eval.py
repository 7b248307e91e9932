"""`lfusd eval --task disparity|flow|sceneflow|views --pred DIR --gt OUT`: score predictions against a dataset.

Prints a table and writes JSON and CSV (default DIR/eval_<task>.json and .csv).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..evaluation import score
from ..evaluation.score import TASKS, mean_row


def register(subparsers) -> None:
    p = subparsers.add_parser("eval", help="score predictions against a dataset's ground truth", description=score.__doc__.split("\n\n", 1)[1] + "\n" + __doc__.split("\n\n", 1)[1], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", required=True, choices=TASKS)
    p.add_argument("--pred", required=True, help="folder of predictions named <frame>_<row>_<col>.<ext>")
    p.add_argument("--gt", required=True, help="dataset folder (output of `lfusd render`)")
    p.add_argument("--json", default=None, help="write results as JSON here (default: PRED/eval_<task>.json)")
    p.add_argument("--csv", default=None, help="write results as CSV here (default: PRED/eval_<task>.csv)")
    p.add_argument("--rig", default=None, help="rig name, for a dataset that holds several rigs")
    p.set_defaults(func=run)


def print_table(rows: list[dict], task: str) -> None:
    mean = mean_row(rows)
    keys = list(dict.fromkeys(k for r in rows for k in r))
    try:
        from rich.console import Console
        from rich.table import Table

        t = Table(title=f"lfusd eval: {task}")
        for k in keys:
            t.add_column(k, justify="right")
        for r in rows + [mean]:
            t.add_row(*(f"{r[k]:.4f}" if isinstance(r.get(k), float) else str(r.get(k, "")) for k in keys))
        Console().print(t)
    except ImportError:  # rich is a dependency, but keep plain output possible
        print("\t".join(keys))
        for r in rows + [mean]:
            print("\t".join(f"{r[k]:.4f}" if isinstance(r.get(k), float) else str(r.get(k, "")) for k in keys))


def run(args) -> int:
    rows = score.evaluate(args.gt, args.pred, args.task, rig=args.rig)
    pred = Path(args.pred)
    score.write_results(rows, args.task, args.json or pred / f"eval_{args.task}.json", args.csv or pred / f"eval_{args.task}.csv")
    print_table(rows, args.task)
    return 0
