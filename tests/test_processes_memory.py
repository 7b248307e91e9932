"""lfusd.processes.reuse_freed_memory: in the processes lfusd owns, a large array comes from the
heap, and its memory stays there for the next one once freed, instead of a fresh mapping whose pages
the kernel zeroes each time (glibc's mallinfo2 tells which)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

PROBE = r"""
import ctypes, json, sys
import numpy as np
class Info(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks",
                                               "uordblks", "fordblks", "keepcost")]
libc = ctypes.CDLL(None)
libc.mallinfo2.restype = Info
if sys.argv[1] == "reuse":
    from lfusd.processes import reuse_freed_memory
    reuse_freed_memory()
a = np.ones(64 << 20, np.uint8)  # 64 MB: above glibc's largest default mapping threshold (32 MB)
held = libc.mallinfo2()
del a
freed = libc.mallinfo2()
print(json.dumps({"mapped": held.hblkhd, "heap_after_free": freed.arena}))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's allocator")
def test_a_freed_array_stays_in_the_heap_for_the_next():
    def probe(mode: str) -> dict:
        out = subprocess.run([sys.executable, "-c", PROBE, mode], capture_output=True, text=True, check=True).stdout
        return json.loads(out)

    plain, reused = probe("plain"), probe("reuse")
    assert plain["mapped"] >= 64 << 20  # by default: a mapping of its own, unmapped when freed
    assert plain["heap_after_free"] < 64 << 20
    assert reused["mapped"] < 1 << 20  # from the heap
    assert reused["heap_after_free"] >= 64 << 20  # kept there once freed
