"""The `lfusd` command: a thin dispatcher over lfusd.commands.* modules.

Each module in lfusd/commands defines ``register(subparsers)``, adding its subcommand with
``set_defaults(func=...)``; ``func(args)`` returns an exit code.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from . import __version__, commands
from .errors import LfusdError


class _Parser(argparse.ArgumentParser):
    """argparse with usage errors on one line, like every other lfusd error."""

    def error(self, message: str):
        self.exit(2, f"lfusd: error: {message} (see '{self.prog} --help')\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="lfusd", description="Light-field datasets from USD stages.")
    parser.add_argument("--version", action="version", version=f"lfusd {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        importlib.import_module(f"{commands.__name__}.{info.name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:  # usage errors and --help
        return int(e.code or 0)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except LfusdError as e:
        print(f"lfusd: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("lfusd: interrupted; rerun the same command to resume", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
