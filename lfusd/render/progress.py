"""Progress of a render: a rich progress bar on a terminal, else rate-limited log lines."""

from __future__ import annotations

import sys
import threading
import time


class Progress:
    """Views done, views per second and time left, as a rich progress bar or plain log lines."""

    LOG_EVERY_S = 5.0  # log lines (--quiet, or no terminal): at most one per interval, and the last

    def __init__(self, total: int, done: int, quiet: bool):
        self.quiet = quiet or not sys.stderr.isatty()
        self.total, self.done, self.start, self.started_with = total, done, time.monotonic(), done
        self.bar = None
        self.last_log = -float("inf")
        self.lock = threading.Lock()  # workers report from several threads
        if not self.quiet:
            from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn
            from rich.progress import Progress as Bar

            self.bar = Bar(TextColumn("rendering"), BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[rate]}"), TimeRemainingColumn())
            self.task = self.bar.add_task("views", total=total, completed=done, rate="")
            self.bar.start()

    def advance(self, n: int) -> None:
        with self.lock:
            self._advance(n)

    def _advance(self, n: int) -> None:
        self.done += n
        rate = (self.done - self.started_with) / max(time.monotonic() - self.start, 1e-9)
        if self.bar:
            self.bar.update(self.task, advance=n, rate=f"{rate:.2f} views/s")
        elif self.done == self.total or time.monotonic() - self.last_log >= self.LOG_EVERY_S:
            self.last_log = time.monotonic()
            left = (self.total - self.done) / rate if rate > 0 else float("inf")
            print(f"lfusd: {self.done}/{self.total} views, {rate:.2f} views/s, {left:.0f} s left", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.bar:
            self.bar.stop()
