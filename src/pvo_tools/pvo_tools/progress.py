"""A dependency-free progress bar on stderr (redrawn in place on a terminal, every 10 % otherwise)."""

from __future__ import annotations

import sys
import time
from typing import TextIO


class Progress:
    def __init__(self, total: int, label: str, stream: TextIO | None = None) -> None:
        self.total = max(int(total), 1)
        self.label = label
        self.stream = stream or sys.stderr
        self.done = 0
        self.start = time.monotonic()
        self._tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self._last_decile = -1

    def update(self, step: int = 1) -> None:
        self.done += step
        fraction = min(self.done / self.total, 1.0)
        elapsed = time.monotonic() - self.start
        rate = self.done / elapsed if elapsed > 0 else 0.0
        if self._tty:
            filled = int(30 * fraction)
            bar = "#" * filled + "-" * (30 - filled)
            self.stream.write(f"\r{self.label} [{bar}] {self.done}/{self.total} {rate:6.1f}/s, {self._left(rate)} left ")
            self.stream.flush()
        else:
            decile = int(fraction * 10)
            if decile != self._last_decile:
                self._last_decile = decile
                self.stream.write(
                    f"{self.label}: {self.done}/{self.total} ({100 * fraction:.0f} %, {rate:.1f}/s, {self._left(rate)} left)\n"
                )
                self.stream.flush()

    def _left(self, rate: float) -> str:
        """Time left at the current rate, as h:mm:ss or m:ss."""
        if rate <= 0:
            return "?"
        seconds = round(max(self.total - self.done, 0) / rate)
        hours, rest = divmod(seconds, 3600)
        return f"{hours}:{rest // 60:02d}:{rest % 60:02d}" if hours else f"{rest // 60}:{rest % 60:02d}"

    def close(self) -> None:
        if self._tty:
            self.stream.write("\n")
            self.stream.flush()


class CountProgress:
    """A ``progress(done, total)`` callback for library calls that report counts: the bar starts at the first call
    (when the total is known), nothing is shown when ``quiet``; :meth:`close` ends it if it started."""

    def __init__(self, label: str, quiet: bool = False) -> None:
        self.label = label
        self.quiet = quiet
        self.bar: Progress | None = None

    def __call__(self, done: int, total: int) -> None:
        if self.quiet:
            return
        if self.bar is None:
            self.bar = Progress(total, self.label)
        if done > self.bar.done:
            self.bar.update(done - self.bar.done)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
