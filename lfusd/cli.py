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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="lfusd", description="Light-field datasets from USD stages.")
    parser.add_argument("--version", action="version", version=f"lfusd {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        importlib.import_module(f"{commands.__name__}.{info.name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
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
