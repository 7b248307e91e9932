"""`ruff check` passes on the whole repository, with the rule set of pyproject.toml ([tool.ruff.lint])."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_ruff_check_passes():
    r = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "--output-format", "concise", str(ROOT)],
                       cwd=ROOT, capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, r.stdout + r.stderr


def test_the_rule_set_finds_defects(tmp_path):
    """Not a no-op: the configured rules flag an unused import, an undefined name and a mutable default."""
    bad = tmp_path / "bad.py"
    bad.write_text("import os\n\n\ndef f(x=[]):\n    return undefined_name + x\n")
    r = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "--output-format", "concise",
                        "--config", str(ROOT / "pyproject.toml"), str(bad)], cwd=tmp_path, capture_output=True, text=True, timeout=240)
    assert r.returncode == 1 and all(code in r.stdout for code in ("F401", "F821", "B006")), r.stdout + r.stderr
