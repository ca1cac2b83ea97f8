"""Progress of long loops: a redrawn line on a terminal, a few log lines otherwise (logs, CI)."""

from __future__ import annotations

import logging
import sys
import time


class Progress:
    """Counts work items. On a TTY it redraws one status line at most every `interval` seconds; elsewhere it
    logs at every quarter of the work, so logs stay short."""

    def __init__(self, desc: str, total: int | None, log: logging.Logger, stream=None, interval: float = 0.25,
                 enabled: bool = True):
        self.desc, self.total, self.log = desc, total, log
        self.stream = stream if stream is not None else sys.stderr
        self.tty = enabled and hasattr(self.stream, "isatty") and self.stream.isatty()
        self.enabled = enabled
        self.interval = interval
        self.done = 0
        self.start = time.perf_counter()
        self._last_draw = 0.0
        self._next_quarter = 1

    def update(self, n: int = 1) -> None:
        self.done += n
        if not self.enabled:
            return
        now = time.perf_counter()
        if self.tty:
            if now - self._last_draw >= self.interval or (self.total and self.done >= self.total):
                self._last_draw = now
                self.stream.write("\r" + self._line(now) + "\x1b[K")
                self.stream.flush()
        elif self.total:
            while self._next_quarter <= 4 and self.done * 4 >= self._next_quarter * self.total:
                self._next_quarter += 1
                if self.done < self.total:
                    self.log.info("%s", self._line(now))

    def _line(self, now: float) -> str:
        elapsed = max(now - self.start, 1e-9)
        rate = self.done / elapsed
        if self.total:
            eta = (self.total - self.done) / rate if rate > 0 else float("inf")
            return (f"{self.desc}: {self.done}/{self.total} ({100 * self.done / self.total:.0f}%) "
                    f"{rate:.1f}/s, {elapsed:.0f} s elapsed, ~{eta:.0f} s left")
        return f"{self.desc}: {self.done} done, {rate:.1f}/s"

    def close(self) -> None:
        if self.enabled and self.tty:
            self.stream.write("\r" + self._line(time.perf_counter()) + "\x1b[K\n")
            self.stream.flush()

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
