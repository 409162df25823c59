"""The simulated device's one clock: every emulator stamps its output with it.

Simulated time runs ``time_scale`` times as fast as the host's monotonic clock from a
start epoch (the scene's track start), so a slow scene can run at, say, half speed and
keep the devices mutually consistent. A clock step (a fault: the GPS-disciplined clock
jumps) moves every later stamp by the same amount, while the platform keeps moving on
the *true* time (:meth:`true_ns`).
"""

from __future__ import annotations

import logging
import threading
import time

log = logging.getLogger(__name__)


class SimClock:
    """Simulated time in int64 ns since the Unix epoch.

    ``start_ns``: the track's start (the ping grid's origin); ``time_scale``: simulated
    seconds per host second (> 0); ``lead_s``: the clock reads ``start_ns - lead_s`` at
    :meth:`start`, so that the instruments run (and a sequencer started meanwhile waits
    for the grid's first point) before the track begins."""

    def __init__(self, start_ns: int, time_scale: float = 1.0, lead_s: float = 0.0) -> None:
        if not time_scale > 0:
            raise ValueError(f"time scale {time_scale!r}: expected a number > 0")
        if not lead_s >= 0:
            raise ValueError(f"lead {lead_s!r} s: expected a number >= 0")
        self.start_ns = int(start_ns)
        self.lead_ns = int(round(lead_s * 1e9))
        self.time_scale = float(time_scale)
        self._t0 = time.monotonic_ns()
        self._offset_ns = 0
        self._lock = threading.Lock()

    def start(self) -> "SimClock":
        """(Re)start: simulated time is ``start_ns - lead`` now."""
        with self._lock:
            self._t0 = time.monotonic_ns()
        return self

    def true_ns(self) -> int:
        """True simulated time (what the platform's motion follows), ns."""
        return self.start_ns - self.lead_ns + int((time.monotonic_ns() - self._t0)
                                                  * self.time_scale)

    def now_ns(self) -> int:
        """The devices' clock: true time plus every step injected so far, ns."""
        with self._lock:
            return self.true_ns() + self._offset_ns

    def elapsed_s(self) -> float:
        """True simulated seconds since the start."""
        return (self.true_ns() - self.start_ns) * 1e-9

    def host_delay_s(self, sim_ns: int) -> float:
        """Host seconds until the true simulated time reaches ``sim_ns`` (<= 0: past)."""
        return (sim_ns - self.true_ns()) * 1e-9 / self.time_scale

    def sleep_until(self, sim_ns: int, stop: threading.Event | None = None) -> bool:
        """Sleep until true simulated time ``sim_ns``; False if ``stop`` was set first."""
        delay = self.host_delay_s(sim_ns)
        if delay <= 0:
            return not (stop is not None and stop.is_set())
        if stop is None:
            time.sleep(delay)
            return True
        return not stop.wait(delay)

    @property
    def offset_ns(self) -> int:
        """Sum of the clock steps injected so far (devices' clock minus true time), ns."""
        with self._lock:
            return self._offset_ns

    def step(self, by_ns: int) -> None:
        """A clock step: every later :meth:`now_ns` is ``by_ns`` later (a fault)."""
        with self._lock:
            self._offset_ns += int(by_ns)
        log.warning("clock step of %+.6f s (devices' clock now %+.6f s off true time)",
                    by_ns * 1e-9, self._offset_ns * 1e-9)
