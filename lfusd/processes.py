"""Child processes that must not outlive lfusd: Blender workers and derivation pool processes."""

from __future__ import annotations

import contextlib
import os
import signal
import sys

# The environment variable through which a Blender worker learns its parent's pid.
PARENT_PID_ENV = "LFUSD_PARENT_PID"

_holding = 0  # depth of hold_stops blocks running (in the main thread)


def holding() -> bool:
    """Whether a :func:`hold_stops` block runs: an interrupt must not be raised now. lfusd.cli's
    import hook asks, as it raises a Ctrl-C it latched earlier at every later import."""
    return _holding > 0


@contextlib.contextmanager
def hold_stops(main: bool = True):
    """Hold Ctrl-C and SIGTERM during a clean-up that must run to its end, then deliver each held
    signal once to the handler it was meant for. Raised inside it, an interrupt would cut the
    clean-up short; ignored, it would be lost (the run would go on to exit 0). ``main``: the
    calling thread is the main thread (only it may set handlers; elsewhere nothing is held)."""
    global _holding
    held: list[int] = []
    handlers = {s: signal.signal(s, lambda signum, frame: held.append(signum)) for s in (signal.SIGINT, signal.SIGTERM)} if main else {}
    _holding += 1
    try:
        yield
    finally:
        _holding -= 1
        for s, h in handlers.items():
            signal.signal(s, h if h is not None else signal.SIG_DFL)
        for s in dict.fromkeys(held):  # each held signal once, to the handler it was meant for
            h = handlers[s]
            if callable(h):
                h(s, None)
            elif h == signal.SIG_DFL:
                signal.raise_signal(s)


def quiet_thread_pools() -> None:
    """In a process lfusd owns (a derivation lane or pool process): OpenMP threads (numba's parallel
    kernels) sleep when idle instead of spinning, which burns CPU after every parallel loop
    (measured: 0.19 -> 0.13 core-s per 1024x1024 view for the motion kernel). Call it before numba
    starts its threads; a value the user set stays."""
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


@contextlib.contextmanager
def one_blas_thread():
    """Inside this block, NumPy's BLAS (OpenBLAS) computes on the calling thread alone. lfusd's
    matrix products are per-pixel and per-vertex (N, 3) x (3, 3): bound by memory, not arithmetic;
    a second BLAS thread speeds none of them and spins after each, burning a core the ray casts
    could use (measured in verify: 0.14-0.2 core-s per 1024x1024 view of a worker doing nothing).
    threadpoolctl restores the previous limit on exit."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield


REUSED_BYTES = 1 << 30  # allocations below this come from the heap and stay there once freed


def reuse_freed_memory() -> None:
    """In a process lfusd owns (a derivation lane or pool process, a Blender worker): glibc keeps
    freed memory for the next allocation instead of handing it back to the kernel. By default each
    array above a few MB is a fresh mapping whose pages the kernel faults in and zeroes, every time:
    a view's raw passes, keys and temporaries are hundreds of MB of them (measured per 1024x1024
    view: decoding the raw passes 61 -> 36 ms of CPU, encoding the motion keys 39 -> 20). The
    process then stays at its peak size, which it reaches on the first view anyway. Nothing
    happens outside glibc (or where mallopt refuses)."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes

    try:
        libc = ctypes.CDLL(None)
        libc.mallopt(-3, REUSED_BYTES)  # M_MMAP_THRESHOLD: below it, no mapping of its own
        libc.mallopt(-1, 2 * REUSED_BYTES)  # M_TRIM_THRESHOLD: free memory up to it stays in the heap
    except (OSError, AttributeError):
        pass  # not glibc


def derivation_process_init(parent: int) -> None:
    """Initializer of lfusd's derivation processes (render lanes, the derive pool): the parent alone
    answers Ctrl-C, thread pools sleep when idle, freed memory is reused, and they die with it."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    quiet_thread_pools()
    reuse_freed_memory()
    die_with_parent(parent)


def die_with_parent(parent: int) -> None:
    """Have the kernel kill this process when its parent dies (Linux), so a killed lfusd leaves
    no strays; exit at once if ``parent`` already died before the request took effect."""
    if sys.platform.startswith("linux"):
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # 1 = PR_SET_PDEATHSIG
    if os.getppid() != parent:
        os._exit(1)


@contextlib.contextmanager
def own_process_group():
    """Inside this block, the processes multiprocessing's spawn starts (derivation pools) get a
    process group of their own: a terminal's Ctrl-C, sent to the foreground group, reaches lfusd
    alone, which stops them itself (and they die with it, :func:`die_with_parent`). Ignoring
    Ctrl-C in lfusd while they start, so that they inherit the ignoring, loses a Ctrl-C sent
    then: the run completed, exit 0. Yields whether it applies (CPython 3.11's spawn, whose
    fork_exec call it repeats with a process group; elsewhere the caller falls back to ignoring)."""
    from multiprocessing import util

    original = util.spawnv_passfds
    if sys.version_info[:2] != (3, 11) or getattr(original, "__name__", "") != "spawnv_passfds":
        yield False
        return

    def spawnv_passfds(path, args, passfds):
        import _posixsubprocess
        import subprocess

        passfds = tuple(sorted(map(int, passfds)))
        errpipe_read, errpipe_write = os.pipe()
        try:  # multiprocessing.util.spawnv_passfds, with pgid_to_set 0: a group of its own
            return _posixsubprocess.fork_exec(args, [path], True, passfds, None, None, -1, -1, -1, -1, -1, -1,
                                              errpipe_read, errpipe_write, False, False, 0, None, None, None, -1, None,
                                              subprocess._USE_VFORK)
        finally:
            os.close(errpipe_read)
            os.close(errpipe_write)

    # A Ctrl-C while a process is being started is held until the block ends: raised between the
    # start and the hand-over of its job, it would leave the new process reading a closed pipe
    # (a traceback on stderr).
    import threading

    held: list[int] = []
    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum)) if main else None
    util.spawnv_passfds = spawnv_passfds
    try:
        yield True
    finally:
        util.spawnv_passfds = original
        if main:
            signal.signal(signal.SIGINT, previous)
            if held and callable(previous):
                previous(signal.SIGINT, None)  # lfusd's or Python's handler: raises KeyboardInterrupt
            elif held and previous == signal.SIG_DFL:
                raise KeyboardInterrupt


@contextlib.contextmanager
def native_stderr_silenced():
    """File descriptor 2 on /dev/null for a while, for native libraries that write to it past
    lfusd's one-line output: pxr's validators (lfusd.author.rules), and Ray's C++ core worker while
    it shuts down (after a Ctrl-C one wrote "task_manager.cc: Failed to push error to driver" before
    lfusd's report, seen once in 13 random stops under load). Python's own sys.stderr writes to the
    same descriptor, so nothing of lfusd's is written inside."""
    sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:
        yield
        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
