"""The `lfusd` command: a thin dispatcher over lfusd.commands.* modules.

Each command module in lfusd/commands defines ``register(subparsers)``, adding its subcommand with
``set_defaults(func=...)``; ``func(args)`` returns an exit code. Arguments are typed by
:mod:`lfusd.commands.args`.

Exit codes: 0 success; 1 ``check``/``verify`` found violations; 2 bad input (usage or an
:class:`LfusdError`, one line); 3 an unexpected error, a bug (one line naming a file that holds the
traceback); 130 interrupted (SIGINT), 143 terminated (SIGTERM); both stop the workers first.
``--traceback`` (anywhere on the command line) or ``LFUSD_DEBUG=1`` prints the full chained
traceback of an error, including causes hidden by ``raise ... from None``.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import importlib
import logging
import os
import pkgutil
import signal
import sys
import threading
import tempfile
import traceback

from . import __version__, commands
from .commands.args import Parser
from .errors import LfusdError

EXIT_OK, EXIT_VIOLATIONS, EXIT_ERROR, EXIT_BUG, EXIT_INTERRUPTED = 0, 1, 2, 3, 130
EXIT_TERMINATED = 143  # 128 + SIGTERM


class Terminated(BaseException):
    """SIGTERM, raised in the main thread so that clean-up (workers, pools, Ray tasks) runs as for Ctrl-C."""


def _on_sigterm(signum, frame) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # a second SIGTERM must not cut the clean-up short
    raise Terminated()


class _CliParser(Parser):
    """Every lfusd (sub)command also takes the global options, anywhere on the command line."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # SUPPRESS: a subcommand that is not given the option leaves the top level's value alone.
        self.add_argument("--traceback", action="store_true", default=argparse.SUPPRESS,
                          help="on an error, print the full traceback with its causes (or set LFUSD_DEBUG=1)")
        self.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS,
                          help="log informational messages (-vv: debugging messages)")


class _StderrHandler(logging.Handler):
    """One line per record on the current sys.stderr: ``lfusd: warning: ...``."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            sys.stderr.write(f"lfusd: {record.levelname.lower()}: {record.getMessage()}\n")
        except Exception:
            self.handleError(record)


def configure_logging(verbose: int = 0) -> None:
    """Route the ``lfusd`` loggers to stderr: warnings and above, ``-v`` info, ``-vv`` debug."""
    log = logging.getLogger("lfusd")
    for h in [h for h in log.handlers if isinstance(h, _StderrHandler)]:
        log.removeHandler(h)
    log.addHandler(_StderrHandler())
    log.setLevel(logging.DEBUG if verbose >= 2 else logging.INFO if verbose == 1 else logging.WARNING)
    log.propagate = False  # one line per message, whatever the root logger does


def build_parser() -> argparse.ArgumentParser:
    parser = _CliParser(prog="lfusd", description="Light-field datasets from USD stages.",
                        epilog="exit codes: 0 ok, 1 check/verify violations, 2 bad input, 3 internal error, 130 interrupted, 143 terminated")
    parser.add_argument("--version", action="version", version=f"lfusd {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_CliParser)
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        if hasattr(module, "register"):  # args.py is the shared argument layer, not a command
            module.register(sub)
    return parser


def full_traceback(e: BaseException) -> str:
    """The traceback of ``e`` with every cause and context, also those hidden by ``raise ... from None``."""
    seen, todo = set(), [e]
    while todo:
        x = todo.pop()
        if x is None or id(x) in seen:
            continue
        seen.add(id(x))
        x.__suppress_context__ = False
        todo += [x.__cause__, x.__context__]
    return "".join(traceback.format_exception(e))


def _caused_by_stop(e: BaseException) -> type | None:
    """KeyboardInterrupt or Terminated when one is among the causes or contexts of ``e``, else None."""
    seen = set()
    while e is not None and id(e) not in seen:
        if isinstance(e, (KeyboardInterrupt, Terminated)):
            return type(e)
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return None


def _stopped(code: int, argv: list[str] | None) -> int:
    """The exit of an interrupted or terminated run. When it is the process itself (``lfusd``, argv
    None) and it used Ray, its clean-up is done (lfusd.render.executors.run_ray shut Ray down): end
    now, without the interpreter's finalisation, in which Ray's core worker threads abort or crash
    after an interrupt (measured: exit -6, -11, or -2 from a SIGINT Ray had deferred) instead of
    ``code``. A call from Python (tests, argv given) just returns ``code``."""
    if argv is None and "ray" in sys.modules:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        import atexit

        # Python's exit functions still run (multiprocessing releases its pools' semaphores, else its
        # resource tracker prints a warning about leaked ones); the C++ finalisation does not
        with contextlib.suppress(BaseException):
            atexit._run_exitfuncs()
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        logging.shutdown()
        os._exit(code)
    return code


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:  # usage errors and --help
        return int(e.code or 0)
    configure_logging(getattr(args, "verbose", 0))
    debug = getattr(args, "traceback", False) or os.environ.get("LFUSD_DEBUG", "") not in ("", "0")
    if not getattr(args, "func", None):
        parser.print_help()
        return EXIT_ERROR
    in_main = threading.current_thread() is threading.main_thread()  # only it may set handlers
    previous = signal.signal(signal.SIGTERM, _on_sigterm) if in_main else None
    try:
        return int(args.func(args) or 0)
    except Terminated:
        print("lfusd: terminated; rerun the same command to resume", file=sys.stderr)
        return _stopped(EXIT_TERMINATED, argv)
    except LfusdError as e:
        if debug:
            sys.stderr.write(full_traceback(e))
        print(f"lfusd: error: {e}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print("lfusd: interrupted; rerun the same command to resume", file=sys.stderr)
        return _stopped(EXIT_INTERRUPTED, argv)
    except OSError as e:  # the machine, not lfusd: a full disk, a read-only folder, a missing path
        if debug:
            sys.stderr.write(full_traceback(e))
        what = f"{e.filename}: " if e.filename else ""
        fix = "free disk space" if e.errno in (errno.ENOSPC, errno.EDQUOT) else "check the path and its permissions"
        print(f"lfusd: error: {what}{e.strerror or e}; {fix}, then rerun", file=sys.stderr)
        return EXIT_ERROR
    except Exception as e:  # a bug: keep the message short, the traceback in a file for the report
        stop = _caused_by_stop(e)  # a Ctrl-C or SIGTERM a library turned into its own error (Ray: RuntimeError, SystemError)
        if stop is Terminated:
            print("lfusd: terminated; rerun the same command to resume", file=sys.stderr)
            return _stopped(EXIT_TERMINATED, argv)
        if stop is KeyboardInterrupt:
            print("lfusd: interrupted; rerun the same command to resume", file=sys.stderr)
            return _stopped(EXIT_INTERRUPTED, argv)
        text = full_traceback(e)
        if debug:
            sys.stderr.write(text)
        first = (str(e).splitlines() or [""])[0]
        try:
            with tempfile.NamedTemporaryFile("w", prefix="lfusd-traceback-", suffix=".txt", delete=False) as f:
                f.write(text)
            where = f"the traceback is in {f.name}"
        except OSError:  # no room for the file either: the summary line must still come out
            where = "rerun with --traceback for the traceback"
        print(f"lfusd: internal error: {type(e).__name__}: {first}; {where} (please report it)", file=sys.stderr)
        return EXIT_BUG
    finally:
        if in_main and argv is None:
            # the program itself is done: a signal during the interpreter's exit (Ray's shutdown takes
            # seconds) must not turn its result into a traceback or a kill (exit -2, -15)
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
        elif in_main:
            signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)


if __name__ == "__main__":
    sys.exit(main())  # argv None: the process itself (see _stopped)
