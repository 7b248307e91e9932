"""Processes a test started (or that lfusd started) and must see gone."""

from __future__ import annotations

import time

import psutil


def alive(procs: list, timeout: float = 0.0) -> list:
    """The processes still running (zombies count as gone) after up to ``timeout`` seconds."""
    end = time.time() + timeout
    while True:
        out = []
        for p in procs:
            try:
                if p.is_running() and p.status() != psutil.STATUS_ZOMBIE:
                    out.append(p)
            except psutil.Error:
                pass
        if not out or time.time() > end:
            return out
        time.sleep(0.1)
