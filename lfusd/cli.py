"""The `lfusd` command: a thin dispatcher over lfusd.commands.* modules.

Each command module in lfusd/commands defines ``register(subparsers)``, adding its subcommand with
``set_defaults(func=run)`` (``run_<action>`` in a command group); ``func(args)`` returns an exit code. Arguments are typed by
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

from . import __version__
from .errors import LfusdError
from .processes import holding

EXIT_OK, EXIT_VIOLATIONS, EXIT_ERROR, EXIT_BUG, EXIT_INTERRUPTED = 0, 1, 2, 3, 130
EXIT_TERMINATED = 143  # 128 + SIGTERM
# Seconds a stopped program gives Python's exit functions (Ray's shutdown, multiprocessing's joins)
# before it exits regardless: one stuck there kept a stopped run alive, its one line printed, until
# it was killed (seen once in about 100 stops under Ray, tests/render/test_ray_shutdown.py; cause not found).
EXIT_FUNCTIONS_SECONDS = 30.0


class Terminated(BaseException):
    """SIGTERM, raised in the main thread so that clean-up (workers, pools, Ray tasks) runs as for Ctrl-C."""


def _on_sigterm(signum, frame) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # a second SIGTERM must not cut the clean-up short
    raise Terminated()


def _cli_parser_class():
    """The parser class of every (sub)command; built on first use, as it imports the commands'
    argument layer (and with it NumPy), which must happen inside :func:`main`'s signal handling."""
    from .commands.args import Parser

    class _CliParser(Parser):
        """Every lfusd (sub)command also takes the global options, anywhere on the command line."""

        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            # SUPPRESS: a subcommand that is not given the option leaves the top level's value alone.
            self.add_argument("--traceback", action="store_true", default=argparse.SUPPRESS,
                              help="on an error, print the full traceback with its causes (or set LFUSD_DEBUG=1)")
            self.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS,
                              help="log informational messages (-vv: debugging messages)")

    return _CliParser


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
    from . import commands

    _CliParser = _cli_parser_class()
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


class _Interrupt:
    """A Ctrl-C that a library must not swallow. Python raises KeyboardInterrupt wherever the main
    thread is; some extensions catch it there: pxr's module set-up turns it into a warning and
    carries on (the run then completes, exit 0), NumPy's import into an ImportError. So the
    handler also latches it: every later import raises it again (:class:`_RaiseAtImport`), and
    :func:`main` reports any ending of a latched run as interrupted."""

    pending = False
    defer = False  # only latch, do not raise: while pxr loads (it prints a warning per module it sees fail)

    @classmethod
    def handler(cls, signum, frame) -> None:
        cls.pending = True
        if not cls.defer:
            raise KeyboardInterrupt

    @classmethod
    def unraisable(cls, info) -> None:
        """sys.unraisablehook while the handler is in place: a Ctrl-C that arrives inside a finaliser
        (a ``__del__``, a weakref callback of the garbage collector) cannot propagate, and Python
        would print it as "Exception ignored in ..." with a traceback (seen once in 30 random
        Ctrl-Cs of ``lfusd verify``). It is latched already; the run reports it as its one line."""
        if isinstance(info.exc_value, KeyboardInterrupt) or info.exc_type is KeyboardInterrupt:
            cls.pending = True
            return
        sys.__unraisablehook__(info)


class _RaiseAtImport:
    """A meta path finder: it raises a latched Ctrl-C at the next import, and loads pxr's modules
    with Ctrl-C deferred (:class:`_Deferred`). Everything else it leaves to the other finders."""

    @staticmethod
    def find_spec(name, path=None, target=None):
        # not in a clean-up that must finish (Ray's shutdown); and only in the main thread, where
        # lfusd reports it: raised in another thread's import it would end that thread with a
        # traceback ("Exception in thread ...", seen once in CI's random Ctrl-Cs of render-video)
        if _Interrupt.pending and not _Interrupt.defer and not holding() and threading.current_thread() is threading.main_thread():
            raise KeyboardInterrupt
        if name.split(".")[0] != "pxr":
            return None
        import importlib.machinery

        spec = importlib.machinery.PathFinder.find_spec(name, path, target)
        if spec is not None and spec.loader is not None:
            spec.loader = _Deferred(spec.loader)
        return spec


class _Deferred:
    """A module loader run with Ctrl-C latched but not raised until it is done: pxr's loader
    catches a KeyboardInterrupt raised inside it, prints a warning with its traceback for every
    module it then fails to load, and carries on. Raised when the outermost load ends."""

    depth = 0

    def __init__(self, loader):
        self.loader = loader

    def __getattr__(self, name):
        return getattr(self.loader, name)

    def create_module(self, spec):
        with self._deferring():
            return self.loader.create_module(spec)

    def exec_module(self, module):
        with self._deferring():
            self.loader.exec_module(module)

    @classmethod
    @contextlib.contextmanager
    def _deferring(cls):
        cls.depth += 1
        _Interrupt.defer = True
        try:
            yield
        finally:
            cls.depth -= 1
            _Interrupt.defer = cls.depth > 0
        if _Interrupt.pending and not _Interrupt.defer and not holding():
            raise KeyboardInterrupt


def _interrupted() -> int:
    print("lfusd: interrupted; rerun the same command to resume", file=sys.stderr)
    return EXIT_INTERRUPTED


def main(argv: list[str] | None = None) -> int:
    # The handlers come first, before any heavy import (the commands' modules import NumPy, pxr,
    # ...): a Ctrl-C or SIGTERM at any moment of a run is one line and exit 130 or 143.
    in_main = threading.current_thread() is threading.main_thread()  # only it may set handlers
    previous = signal.signal(signal.SIGTERM, _on_sigterm) if in_main else None
    # Ctrl-C: Python's own handler is replaced by the latching one; an inherited SIG_IGN (a
    # background job of a shell) is the caller's choice and kept.
    latch = in_main and signal.getsignal(signal.SIGINT) is signal.default_int_handler
    if latch:
        _Interrupt.pending = False
        signal.signal(signal.SIGINT, _Interrupt.handler)
        sys.meta_path.insert(0, _RaiseAtImport)
        unraisable, sys.unraisablehook = sys.unraisablehook, _Interrupt.unraisable
    try:
        code = _main(argv)
        code = _interrupted() if _Interrupt.pending and code != EXIT_INTERRUPTED else code
    except KeyboardInterrupt:  # a second Ctrl-C while the first was being reported
        code = EXIT_INTERRUPTED
    finally:
        if in_main:
            # the program (argv None) is done: a SIGTERM now must not change its exit code
            signal.signal(signal.SIGTERM, signal.SIG_IGN if argv is None else signal.SIG_DFL if previous is None else previous)
        if latch:
            # the program (argv None) is done: a Ctrl-C now must not turn its result into a traceback
            signal.signal(signal.SIGINT, signal.SIG_IGN if argv is None else signal.default_int_handler)
            with contextlib.suppress(ValueError):
                sys.meta_path.remove(_RaiseAtImport)
            if argv is not None:  # a caller's main([...]); the program keeps it through its exit functions
                sys.unraisablehook = unraisable
            _Interrupt.pending = False
    if argv is None and code in (EXIT_INTERRUPTED, EXIT_TERMINATED):
        # The program itself (not a caller's main([...])), stopped: its clean-up has run (workers,
        # pools), and Python's exit functions run now (Ray's stops its agents). Then exit before the
        # C++ libraries' static destructors: Open3D's report of memory a cut-short ray cast left
        # changes the exit code to 1 and prints pages to stdout.
        import atexit

        threading.Thread(target=_exit_after, args=(EXIT_FUNCTIONS_SECONDS, code), daemon=True).start()
        with contextlib.suppress(BaseException):
            atexit._run_exitfuncs()
        with contextlib.suppress(Exception):
            sys.stdout.flush()
            sys.stderr.flush()
        os._exit(code)
    return code


def _exit_after(seconds: float, code: int) -> None:
    """End the process with ``code`` after ``seconds``, wherever its main thread is (a watchdog for
    the exit functions of a stopped program; the kernel ends its derivation processes with it)."""
    threading.Event().wait(seconds)
    with contextlib.suppress(Exception):
        sys.stdout.flush()
        sys.stderr.flush()
    os._exit(code)


def _main(argv: list[str] | None) -> int:
    """Parse, run the command, and turn every way it can end into an exit code and one line."""
    debug = os.environ.get("LFUSD_DEBUG", "") not in ("", "0")
    try:
        # The commands' modules import NumPy and pxr: a Ctrl-C during those imports is raised
        # after them, not inside their C++ module loaders (which would print their own warnings).
        _Interrupt.defer = True
        try:
            parser = build_parser()
        finally:
            _Interrupt.defer = False
        if _Interrupt.pending:
            raise KeyboardInterrupt
        try:
            args = parser.parse_args(argv)
        except SystemExit as e:  # usage errors and --help
            return int(e.code or 0)
        configure_logging(getattr(args, "verbose", 0))
        debug = debug or getattr(args, "traceback", False)
        if not getattr(args, "func", None):
            parser.print_help()
            return EXIT_ERROR
        return int(args.func(args) or 0)
    except Terminated:
        print("lfusd: terminated; rerun the same command to resume", file=sys.stderr)
        return EXIT_TERMINATED
    except KeyboardInterrupt:
        return _interrupted()
    except Exception as e:
        stop = _caused_by_stop(e)  # a Ctrl-C or SIGTERM that a library (Ray) wrapped in another error
        if _Interrupt.pending or stop is KeyboardInterrupt:  # ... or turned into another error
            return _interrupted()
        if stop is Terminated:
            print("lfusd: terminated; rerun the same command to resume", file=sys.stderr)
            return EXIT_TERMINATED
        return _report(e, debug)


def _caused_by_stop(e: BaseException) -> type | None:
    """KeyboardInterrupt or Terminated when one is among the causes or contexts of ``e``, else None."""
    seen = set()
    while e is not None and id(e) not in seen:
        if isinstance(e, (KeyboardInterrupt, Terminated)):
            return type(e)
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return None


def _report(e: Exception, debug: bool) -> int:
    """One line for an error: the user's (exit 2), the machine's (OSError, exit 2) or a bug (exit 3)."""
    if isinstance(e, LfusdError):
        if debug:
            sys.stderr.write(full_traceback(e))
        print(f"lfusd: error: {e}", file=sys.stderr)
        return EXIT_ERROR
    if isinstance(e, OSError):  # the machine, not lfusd: a full disk, a read-only folder, a missing path
        if debug:
            sys.stderr.write(full_traceback(e))
        what = f"{e.filename}: " if e.filename else ""
        fix = "free disk space" if e.errno in (errno.ENOSPC, errno.EDQUOT) else "check the path and its permissions"
        print(f"lfusd: error: {what}{e.strerror or e}; {fix}, then rerun", file=sys.stderr)
        return EXIT_ERROR
    # a bug: keep the message short, the traceback in a file for the report
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


if __name__ == "__main__":
    sys.exit(main())  # argv None: the process itself (see _stopped)
