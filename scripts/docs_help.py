"""Paste `lfusd ... --help` into the command pages of the docs site, between markers.

A page holds, for each command it documents::

    <!-- BEGIN help: lfusd rig add -->
    (generated: a text block with the command's help)
    <!-- END help -->

`python scripts/docs_help.py` rewrites every such block in docs/ from the current parser;
tests/test_docs.py fails when a block differs from it, or when a command has no block. Help is
formatted at a fixed width, so the pages do not depend on the terminal they were made in.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
WIDTH = 100
BLOCK = re.compile(r"(<!-- BEGIN help: (?P<cmd>[^>]+?) -->\n)(?P<body>.*?)(<!-- END help -->)", re.S)


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """Name -> parser of each subcommand; an alias (`lfusd flow`, the old name of `lfusd derive`)
    shares its command's parser and is documented with it."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            out, seen = {}, set()
            for name, sub in action.choices.items():  # a command's own name comes before its aliases
                if id(sub) not in seen:
                    seen.add(id(sub))
                    out[name] = sub
            return out
    return {}


def commands() -> dict[str, argparse.ArgumentParser]:
    """The top-level parser ("lfusd") and every command line that runs something ("lfusd render",
    "lfusd rig add", ...), each with its parser."""
    from lfusd.cli import build_parser

    out, todo = {}, [("lfusd", build_parser())]
    while todo:
        name, parser = todo.pop()
        subs = _subparsers(parser)
        if not subs or name == "lfusd":
            out[name] = parser
        todo += [(f"{name} {sub}", p) for sub, p in subs.items()]
    return dict(sorted(out.items()))


def help_text(parser: argparse.ArgumentParser) -> str:
    """The parser's --help at WIDTH columns, whatever the terminal."""
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(WIDTH)  # argparse's formatter reads the width from COLUMNS
    try:
        return parser.format_help().rstrip() + "\n"
    finally:
        if old is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = old


def block(text: str) -> str:
    return f"```text\n{text}```\n"


def documented() -> dict[str, tuple[Path, str]]:
    """Command -> (page, the block's current body) for every help block in docs/."""
    found = {}
    for page in sorted(DOCS.rglob("*.md")):
        for m in BLOCK.finditer(page.read_text()):
            found[m["cmd"].strip()] = (page, m["body"])
    return found


def update() -> list[Path]:
    """Rewrite every help block from the parser; returns the pages that changed."""
    parsers, changed = commands(), []
    for page in sorted(DOCS.rglob("*.md")):
        text = page.read_text()

        def fill(m):
            cmd = m["cmd"].strip()
            if cmd not in parsers:
                sys.exit(f"{page}: no command {cmd!r}; known: {', '.join(parsers)}")
            return m.group(1) + block(help_text(parsers[cmd])) + m.group(4)

        new = BLOCK.sub(fill, text)
        if new != text:
            page.write_text(new)
            changed.append(page)
    return changed


if __name__ == "__main__":
    for p in update():
        print(f"updated {p.relative_to(ROOT)}")
