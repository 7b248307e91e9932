"""`lfusd eval --task disparity|flow|sceneflow|views --pred DIR --gt OUT [--protocol lfusd|hci|kitti|sintel|spring|basiclfsr|distgasr]`.

Prints a table whose last row is the protocol's summary (pooled or mean, as the caption says) and
writes JSON and CSV (default DIR/eval_<task>[_<protocol>].json and .csv).
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
    return f"{v:.4f}" if isinstance(v, float) else str(v)


def print_table(scores: score.Scores) -> None:
    rows = list(scores) + [scores.summary]
    keys = list(dict.fromkeys(k for r in rows for k in r))
    note = score.aggregation_note(scores)
    try:
        from rich.console import Console
        from rich.table import Table

        t = Table(title=f"lfusd eval: {scores.task}, {scores.protocol} protocol", caption=note)
        for k in keys:
            t.add_column(k, justify="right")
        for r in rows:
            t.add_row(*(_cell(r.get(k, "")) for k in keys))
        Console().print(t)
    except ImportError:  # rich is a dependency, but keep plain output possible
        print("\t".join(keys))
        for r in rows:
            print("\t".join(_cell(r.get(k, "")) for k in keys))
        print(note)


def run(args) -> int:
    scores = score.evaluate(args.gt, args.pred, args.task, rig=args.rig, protocol=args.protocol)
    pred = Path(args.pred)
    stem = f"eval_{args.task}" + ("" if args.protocol == "lfusd" else f"_{args.protocol}")
    score.write_results(scores, args.json or pred / f"{stem}.json", args.csv or pred / f"{stem}.csv")
    print_table(scores)
    return 0
