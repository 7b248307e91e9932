"""Verification report of a dataset's motion ground truth against its stage (see flow/README.md)."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict


def to_markdown(report) -> str:
    """Markdown: a summary table per key and class, then the failures."""
    lines = ["| key | class | pixels | median | p99 | max | limit | ok |", "|---|---|---:|---:|---:|---:|---:|---|"]
    for e in report.summary():
        lines.append(
            f"| {e['key']} | {e['label'] or 'unlabelled'} | {e['count']} | {e['median']:.3g} | {e['p99']:.3g} | "
            f"{e['max']:.3g} | {e['threshold']:.3g} | {'yes' if e['ok'] else '**no**'} |"
        )
    fails = report.failures()
    lines += ["", f"**{len(fails)} failing rows**" if fails else "All checks passed."]
    lines += [f"- {f}" for f in fails]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    from lfusd.camera import parse_frames, parse_view
    from lfusd.errors import LfusdError
    from lfusd.truth.verify import VerifyReport, verify

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("out", help="dataset folder")
    ap.add_argument("--stage", help="stage the dataset was rendered from (default: the one it records)")
    ap.add_argument("--frames", help="e.g. 1-10,15 (default: all)")
    ap.add_argument("--views", nargs="+", metavar="R,C")
    ap.add_argument("--rig", help="rig (default: every rig of the dataset)")
    ap.add_argument("--json", help="write every row (frame, view, key, class) as JSON here")
    ap.add_argument("--markdown", help="write the summary table as Markdown here")
    a = ap.parse_args(argv)
    try:
        frames = parse_frames(a.frames) if a.frames else None
        views = [parse_view(v) for v in a.views] if a.views else None
        reports = verify(a.out, stage=a.stage, rig=a.rig, frames=frames, views=views)
    except LfusdError as e:
        print(f"verify_report: error: {e}", file=sys.stderr)
        return 2
    report = VerifyReport([row for r in reports.values() for row in r.rows])
    print(report.table())
    for line in report.failures():
        print(f"FAIL {line}")
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"ok": report.ok, "rows": [asdict(r) | {"ok": r.ok} for r in report.rows], "summary": report.summary()}, f, indent=1, default=float)
    if a.markdown:
        with open(a.markdown, "w") as f:
            f.write(to_markdown(report))
    return 0 if report.ok else 1


if __name__ == "__main__":
    sys.exit(main())
