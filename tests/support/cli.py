"""Running the CLI in-process and checking its one-line errors."""

from __future__ import annotations

import re

from lfusd.cli import main


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def assert_one_line_error(code: int, err: str, *needles: str) -> None:
    assert code != 0
    # --quiet progress logs ("lfusd: 3/9 views, ...") may precede the error line
    lines = [ln for ln in err.splitlines() if ln.strip() and not re.match(r"lfusd: \d+/\d+ views", ln)]
    assert len(lines) == 1 and lines[0].startswith("lfusd: error: "), err
    for n in needles:
        assert n in lines[0], lines[0]
