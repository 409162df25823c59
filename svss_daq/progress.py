"""Progress of long work, reported through logging (rate-limited)."""

from __future__ import annotations

import logging
import time


class Progress:
    """Log 'what: done/total (pct), rate, ETA' at most every ``interval_s`` seconds."""

    def __init__(self, what: str, total: int | None, logger: logging.Logger,
                 unit: str = "pings", interval_s: float = 2.0):
        self.what, self.total, self.log, self.unit = what, total, logger, unit
        self.interval = interval_s
        self.done = 0
        self.t0 = self._last = time.monotonic()

    def update(self, n: int = 1) -> None:
        self.done += n
        now = time.monotonic()
        if now - self._last >= self.interval or (self.total and self.done >= self.total):
            self._last = now
            self.report()

    def report(self) -> None:
        el = max(time.monotonic() - self.t0, 1e-9)
        rate = self.done / el
        if self.total:
            eta = (self.total - self.done) / rate if rate > 0 else float("inf")
            self.log.info("%s: %d/%d %s (%.0f%%), %.1f %s/s, ETA %.0f s", self.what,
                          self.done, self.total, self.unit, 100 * self.done / self.total,
                          rate, self.unit, eta)
        else:
            self.log.info("%s: %d %s, %.1f %s/s", self.what, self.done, self.unit, rate,
                          self.unit)
