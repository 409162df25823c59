"""The acquisition daemon's navigation monitor: the pose of every ping, and what the
navigation was doing while the run was recorded.

:class:`NavigationMonitor` holds the run's :class:`~svss_daq.navigation.Navigator`,
fed from the device readers' threads (GPS sentences, DVL ensembles, the sequencer's
transmit records for the ping clock) under one lock. It poses pings (none without a
navigation link; a failed solution is counted and said, the ping recorded without a
pose), tallies each ping's navigation flags (:class:`NavTally`) and says when they
change: GPS outage and back, poses held on the last sample and current again, DVL bottom
lock lost (with why) and back. The navigation's own notices (instrument clocks, the GPS
sigma gate) become run events, and it gives the status stream's and the summary's
``navigation``. See docs/acquisition.md and docs/navigation.md.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass

from .nav.clocks import describe_offset
from .navigation import Navigator
from .ping import (NAV_BOTTOM_LOCK, NAV_CLOCK_RETIMED, NAV_DEAD_RECKONED, NAV_GPS_FIX,
                   NAV_HELD, NavSnapshot)
from .status import pose_summary
from .daemon_run import RunState, utc_now_ns

log = logging.getLogger("svss_daq.daemon")      # one logger for the daemon and its parts

NAN = float("nan")


@dataclass
class NavTally:
    mode: str = "none"
    dead_reckoned: int = 0
    no_gps_fix: int = 0
    no_bottom_lock: int = 0
    last_quality: int = 0
    outage: bool = False
    lock_lost: bool = False
    held: int = 0               # pings posed on the last navigation sample held (NAV_HELD)
    clock_retimed: int = 0      # pings posed on re-timed instrument clocks
    holding: bool = False
    last_held_ns: int = 0

    #: the monitor's state, not counts: left out of the run's summary
    STATE = ("outage", "lock_lost", "holding", "last_held_ns")

    def counts(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k not in self.STATE}


def unknown_pose(t_ns: int) -> NavSnapshot:
    """The pose of a ping at ``t_ns`` that has none (every field NaN)."""
    return NavSnapshot(t_ns, NAN, NAN, NAN, NAN, NAN, NAN, NAN, NAN, NAN, NAN)


class NavigationMonitor:
    """The navigation of run ``run`` with the configuration ``setup``
    (:class:`~svss_daq.acquire_config.AcquireSetup`)."""

    def __init__(self, setup, run: RunState):
        self.run = run
        self.devices = setup.devices
        self.navigator = Navigator(setup.devices.navigation,
                                   setup.hardware.value.lever_arms,
                                   history_s=setup.acquire.navigation.history_s)
        self.lock = threading.Lock()
        self.tally = NavTally()
        self.last_pose: NavSnapshot | None = None      # the last ping's pose

    # -- fed from the readers' threads ---------------------------------------------------

    def add_reference(self, receive_ns: int, transmit_ns: int) -> None:
        """A transmit record's time on the ping clock, received at ``receive_ns``: the
        ping clock as the host sees it (for the instrument clocks)."""
        with self.lock:
            self.navigator.add_reference(receive_ns, transmit_ns)

    def on_nmea(self, record) -> None:
        """Each sentence to the navigation as it arrives, with its receive time: GST is
        paired with its fix by time of day there, HDT timed on the receiver's clock, and
        the receiver's clock judged against the ping clock."""
        now = utc_now_ns()
        with self.lock:
            self.navigator.add_nmea([(now, record)])

    def on_pd0(self, ensemble) -> None:
        now = utc_now_ns()
        with self.lock:
            self.navigator.add_pd0(ensemble, receive_ns=now)

    def has_data(self, link: str) -> bool:
        """Whether navigation link ``link`` ("gps" or "dvl") sent anything yet (a GPS
        fix; any DVL ensemble, with bottom track or without: the link is alive)."""
        if link == "gps":
            return bool(self.navigator.fixes)
        return bool(self.navigator.counts["dvl_ensembles"])

    # -- posing pings --------------------------------------------------------------------

    def caught_up(self, t_ns: int) -> bool:
        """Whether every navigation link has data at or after ``t_ns`` (a pose between
        samples, not extrapolated past the last one)."""
        nav, dev = self.navigator, self.devices
        with self.lock:
            for name, link in (("dvl", dev.dvl), ("gps", dev.gps)):
                latest = nav.latest_ns(name)     # on the ping clock (re-timed clocks too)
                if link is not None and not (latest is not None and latest >= t_ns):
                    return False
        return True

    def poses(self, times_ns: list[int]) -> list[NavSnapshot]:
        """The poses at ``times_ns`` in one solution; unknown (NaN) without a navigation
        link or a solution (counted, ``pose_errors``, and said at every 100)."""
        if self.devices.gps is None and self.devices.dvl is None:
            return [unknown_pose(t) for t in times_ns]
        try:
            with self.lock:
                return self.navigator.poses(times_ns)
        except (ValueError, IndexError) as exc:
            c = self.run.counters
            before = c.pose_errors
            c.pose_errors += len(times_ns)
            if before == 0 or before // 100 != c.pose_errors // 100:
                self.run.event("navigation.no_solution", f"no pose for {len(times_ns)} "
                               f"ping(s) ({exc}); recorded without one; "
                               f"{c.pose_errors} in all")
            return [unknown_pose(t) for t in times_ns]

    def count(self, nav: NavSnapshot) -> None:
        """Tally the pose ``nav`` of a ping being recorded; an event where the
        navigation's state changes (GPS outage, held poses, bottom lock)."""
        t, q = self.tally, nav.quality
        event = self.run.event
        dev = self.devices
        t.last_quality = q
        self.last_pose = nav
        gps, dr, lock = bool(q & NAV_GPS_FIX), bool(q & NAV_DEAD_RECKONED), bool(q & NAV_BOTTOM_LOCK)
        held = bool(q & NAV_HELD)
        t.mode = ("gps" if gps else "dead_reckoning" if dr else "held" if held else "none")
        if not gps:
            t.no_gps_fix += 1
        if dr:
            t.dead_reckoned += 1
        if held:
            t.held += 1
            t.last_held_ns = nav.time_ns
        if q & NAV_CLOCK_RETIMED:
            t.clock_retimed += 1
        if not lock and dev.dvl is not None:
            t.no_bottom_lock += 1
        if not gps and not t.outage and dev.gps is not None:
            t.outage = True
            event("navigation.gps_outage", "no GPS fix at the ping's time: " + (
                "dead reckoning on the DVL carries the pose" if dr else
                "the last navigation sample is held" if held else "no position"))
        elif gps and t.outage:
            t.outage = False
            event("navigation.gps_back", "GPS fixes again", logging.INFO)
        if held and not t.holding:
            t.holding = True
            event("navigation.held", "pings posed on the last navigation sample held "
                  "(flag NAV_HELD): no newer DVL or GPS record within acquire "
                  "navigation.wait_s of the ping (an instrument slower than that, or "
                  "silent)")
        elif not held and t.holding and (nav.time_ns - t.last_held_ns) * 1e-9 \
                > dev.navigation.held_clear_s:
            t.holding = False
            event("navigation.held_end", "pings posed on current navigation again "
                  f"(none held for navigation.held_clear_s); {t.held} held in all",
                  logging.INFO)
        if dev.dvl is not None:
            if not lock and not t.lock_lost:
                t.lock_lost = True
                event("navigation.bottom_lock_lost", self.why_no_lock(nav.time_ns))
            elif lock and t.lock_lost:
                t.lock_lost = False
                event("navigation.bottom_lock_back", "DVL bottom track again",
                      logging.INFO)

    def why_no_lock(self, t_ns: int) -> str:
        """Why a ping has no bottom lock: no DVL ensemble near it (silent, slow, or its
        clock elsewhere), or ensembles without bottom track."""
        with self.lock:       # (once per loss: a scan of the samples kept is cheap)
            nearest = min((d.time_ns - t_ns for d in self.navigator.dvl), key=abs,
                          default=None)
        gap_s = self.devices.navigation.dvl_max_gap_s
        if nearest is None:
            n = self.navigator.counts["dvl_ensembles"]
            return ("no DVL ensemble yet" if n == 0 else
                    f"no DVL ensemble near the ping ({n} received, none within the "
                    "navigation's history of it: the DVL's clock elsewhere?)") + \
                ": altitude unknown, no dead reckoning"
        if abs(nearest) * 1e-9 > gap_s:
            return (f"no DVL ensemble within navigation.dvl_max_gap_s {gap_s:g} s of the "
                    f"ping (the nearest {describe_offset(nearest * 1e-9)} from it: the DVL "
                    "slow or silent, or its clock elsewhere): altitude unknown, no dead "
                    "reckoning")
        return "no DVL bottom track: altitude unknown, no dead reckoning"

    def notices(self) -> None:
        """The navigation's notices (instrument clocks, the GPS sigma gate) as events
        (the navigation logged them already)."""
        with self.lock:
            notices = self.navigator.take_notices()
        for kind, detail, _level in notices:
            self.run.event(kind, detail, logging.DEBUG)

    # -- reports -------------------------------------------------------------------------

    def status(self) -> dict:
        """The status stream's ``navigation``: the tally, the last ping's pose and the
        solution's quality now."""
        t = self.tally
        nav = {"mode": t.mode, "last_quality": t.last_quality,
               "dead_reckoned": t.dead_reckoned, "no_gps_fix": t.no_gps_fix,
               "no_bottom_lock": t.no_bottom_lock, "held": t.held,
               "clock_retimed": t.clock_retimed,
               "pose_errors": self.run.counters.pose_errors}
        # "now" on the ping clock: the navigation's records are on it (a device whose
        # clock is not the host's, as the simulated one, is judged on its own time)
        # (unknown before the first transmit record: no solution is judged then)
        with self.lock:
            ping_now = self.navigator.ping_clock.ping_time(utc_now_ns())
        if self.last_pose is not None:
            nav["pose"] = pose_summary(self.last_pose, ping_now)
        quality = getattr(self.navigator, "quality", None)
        if callable(quality) and ping_now is not None:
            try:
                with self.lock:
                    nav["solution"] = quality(ping_now)
            except Exception as exc:             # status must never stop acquisition
                log.debug("navigation quality: %s", exc)
        return nav

    def summary(self) -> dict:
        """The run summary's ``navigation``: the tally's counts."""
        return self.tally.counts()
