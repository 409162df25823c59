"""One run as the stream worker (:mod:`svss_proc.worker`) follows it: its folder's worker,
the next sequence to feed, the reorder buffer and the times that pace gaps, catch-up
and the service's questions; and what a worker says of its memory."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from svss_daq.ping import Ping

from .run_worker import Worker


@dataclass
class _Run:
    """A run the stream worker is imaging: its folder's worker, the next sequence to
    feed and the reorder buffer."""
    run_id: str | None                  # None: not known yet (no service, before RunEnd)
    worker: Worker | None               # None: a run already finished here (ignored)
    next_seq: int | None
    buffer: dict[int, Ping] = field(default_factory=dict)
    #: pings fed to the worker in this session (all of a run's: nothing to fetch at its end)
    fed: int = 0
    gap_since: float | None = None
    retry_at: float = 0.0
    service_failed: bool = False        # the last catch-up of this run failed
    #: when ``next_seq`` last moved (monotonic): how far ahead a ping may plausibly be
    progress_at: float = field(default_factory=time.monotonic)
    #: the run's last sequence the recording held when last asked, and when (monotonic)
    recorded_last: int | None = None
    recorded_at: float = -float("inf")
    #: when this worker last told the service its progress in the run (monotonic)
    said_at: float = -float("inf")
    #: why the run's end could not be confirmed (the run is then not complete)
    end_unconfirmed: str | None = None
    #: when the stream last brought a ping of the run (monotonic)
    heard_at: float = field(default_factory=time.monotonic)
    #: when the service is next asked about the run while the stream is quiet
    ask_at: float = 0.0


def memory_state(worker: Worker | None, now: float) -> dict:
    """What a worker says of its memory in its progress messages (the daemon's alarm
    worker.memory_bound): its open tiles, the most limits.memory_gib allows, and how
    long ago (s) it last reached that bound (None: never)."""
    if worker is None:
        return {}
    sched = worker.imager.schedule
    at = sched.memory_bound_at
    return {"open_tiles": len(worker.imager.active), "max_open_tiles": sched.max_open_tiles,
            "memory_bound_age_s": None if at is None else round(now - at, 3),
            "imaging_method": worker.imager.accumulator.method}
