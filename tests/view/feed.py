"""A status stream for the view's tests: the daemon's own publisher
(:class:`svss_daq.status.StatusPublisher`, the real message format) sending snapshots of
a run in the daemon's layout every 0.2 s, their alarms found by the daemon's own checks
(:func:`svss_daq.alarms.evaluate`, :class:`~svss_daq.alarms.AlarmTracker`): the pings
stopped (critical ``pings.stopped``) while the boat moves along its line."""

from __future__ import annotations

import copy
import math
import threading
import time

from svss_daq.alarms import AlarmLimits, AlarmTracker, evaluate
from svss_daq.status import StatusPublisher, utc_text

from .synthetic import HEADING_RAD, ORIGIN, T0_NS, line

LIM = AlarmLimits(ping_interval_s=0.1, no_ping_intervals=5, min_rate_fraction=0.8,
                  rate_window_s=10, disk_min_free_mib=4096, disk_min_time_left_s=1800,
                  gps_fix_max_age_s=2.0, gps_max_sigma_m=5.0, dead_reckoning_max_s=60,
                  device_silent_s=3.0, worker_max_backlog_s=20, recent_s=10)

BASE = {
    "state": "recording", "recording_s": 60.0, "uptime_s": 62.0, "ping_rate_hz": 0.0,
    "schedule_rate_hz": 10.0, "last_ping_age_s": 4.2,
    "counters": {"delivered": 300, "recorded": 300, "published": 300, "dropped": 0},
    "recent": {"lost": {"never_delivered": 0, "incomplete": 0}, "stream_dropped": 0},
    "recorder": {"file": "/data/runs/line-view_000.h5", "segment": 0, "flushed": 300,
                 "free_mib": 100000.0, "fill_mib_s": 2.4, "time_left_s": 41000.0,
                 "stopped": None},
    "devices": {"sequencer": {"connected": True, "silent_s": 0.1},
                "digitiser": {"connected": True},
                "dvl": {"connected": True, "silent_s": 0.2},
                "gps": {"connected": True, "silent_s": 0.3}},
    "navigation": {"mode": "gps", "solution": {
        "mode": "gps", "gps_fix_age_s": 0.4, "dvl_age_s": 0.1, "heading_source": "hdt",
        "bottom_lock": True, "gps_sigma_m": 0.05, "gps_gate": "accepting",
        "clock_offset_s": {"gps": 0.01}, "clock_retimed": [], "gps_rejected_sigma": 0}},
    "workers": [{"client": "w1", "run_id": "line-view", "next": 100, "done": False,
                 "backlog_pings": 2, "backlog_s": 0.2, "open_tiles": 3,
                 "max_open_tiles": 12, "memory_bound_age_s": None}],
    "events": [],
}


class StatusFeed:
    """Publishes on ``tcp://127.0.0.1:*`` (:attr:`endpoint`) until :meth:`stop`."""

    def __init__(self, run_id: str = "line-view", interval_s: float = 0.2):
        self.pub = StatusPublisher("tcp://127.0.0.1:*")
        self.endpoint = self.pub.endpoint
        self.run_id, self.interval_s = run_id, interval_s
        self.tracker = AlarmTracker(0.5)
        self._stop = threading.Event()
        self.paused = threading.Event()       # set: nothing published (a run over)
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def snapshot(self, k: int) -> dict:
        from svss_daq.navigation import ned_to_geodetic
        s = copy.deepcopy(BASE)
        along = min(0.05 * k, 12.0)             # the boat along its line, m
        n, e, _ = line().tile_to_ned([[along, 0.0, -3.0]])[0]
        lat, lon, _ = ned_to_geodetic([n, e, 0.0], ORIGIN)
        s["navigation"]["pose"] = {
            "time_utc": utc_text(T0_NS + k * 10**8), "age_s": 0.3,
            "latitude_deg": float(lat), "longitude_deg": float(lon),
            "north_m": float(n), "east_m": float(e), "down_m": 0.0, "speed_m_s": 1.0,
            "course_deg": math.degrees(HEADING_RAD), "heading_deg": math.degrees(HEADING_RAD),
            "altitude_m": 2.5, "position_source": "gps", "speed_source": "dvl",
            "heading_source": "hdt", "altitude_source": "dvl"}
        s.update(run_id=self.run_id, time_utc=utc_text(time.time_ns()))
        return s

    def _run(self) -> None:
        k = 0
        while not self._stop.is_set():
            if self.paused.is_set():
                self._stop.wait(self.interval_s)
                continue
            s = self.snapshot(k)
            now = time.monotonic()
            self.tracker.update(evaluate(s, LIM), now)
            self.pub.publish({"alarms": self.tracker.listing(now), **s})
            k += 1
            self._stop.wait(self.interval_s)

    def stop(self) -> None:
        if not self._stop.is_set():
            self._stop.set()
            self.thread.join(5)
            self.pub.close()
