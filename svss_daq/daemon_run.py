"""What the parts of the acquisition daemon (:mod:`svss_daq.daemon`) share: the run.

:class:`RunState` is one run's identity, state and outputs (recording, ping stream, catch-up
service, bound endpoints), its timeline, its counters (:class:`Counters`) and its device
events (:meth:`RunState.event`: logged, counted, kept for the status stream and written to
the raw file). The ping pipeline (:mod:`svss_daq.daemon_pipeline`), the device
supervisor (:mod:`svss_daq.daemon_devices`), the navigation monitor
(:mod:`svss_daq.daemon_nav`) and the status reporter (:mod:`svss_daq.daemon_status`)
each hold it; none holds another's state.
"""

from __future__ import annotations

import collections
import logging
import time
from dataclasses import dataclass

from .recorder import RecordingStopped

log = logging.getLogger("svss_daq.daemon")

#: events kept for the status stream
RECENT_EVENTS = 20


def utc_now_ns() -> int:
    return time.time_ns()


def run_id_now(name: str) -> str:
    return f"{name}-{time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())}"


@dataclass
class Counters:
    """What the daemon counted (the status stream's ``counters``)."""
    delivered: int = 0          # complete pings from the digitiser
    incomplete: int = 0         # pings the digitiser closed with channels missing
    never_delivered: int = 0    # ping numbers the digitiser skipped (no frame at all)
    recorded: int = 0           # pings on disk (flushed)
    not_recorded: int = 0       # assembled, lost with a failed write or after recording
                                # stopped (a full disk): neither recorded nor published
    published: int = 0
    publish_dropped: int = 0    # refused by a full subscriber queue (best-effort stream)
    transmit_missing: int = 0   # no sequencer record: assembled from the digitiser's
    duplicates: int = 0         # a sequence delivered twice (the second is not recorded)
    assembly_errors: int = 0
    pose_errors: int = 0        # no navigation solution at all (pose left NaN)
    # past the bounds of acquire.toml [limits] (docs/acquisition.md, "Limits")
    pending_full: int = 0       # pings posed before their wait ended: too many waiting
    transmit_unclaimed: int = 0  # transmit records dropped: too many waiting for a ping
    records_dropped: int = 0    # NMEA / PD0 / clock records dropped before being written

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def power_of_ten(n: int) -> bool:
    """Whether count ``n`` is 1, 10, 100, ...: a bounded count's events say so then."""
    return str(n).rstrip("0") == "1"


class RunState:
    """One run of acquisition as its parts see it.

    ``state``: starting, recording, stopping, stopped or failed; ``failure``: why
    recording could not go on (None while it can). The outputs (``recorder``,
    ``publisher``, ``service``) are None until the daemon binds them; ``endpoints``
    what they bound. The timeline is monotonic seconds: ``started_at`` (the daemon
    made), ``recording_at`` (the devices opened and pinging), ``pings_due_at`` (the
    first ping due at the latest), ``first_ping_at`` and ``last_ping_at`` (pings
    delivered)."""

    def __init__(self, run_id: str, keep_events: int = RECENT_EVENTS):
        self.run_id = run_id
        self.counters = Counters()
        self.state = "starting"
        self.failure: str | None = None
        self.recorder = None
        self.publisher = None
        self.service = None
        self.endpoints: dict[str, str] = {}
        self.events: collections.deque = collections.deque(maxlen=keep_events)
        self.n_events = 0
        self.event_counts: collections.Counter = collections.Counter()
        self.started_at = time.monotonic()
        self.recording_at: float | None = None
        self.pings_due_at: float | None = None
        self.first_ping_at: float | None = None
        self.last_ping_at: float | None = None
        self.last_recorded_seq: int | None = None

    def event(self, kind: str, detail: str, level: int = logging.WARNING) -> None:
        """Log, count, keep for the status stream and record one device event."""
        t = utc_now_ns()
        self.n_events += 1
        self.event_counts[kind] += 1
        self.events.append((t, kind, detail))
        log.log(level, "%s: %s", kind, detail)
        if self.recorder is not None and not self.recorder.stopped:
            try:
                self.recorder.append_event(t, kind, detail)
            except RecordingStopped:
                pass

    def recording(self, first_ping_s: float) -> None:
        """The devices are pinging: recording from now, the first ping due within
        ``first_ping_s``."""
        self.state = "recording"
        self.recording_at = time.monotonic()
        self.pings_due_at = self.recording_at + first_ping_s

    def recording_failed(self, exc: RecordingStopped) -> None:
        """Recording cannot go on (``exc`` says why): the run has failed."""
        if self.failure is None:
            log.error("recording stopped: %s", exc)
        self.failure = self.failure or str(exc)
        self.state = "failed"

    def ping_delivered(self) -> None:
        """A complete ping came from the digitiser (counted, timed)."""
        self.counters.delivered += 1
        self.last_ping_at = time.monotonic()
        if self.first_ping_at is None:
            self.first_ping_at = self.last_ping_at
