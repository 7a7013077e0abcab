"""A one-line progress display for long runs (stderr, throttled, no dependencies)."""
from __future__ import annotations

import math
import sys
import time


class Progress:
    """``label [#####.....] 1200/30000 micro-actions  5400/s  goals 31 ...`` redrawn in place on a
    terminal, or printed every ``log_every`` seconds when stderr is not a terminal (CI logs)."""

    def __init__(self, total: int, label: str, enabled: bool = True, stream=None,
                 min_interval: float = 0.2, log_every: float = 10.0):
        self.total = max(1, total)
        self.label = label
        self.enabled = enabled
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.min_interval = min_interval if self.tty else log_every
        self.t0 = time.perf_counter()
        self.last = -math.inf
        self.line = ""

    def format(self, done: int, **fields) -> str:
        frac = min(1.0, done / self.total)
        elapsed = time.perf_counter() - self.t0
        rate = done / elapsed if elapsed > 0 else 0.0
        bar = "#" * int(20 * frac) + "." * (20 - int(20 * frac))
        extra = "  ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}"
                          for k, v in fields.items())
        return f"{self.label} [{bar}] {done}/{self.total} micro-actions  {rate:,.0f}/s  {extra}"

    def update(self, done: int, force: bool = False, **fields) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        if not force and now - self.last < self.min_interval and done < self.total:
            return
        self.last = now
        self.line = self.format(done, **fields)
        if self.tty:
            self.stream.write("\r" + self.line[:200].ljust(100))
        else:
            self.stream.write(self.line + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self.enabled and self.tty:
            self.stream.write("\n")
            self.stream.flush()
