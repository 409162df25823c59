"""The acquisition daemon's status reporter: what the operator sees of a run.

:class:`StatusReporter` composes the status snapshot of a run from its parts (the run's
state, timeline and counters; the ping pipeline's rate; the devices; the navigation;
the recording and its disk, :class:`DiskWatch`; the tile workers the catch-up service
hears from; the recent events), evaluates the alarms on it (:mod:`svss_daq.alarms`:
each one raised or cleared is a run event) and publishes it, alarms first, every
``status.interval_s`` on the status stream (:class:`~svss_daq.status.StatusPublisher`).
See docs/acquisition.md and docs/operator.md.
"""

from __future__ import annotations

import logging
import time

from .acquire_config import alarms_section
from .alarms import AlarmLimits, AlarmTracker, evaluate
from .daemon_devices import DeviceSupervisor
from .daemon_nav import NavigationMonitor
from .daemon_pipeline import PingPipeline
from .daemon_run import RunState, utc_now_ns
from .recent import RecentChange
from .status import StatusPublisher, utc_text

NAN = float("nan")


class DiskWatch:
    """How fast the recording's disk fills, over ``window_s``, and the time left at
    that rate before recording stops at ``min_free_mib`` free."""

    def __init__(self, window_s: float, min_free_mib: float):
        self.min_free_mib = min_free_mib
        self._free = RecentChange(window_s)

    def rate(self, now: float, free_mib: float) -> dict:
        """``fill_mib_s`` and ``time_left_s`` (None where unknown) with ``free_mib``
        free at monotonic time ``now`` (NaN: no recording)."""
        if not free_mib == free_mib:                      # NaN: no recorder
            return {"fill_mib_s": None, "time_left_s": None}
        self._free.add(now, {"free": free_mib})
        change, dt = self._free.change()
        if dt <= 0:
            return {"fill_mib_s": None, "time_left_s": None}
        rate = -change["free"] / dt
        room = free_mib - self.min_free_mib
        left = max(room, 0.0) / rate if rate > 1e-6 else None
        return {"fill_mib_s": round(rate, 4),
                "time_left_s": None if left is None else round(left, 1)}


class StatusReporter:
    """The status of run ``run`` (configuration ``setup``) from its ``pipeline``,
    ``devices`` and ``nav``; published on :attr:`publisher` once the daemon binds it."""

    def __init__(self, setup, run: RunState, pipeline: PingPipeline, devices: DeviceSupervisor,
                 nav: NavigationMonitor):
        acq = setup.acquire
        self.setup = setup
        self.run = run
        self.pipeline = pipeline
        self.devices = devices
        self.nav = nav
        self.publisher: StatusPublisher | None = None
        # alarms (svss_daq.alarms): thresholds, the active ones, and what the status
        # snapshot needs for them
        self.alarm_limits = AlarmLimits.from_setup(setup)
        self.alarms = AlarmTracker(alarms_section(acq).clear_after_s)
        self._recent = RecentChange(self.alarm_limits.recent_s)     # drops
        self.disk = DiskWatch(acq.status.rate_window_s, acq.disk.min_free_mib)
        self._next = 0.0

    def status(self) -> dict:
        """The status snapshot (the status stream's message, less its alarms: see
        :meth:`publish`). Ages are seconds; times UTC text."""
        run = self.run
        c, rec = run.counters, run.recorder
        now = time.monotonic()
        devices = self.devices.status(now)
        nav = self.nav.status()
        interval = self.setup.hardware.value.sequencer.ping_interval_s
        recording_s = None if run.recording_at is None else now - run.recording_at
        # before the first ping, its age counts from when pings are due (none before)
        last_ping = run.last_ping_at if run.last_ping_at is not None else run.pings_due_at
        if last_ping is not None and now < last_ping:
            last_ping = None
        due_in = (None if run.first_ping_at is not None or run.pings_due_at is None
                  else max(run.pings_due_at - now, 0.0))
        # recent drops (alarms pings.lost, stream.dropped)
        self._recent.add(now, {"never_delivered": c.never_delivered,
                               "incomplete": c.incomplete, "not_recorded": c.not_recorded,
                               "driver_queue_full": self.devices.pings_dropped,
                               "stream_dropped": c.publish_dropped})
        change, _ = self._recent.change()
        stream_dropped = int(change.pop("stream_dropped", 0))
        file = None
        if rec is not None:
            file = rec.writer.path if rec.writer else (rec.segments[-1] if rec.segments
                                                       else None)
        free_mib = rec.free_bytes / 2**20 if rec else NAN
        disk = self.disk.rate(now, free_mib)
        return {
            "time_utc": utc_text(utc_now_ns()),
            "run_id": run.run_id, "state": run.state,
            "uptime_s": round(now - run.started_at, 3),
            "recording_s": None if recording_s is None else round(recording_s, 3),
            # since the first ping (the ping rate's window counts from it), and the
            # seconds until pings are due at the latest before it
            "pinging_s": None if run.first_ping_at is None
            else round(now - run.first_ping_at, 3),
            "first_ping_due_s": None if due_in is None else round(due_in, 3),
            "ping_rate_hz": round(self.pipeline.ping_rate(), 3),
            "schedule_rate_hz": round(1.0 / interval, 3), "ping_interval_s": interval,
            "last_ping_age_s": None if last_ping is None else round(now - last_ping, 3),
            "last_sequence": run.last_recorded_seq,
            "counters": c.as_dict(), "endpoints": dict(run.endpoints),
            "subscribers": run.publisher.subscriptions if run.publisher else 0,
            "recent": {"window_s": self.alarm_limits.recent_s,
                       "lost": {k: int(v) for k, v in change.items()},
                       "stream_dropped": stream_dropped},
            "recorder": {"file": None if file is None else str(file),
                         "closed": bool(rec is not None and rec.writer is None
                                        and rec.ended),
                         "segment": len(rec.segments) - 1 if rec else None,
                         "recorded": rec.n_recorded if rec else 0,
                         "flushed": rec.n_flushed if rec else 0,
                         "free_mib": free_mib, **disk,
                         "stopped": rec.stopped if rec else None},
            "devices": devices, "navigation": nav, "workers": self.workers(interval),
            "n_events": run.n_events,
            "events": [{"time_utc": utc_text(te), "kind": k, "detail": d}
                       for te, k, d in run.events],
            "event_counts": dict(run.event_counts),
            "failure": run.failure,
        }

    def workers(self, interval: float) -> list[dict]:
        """The tile workers the catch-up service hears from, with their backlog on this
        run (pings recorded that they still lack, and those pings' time)."""
        run = self.run
        if run.service is None:
            return []
        out = []
        for w in run.service.workers():
            backlog = None
            if w["run_id"] == run.run_id:
                last = run.last_recorded_seq
                backlog = 0 if w["done"] or last is None else max(last + 1 - w["next"], 0)
            out.append({**w, "backlog_pings": backlog,
                        "backlog_s": None if backlog is None else round(backlog * interval,
                                                                        3)})
        return out

    def publish(self, force: bool = False, settle: bool = False) -> None:
        """Publish the status when due (``force``: now), its alarms first, after
        evaluating them (:mod:`svss_daq.alarms`); every alarm raised or cleared is an
        event (``alarm.raised`` / ``alarm.cleared``). ``settle``: alarms whose
        condition is gone clear at once (the run ended)."""
        now = time.monotonic()
        if not force and now < self._next:
            return
        self._next = now + self.setup.acquire.status.interval_s
        status = self.status()
        for what, alarm in self.alarms.update(evaluate(status, self.alarm_limits), now,
                                              settle=settle):
            if what == "raised":
                self.run.event("alarm.raised", f"{alarm.name}: {alarm.message}")
            else:
                self.run.event("alarm.cleared", f"{alarm.name}: the condition has gone "
                               f"(last said: {alarm.message})", logging.INFO)
        status["n_events"] = self.run.n_events
        if self.publisher is not None:
            self.publisher.publish({"alarms": self.alarms.listing(now), **status})
