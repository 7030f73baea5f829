"""A dependency-free progress line for long runs (scans done, scans/s, time left)."""

from __future__ import annotations

import sys
import time
from typing import TextIO

__all__ = ["Progress"]


class Progress:
    """Redraws one status line on a terminal; on a pipe, prints a line every ``log_every_s``."""

    def __init__(self, total: int | None, label: str, stream: TextIO | None = None, log_every_s: float = 10.0) -> None:
        self.total = total
        self.label = label
        self.stream = stream or sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.log_every_s = log_every_s
        self.start = time.perf_counter()
        self._last_draw = 0.0
        self.done = 0

    def update(self, done: int) -> None:
        self.done = done
        now = time.perf_counter()
        interval = 0.2 if self.tty else self.log_every_s
        if now - self._last_draw >= interval:
            self._last_draw = now
            self._draw(now)

    def _draw(self, now: float) -> None:
        elapsed = now - self.start
        rate = self.done / elapsed if elapsed > 0 else 0.0
        text = f"{self.label}: {self.done}"
        if self.total:
            text += f"/{self.total} ({100.0 * self.done / self.total:.0f}%)"
            if rate > 0:
                text += f", {(self.total - self.done) / rate:.0f} s left"
        text += f", {rate:.1f} scans/s"
        if self.tty:
            self.stream.write("\r" + text.ljust(78)[:120])
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def close(self) -> None:
        self._draw(time.perf_counter())
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()
