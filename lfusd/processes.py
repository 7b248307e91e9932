"""Child processes that must not outlive lfusd: Blender workers and derivation pool processes."""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading

# The environment variable through which a Blender worker learns its parent's pid.
PARENT_PID_ENV = "LFUSD_PARENT_PID"


def die_with_parent(parent: int) -> None:
    """Have the kernel kill this process when its parent dies (Linux), so a killed lfusd leaves
    no strays; exit at once if ``parent`` already died before the request took effect."""
    if sys.platform.startswith("linux"):
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # 1 = PR_SET_PDEATHSIG
    if os.getppid() != parent:
        os._exit(1)


@contextlib.contextmanager
def children_ignore_sigint():
    """Start child processes inside this: they begin with Ctrl-C ignored (a SIG_IGN disposition
    survives exec; the parent alone answers Ctrl-C and stops them), while a Ctrl-C to this process
    meanwhile is held, not lost: SIGINT is also blocked here (Linux keeps a blocked signal pending
    even while it is ignored) and raised as KeyboardInterrupt once the handler is back. Before, a
    Ctrl-C in that window was dropped and the run went on to exit 0. Only the main thread may set
    handlers; elsewhere this does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    handler = signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, signal.SIG_DFL if handler is None else handler)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # a held Ctrl-C is raised here
