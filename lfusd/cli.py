"""The `lfusd` command: a thin dispatcher over lfusd.commands.* modules.

Each command module in lfusd/commands defines ``register(subparsers)``, adding its subcommand with
``set_defaults(func=...)``; ``func(args)`` returns an exit code. Arguments are typed by
:mod:`lfusd.commands.args`.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from . import __version__, commands
from .commands.args import Parser
from .errors import LfusdError


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="lfusd", description="Light-field datasets from USD stages.")
    parser.add_argument("--version", action="version", version=f"lfusd {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        if hasattr(module, "register"):  # args.py is the shared argument layer, not a command
            module.register(sub)
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
