"""Where the stream worker's time goes, and how far behind the sonar it is.

- :class:`StageClock`: CPU time (the whole process's, so the imaging kernel's threads
  count) and wall time per named stage, with a call count; :func:`instrument` puts a
  :class:`~svss_proc.imaging.imager.TileImager`'s conditioning, imaging kernel, coverage
  and scheduling (poses into tiles) on it, from outside (the accumulator's ``kernel`` is
  its documented front door; ``condition``, ``new_tile`` and the schedule's ``step`` are
  wrapped on the instances).
- :class:`SonarLag`: how far behind the sonar a ping is when it is fed to the imager:
  its age on the worker's clock (now minus its transmit time) less the smallest age seen
  in the run (the clocks' offset plus the stream's latency, found while the worker kept
  up). It needs no service and no shared clock; a worker that starts a run already
  behind (restarted mid-run) under-states it by what it was behind at its first ping.

The worker reports both in each run's manifest (``stage_times``, ``behind``) and, with
``svss worker --timings FILE``, per ping and per tile (``benchmarks/bench_live.py``).
"""

from __future__ import annotations

import contextlib
import functools
import math
import time
from dataclasses import dataclass, field


class StageClock:
    """CPU and wall seconds per stage, and calls. Stages may nest (the imaging kernel
    runs inside a ping's imaging); each is counted on its own."""

    def __init__(self) -> None:
        self._t: dict[str, list[float]] = {}

    def add(self, name: str, cpu_s: float, wall_s: float, calls: int = 1) -> None:
        t = self._t.setdefault(name, [0.0, 0.0, 0])
        t[0] += cpu_s
        t[1] += wall_s
        t[2] += calls

    @contextlib.contextmanager
    def stage(self, name: str):
        c0, w0 = time.process_time(), time.perf_counter()
        try:
            yield
        finally:
            self.add(name, time.process_time() - c0, time.perf_counter() - w0)

    def wrap(self, fn, name: str):
        """``fn`` timed as stage ``name`` at every call."""
        @functools.wraps(fn)
        def timed(*args, **kw):
            c0, w0 = time.process_time(), time.perf_counter()
            try:
                return fn(*args, **kw)
            finally:
                self.add(name, time.process_time() - c0, time.perf_counter() - w0)
        timed.__wrapped_stage__ = name
        return timed

    def totals(self) -> dict[str, dict]:
        """``{stage: {"cpu_s", "wall_s", "calls"}}``, rounded to microseconds (``cpu_s``
        None: a stage timed by its wall time only)."""
        return {k: {"cpu_s": None if math.isnan(c) else round(c, 6), "wall_s": round(w, 6),
                    "calls": int(n)} for k, (c, w, n) in sorted(self._t.items())}

    def wall(self, name: str) -> float:
        return self._t.get(name, [0.0, 0.0, 0])[1]


def instrument(imager, clock: StageClock) -> None:
    """Time ``imager``'s stages on ``clock``: ``conditioning`` (matched filter and
    baseband), ``imaging`` (the back-projection: the kernel, or the factorised method's
    two stages around it), ``coverage`` (which voxels each
    ping reached) and ``scheduling`` (the pose placed in the tile frame, the tiles it
    reaches and closes)."""
    acc = imager.accumulator
    acc.image_slice = clock.wrap(acc.image_slice, "imaging")
    acc.condition = clock.wrap(acc.condition, "conditioning")
    new_tile = acc.new_tile

    @functools.wraps(new_tile)
    def timed_new_tile(*args, **kw):
        tile = new_tile(*args, **kw)
        if tile.coverage is not None:
            tile.coverage.add = clock.wrap(tile.coverage.add, "coverage")
        return tile
    acc.new_tile = timed_new_tile
    imager.schedule.step = clock.wrap(imager.schedule.step, "scheduling")


@dataclass
class SonarLag:
    """Seconds behind the sonar of the pings fed (see the module's docstring)."""
    base_s: float | None = None      # the smallest age seen (clock offset + latency)
    lag_s: float = 0.0               # the latest ping's
    max_lag_s: float = 0.0
    #: (unix time fed, sequence, lag s) of every ping, kept only when asked for
    timeline: list | None = field(default=None)

    def feed(self, transmit_time_ns: int, sequence: int, now_s: float | None = None
             ) -> float:
        now_s = time.time() if now_s is None else now_s
        age = now_s - transmit_time_ns * 1e-9
        if self.base_s is None or age < self.base_s:
            self.base_s = age
        self.lag_s = age - self.base_s
        self.max_lag_s = max(self.max_lag_s, self.lag_s)
        if self.timeline is not None:
            self.timeline.append((round(now_s, 4), int(sequence), round(self.lag_s, 4)))
        return self.lag_s
