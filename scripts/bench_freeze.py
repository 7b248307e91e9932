"""Freeze a benchmark definition: generate its stages and record their sha256 in
lfusd/bench/definitions/NAME.digests.json (a new benchmark version when the generators changed).

    PYTHONPATH=$PWD .venv/bin/python scripts/bench_freeze.py NAME [NAME ...]
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lfusd.bench.make import DEFINITIONS, load_definition, stage_digests  # noqa: E402
from lfusd.errors import LfusdError  # noqa: E402


def main(argv: list[str]) -> int:
    for name in argv:
        path = DEFINITIONS / f"{name}.digests.json"
        before = path.read_text() if path.is_file() else None
        path.write_text(json.dumps({"stages": {}}) + "\n")  # load_definition needs the file; filled below
        try:
            d = load_definition(name)
            with tempfile.TemporaryDirectory() as tmp:
                digests = stage_digests(d, Path(tmp))
        except (LfusdError, KeyboardInterrupt) as e:
            if before is None:
                path.unlink()
            else:
                path.write_text(before)  # the frozen digests stay as they were
            print(f"bench_freeze: error: {e}", file=sys.stderr)
            return 2
        path.write_text(json.dumps({"stages": digests}, indent=1) + "\n")
        print(f"{path}: {len(digests)} stages")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
