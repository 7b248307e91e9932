"""Child processes that must not outlive lfusd: Blender workers and derivation pool processes."""

from __future__ import annotations

import os
import signal
import sys

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
