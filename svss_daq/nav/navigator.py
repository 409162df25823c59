"""The collecting navigator: instrument records in, poses and a quality summary out."""

from __future__ import annotations

import collections
import dataclasses
import logging
import math
from typing import Iterable, Optional

import numpy as np

from svss_daq.ping import NAV_CLOCK_RETIMED, NAV_SMOOTHED, NavSnapshot

from .clocks import InstrumentClock, PingClock, describe_offset
from .fusion import attitude_poses, compute_poses, prior_at
from .geodesy import ned_to_geodetic
from .live import follow
from .nmea_samples import NmeaSampler
from .pd0_samples import dvl_sample_from_pd0
from .records import DvlSample, GpsFix, HeadingSample

logger = logging.getLogger(__name__)

#: notices (clock offsets, the GPS sigma gate) kept until the acquisition takes them
NOTICES_KEPT = 100
#: live poses chain across a gap between pings of up to this many ``live_follow_s``
#: (the pull toward the solution, 1 - exp(-gap / live_follow_s), is then complete to
#: 0.7 %); a gap in the pings is not one in the solution (a chain that restarted after
#: 2 s without pings, as a loaded simulator's dropped pings made, jumped 120 mm)
LIVE_CHAIN_TAUS = 5.0
#: fixes given out recently, for their withdrawal (a late GST or GGA of their epoch)
GIVEN_KEPT = 256
#: instruments whose clocks are judged, and the record lists each feeds
CLOCK_LISTS = {"gps": ("fixes", "headings"), "dvl": ("dvl",)}


class Navigator:
    """Collects GPS, heading and DVL records and poses pings from them.

    ``add_nmea`` takes NMEA records of ``svss_daq.protocols.nmea``, or ``(receive_ns,
    record)`` pairs (the host's receive time; see
    :class:`~svss_daq.nav.nmea_samples.NmeaSampler` for GST pairing and HDT times);
    ``add_pd0`` PD0 ensembles with their ``receive_ns``; ``add_reference`` the ping
    clock's events as received (the sequencer's transmit records). ``poses(times_ns)``
    poses pings from everything collected (kept for ``history_s``); ``quality(now_ns)``
    summarises the state for a status stream; :meth:`take_notices` gives the events
    for the acquisition (``(kind, detail, logging level)``: clock offsets, the GPS
    sigma gate).

    Survey origin (:attr:`origin`): the configured one; else the first fix **with a
    height** (an RMC has none; a configured latitude and longitude without a height
    take their height from it); None until then (the fusion's own fallback applies).

    Clocks (:mod:`svss_daq.nav.clocks`): given receive times and ping-clock events,
    each instrument's offset from the ping clock is the median over its records of the
    latest ``clock_window_s`` (at least ``clock_records``) of (receive time on the ping
    clock - instrument time). When every one of them is beyond ``clock_max_offset_s``
    the instrument is named (notice ``navigation.clock_offset``), listed in
    :attr:`retimed` and its records re-timed onto the ping clock: instrument time +
    that median, frozen, so the spacing of its own clock is kept (records kept so far
    included). Without ping-clock events
    nothing is judged (the ping clock is unknown): records keep their own times.
    """

    def __init__(self, cfg, lever_arms, history_s: float = 600.0) -> None:
        self.cfg, self.lever_arms, self.history_ns = cfg, lever_arms, int(history_s * 1e9)
        self.fixes: list[GpsFix] = []
        self.headings: list[HeadingSample] = []
        self.dvl: list[DvlSample] = []
        self.origin: Optional[tuple[float, float, float]] = None
        if None not in (cfg.origin_latitude_deg, cfg.origin_longitude_deg, cfg.origin_height_m):
            self.origin = (cfg.origin_latitude_deg, cfg.origin_longitude_deg,
                           cfg.origin_height_m)
        self._live_last: Optional[NavSnapshot] = None   # the last live pose given (poses())
        self._first_latlon: Optional[tuple[float, float]] = None
        self._state: dict = {}    # the live filter's states at the DVL samples (a window's prior)
        self.counts = {"gps_fixes": 0, "gps_rejected": 0, "gps_rejected_sigma": 0,
                       "gps_gst_missing": 0, "dvl_ensembles": 0, "dvl_samples": 0,
                       "dvl_no_lock": 0}
        self.notices: collections.deque = collections.deque(maxlen=NOTICES_KEPT)
        #: instruments whose records are re-timed onto the ping clock ("gps", "dvl")
        self.retimed: set[str] = set()
        self.ping_clock = PingClock()
        max_ns = int(round(cfg.clock_max_offset_s * 1e9))
        window_ns = int(round(cfg.clock_window_s * 1e9))
        self.clocks = {name: InstrumentClock(name, max_ns, cfg.clock_records, window_ns)
                       for name in CLOCK_LISTS}
        self._nmea = NmeaSampler(cfg.course_min_speed_m_s, cfg.gps_max_sigma_m,
                                 cfg.gps_fix_max_age_s, self.counts)
        self._appended = {"fixes": 0, "headings": 0, "dvl": 0}
        self._given: collections.OrderedDict = collections.OrderedDict()
        self._last_fix: Optional[GpsFix] = None
        self._last_dvl: Optional[DvlSample] = None
        self._last_lock_ns: Optional[int] = None
        self._last_hdt_ns: Optional[int] = None
        self._last_course_ns: Optional[int] = None
        self._last_compass_ns: Optional[int] = None

    # -- input ---------------------------------------------------------------------------

    def add_fix(self, f: GpsFix) -> None:
        """A gated GPS fix, on the ping clock."""
        if self.origin is None and self._first_latlon is None:
            # the horizontal origin is fixed by the first fix (an RMC has no height: the
            # height comes from the first fix with one, the plane stays where it was)
            self._first_latlon = (f.latitude_deg, f.longitude_deg)
        if self.origin is None and math.isfinite(f.height_m):
            cfg = self.cfg
            if cfg.origin_latitude_deg is not None and cfg.origin_longitude_deg is not None:
                self.origin = (cfg.origin_latitude_deg, cfg.origin_longitude_deg, f.height_m)
                logger.info("navigation: survey origin height %.3f m from the first fix "
                            "with a height (configured latitude and longitude)", f.height_m)
            else:
                self.origin = (*self._first_latlon, f.height_m)
                logger.info("navigation: survey origin %.8f, %.8f (the first fix), height "
                            "%.3f m (the first fix with a height)", *self.origin)
        self.fixes.append(f)
        self._appended["fixes"] += 1
        self.counts["gps_fixes"] += 1
        if self._last_fix is None or f.time_ns >= self._last_fix.time_ns:
            self._last_fix = f

    def add_nmea(self, records: Iterable) -> None:
        """NMEA records, or ``(receive_ns, record)`` pairs, in the order received."""
        for item in records:
            rx, rec = item if isinstance(item, tuple) else (None, item)
            t = getattr(rec, "time_ns", None)
            if rx is not None and t is not None:
                self._observe("gps", rx, t)
            self._take_nmea(*self._nmea.feed([item]))

    def flush(self) -> None:
        """Decide the GPS epochs still waiting for their GST (the end of a recording:
        their GST will not come)."""
        self._take_nmea(*self._nmea.flush())

    def _take_nmea(self, fixes, heads, gone) -> None:
        off = self.clocks["gps"].applied_ns
        for f in fixes:
            g = f if off == 0 else dataclasses.replace(f, time_ns=f.time_ns + off)
            self._given[id(f)] = [f, g]          # f kept: its id stays its own
            while len(self._given) > GIVEN_KEPT:
                self._given.popitem(last=False)
            self.add_fix(g)
        for f in gone:
            pair = self._given.pop(id(f), None)
            if pair is None:
                continue
            for k in range(len(self.fixes) - 1, -1, -1):
                if self.fixes[k] is pair[1]:
                    del self.fixes[k]
                    self.counts["gps_fixes"] -= 1
                    break
            if self._last_fix is pair[1]:
                self._last_fix = max(self.fixes, key=lambda x: x.time_ns, default=None)
        for h in heads:
            if off:
                h = dataclasses.replace(h, time_ns=h.time_ns + off)
            if h.from_course:
                self._last_course_ns = max(self._last_course_ns or h.time_ns, h.time_ns)
            else:
                self._last_hdt_ns = max(self._last_hdt_ns or h.time_ns, h.time_ns)
            self.headings.append(h)
            self._appended["headings"] += 1
        while self._nmea.notices:
            kind, detail, level = self._nmea.notices.pop(0)
            self.notices.append((kind, detail, level))

    def add_pd0(self, ensemble, receive_ns: Optional[int] = None) -> None:
        """A decoded PD0 ensemble; ``receive_ns``: when the host received it (its clock
        is then judged against the ping clock)."""
        self.counts["dvl_ensembles"] += 1
        t = getattr(getattr(ensemble, "variable", None), "time_ns", None)
        if receive_ns is not None and t is not None:
            self._observe("dvl", receive_ns, t)
        d = dvl_sample_from_pd0(ensemble, self.cfg.dvl_min_beams,
                                math.radians(self.cfg.dvl_beam_angle_deg),
                                math.radians(self.cfg.magnetic_declination_deg))
        if d is not None:
            self.add_dvl(d)

    def add_dvl(self, d: DvlSample) -> None:
        """A DVL sample on its instrument's clock (re-timed here when that is wrong)."""
        off = self.clocks["dvl"].applied_ns
        if off:
            d = dataclasses.replace(d, time_ns=d.time_ns + off)
        self.dvl.append(d)
        self._appended["dvl"] += 1
        self.counts["dvl_samples"] += 1
        if self._last_dvl is None or d.time_ns >= self._last_dvl.time_ns:
            self._last_dvl = d
        if d.bottom_lock:
            self._last_lock_ns = max(self._last_lock_ns or d.time_ns, d.time_ns)
        else:
            self.counts["dvl_no_lock"] += 1
        if math.isfinite(d.heading_rad):
            self._last_compass_ns = max(self._last_compass_ns or d.time_ns, d.time_ns)

    # -- clocks --------------------------------------------------------------------------

    def add_reference(self, receive_ns: int, ping_ns: int) -> None:
        """A ping-clock event: ``ping_ns`` on the ping clock, received at ``receive_ns``
        on the clock of the records' receive times (the sequencer's transmit record).
        One call with equal times says the receive clock is the ping clock."""
        self.ping_clock.add(receive_ns, ping_ns)

    def _observe(self, name: str, receive_ns: int, instrument_ns: int) -> None:
        rx = self.ping_clock.ping_time(receive_ns)
        if rx is None:
            return
        clock = self.clocks[name]
        mark = {k: self._appended[k] for k in CLOCK_LISTS[name]}
        change = clock.observe(rx - int(instrument_ns), instrument_ns, mark)
        if change is not None:
            self._retime(clock, *change)

    def _retime(self, clock: InstrumentClock, old: int, new: int, since) -> None:
        """Move ``clock``'s records kept (all, or those from the mark ``since``) from
        ``old`` to ``new`` applied offset; name the instrument."""
        name, delta = clock.name, new - old
        for key in CLOCK_LISTS[name]:
            lst = getattr(self, key)
            n = len(lst) if since is None else min(len(lst), self._appended[key] - since[key])
            if n <= 0:
                continue
            moved = {}
            for k in range(len(lst) - n, len(lst)):
                x = dataclasses.replace(lst[k], time_ns=lst[k].time_ns + delta)
                moved[id(lst[k])] = x
                lst[k] = x
            if key == "fixes":
                for pair in self._given.values():
                    pair[1] = moved.get(id(pair[1]), pair[1])
        if name == "gps":
            self._last_fix = max(self.fixes, key=lambda x: x.time_ns, default=None)
            self._last_hdt_ns = None if self._last_hdt_ns is None else self._last_hdt_ns + delta
            self._last_course_ns = (None if self._last_course_ns is None
                                    else self._last_course_ns + delta)
        else:
            self._last_dvl = max(self.dvl, key=lambda x: x.time_ns, default=None)
            for a in ("_last_lock_ns", "_last_compass_ns"):
                v = getattr(self, a)
                setattr(self, a, None if v is None else v + delta)
        limit = self.cfg.clock_max_offset_s
        n = len(clock.window)
        span = (clock.window[-1][0] - clock.window[0][0]) * 1e-9
        if new:
            self.retimed.add(name)
            off_s = -new * 1e-9                       # instrument minus ping clock
            kind, level = "navigation.clock_offset", logging.WARNING
            detail = (f"{name} clock {describe_offset(off_s)} ({off_s:+.3f} s) off the ping "
                      f"clock (instrument minus ping clock, median of {n} records over "
                      f"{span:.1f} s, every one beyond navigation.clock_max_offset_s "
                      f"{limit:g} s): its records are re-timed onto the ping clock")
        else:
            self.retimed.discard(name)
            off_s = -(clock.offset_ns or 0) * 1e-9
            kind, level = "navigation.clock_ok", logging.INFO
            detail = (f"{name} clock within {limit:g} s of the ping clock again "
                      f"({off_s:+.3f} s): its records are no longer re-timed")
        logger.log(level, "navigation: %s", detail)
        self.notices.append((kind, detail, level))

    def take_notices(self) -> list:
        """The notices since the last call: ``(kind, detail, logging level)``."""
        out = list(self.notices)
        self.notices.clear()
        return out

    def latest_ns(self, name: str) -> Optional[int]:
        """On the ping clock: the latest DVL sample's time (``"dvl"``), or the latest
        GPS epoch decided (``"gps"``: given out or rejected; an epoch waiting for its
        GST is not), None before the first."""
        if name == "dvl":
            return None if self._last_dvl is None else self._last_dvl.time_ns
        d = self._nmea.decided_ns
        return None if d is None else d + self.clocks["gps"].applied_ns

    def prune(self, before_ns: int) -> None:
        self.fixes = [f for f in self.fixes if f.time_ns >= before_ns]
        self.headings = [h for h in self.headings if h.time_ns >= before_ns]
        self.dvl = [d for d in self.dvl if d.time_ns >= before_ns]

    def survey_origin(self) -> Optional[tuple[float, float, float]]:
        """The survey origin the poses use: :attr:`origin`, else (no fix with a height
        yet, or an RMC-only receiver) the first fix's latitude and longitude at height 0;
        None without a fix or a configured origin (the fusion's own rule then)."""
        if self.origin is not None:
            return self.origin
        cfg = self.cfg
        if cfg.origin_latitude_deg is not None and cfg.origin_longitude_deg is not None:
            return (cfg.origin_latitude_deg, cfg.origin_longitude_deg, cfg.origin_height_m or 0.0)
        if self._first_latlon is not None:
            return (*self._first_latlon, 0.0)
        return None

    def poses(self, times_ns, smooth: bool = False) -> list[NavSnapshot]:
        """Poses at ``times_ns`` from the records collected.

        Live (``smooth`` False): the records of the last ``history_s`` (older ones are
        dropped) through the Kalman filter and RTS smoother; the acquisition poses a ping
        once the records reach ``fixed_lag_s`` past it, so this is a fixed-lag smoother.
        ``smooth``: every record kept, the whole recording smoothed (re-navigation;
        poses flagged NAV_SMOOTHED). Poses built on re-timed instrument clocks carry
        NAV_CLOCK_RETIMED."""
        times = np.asarray(times_ns, dtype=np.int64).reshape(-1)
        if times.size and not smooth:
            self.prune(int(times.min()) - self.history_ns)
        flags = NAV_SMOOTHED if smooth else 0
        if getattr(self, "retimed", None):
            flags |= NAV_CLOCK_RETIMED
        origin = self.survey_origin()
        if smooth:
            return compute_poses(times, self.fixes, self.headings, self.dvl, self.cfg,
                                 self.lever_arms, origin, flags=flags)
        if origin is None:
            # no survey origin configured and no GPS fix accepted to take it from: no
            # position, but the attitude and heading the instruments give, flagged
            return attitude_poses(times, self.headings, self.dvl, self.cfg, flags)
        prev = self._live_last
        chain = prev is not None and times.size and int(times.min()) > prev.time_ns
        query = np.concatenate([[prev.time_ns], times]) if chain else times
        # the window's first DVL sample starts from the state the previous window had
        # there (what the prune dropped is carried, not forgotten)
        prior = prior_at(self._state, min(d.time_ns for d in self.dvl)) if self.dvl else None
        state: dict = {}
        fused = compute_poses(query, self.fixes, self.headings, self.dvl, self.cfg,
                              self.lever_arms, origin, flags=flags, prior=prior,
                              state_out=state)
        self._state = state
        if not times.size:
            return fused
        # live: each ping placed from the one before it (svss_daq.nav.live)
        prev_now = fused[0] if chain else None
        fused = fused[1:] if chain else fused
        order = np.argsort(times, kind="stable")
        live = follow(prev if chain else None, prev_now, [fused[i] for i in order],
                      self.cfg.live_follow_s, LIVE_CHAIN_TAUS * self.cfg.live_follow_s)
        out = [None] * len(fused)
        for i, pose in zip(order, live):
            out[i] = pose
        if origin is not None:        # the chained positions' own latitude and longitude
            ned = np.array([[p.north_m, p.east_m, p.down_m] for p in out])
            lat, lon, _ = ned_to_geodetic(ned, origin)
            out = [dataclasses.replace(p, latitude_deg=float(la), longitude_deg=float(lo))
                   for p, la, lo in zip(out, lat, lon)]
        last = live[-1]
        if self._live_last is None or last.time_ns > self._live_last.time_ns:
            self._live_last = last
        return out

    def quality(self, now_ns: int) -> dict:
        """JSON-serialisable state at ``now_ns`` (O(1)): ``mode`` ("gps" within
        ``gps_fix_max_age_s`` of the last fix, "dead_reckoning" with bottom lock within
        ``dvl_max_gap_s`` and a survey origin, else "none"), ``gps_fix_age_s``,
        ``dvl_age_s`` (s, null: never), ``heading_source`` ("hdt", "dvl_compass",
        "course" or "none": the first within ``heading_max_age_s``), ``bottom_lock``,
        ``gps_sigma_m`` (GST sigma of the last fix; while rejecting by sigma, the
        receiver's latest; null: not sent), ``gps_gate``
        ("accepting", "sigma": rejecting fixes by GST sigma, "no_fix": rejecting
        non-fixes), ``clock_offset_s`` (per instrument measured: its clock minus the
        ping clock, s), ``clock_retimed`` (instruments re-timed onto the ping clock) and
        the counters ``gps_fixes``, ``gps_rejected``, ``gps_rejected_sigma``,
        ``gps_gst_missing``, ``dvl_ensembles``, ``dvl_samples``, ``dvl_no_lock``."""
        cfg = self.cfg

        def age(t):
            return None if t is None else (int(now_ns) - int(t)) * 1e-9

        fix_age = age(None if self._last_fix is None else self._last_fix.time_ns)
        dvl_age = age(None if self._last_dvl is None else self._last_dvl.time_ns)
        lock_age = age(self._last_lock_ns)
        bottom_lock = (self._last_dvl is not None and self._last_dvl.bottom_lock
                       and dvl_age is not None and abs(dvl_age) <= cfg.dvl_max_gap_s)
        has_origin = (self.origin is not None or cfg.origin_latitude_deg is not None
                      or self._last_fix is not None)
        if fix_age is not None and abs(fix_age) <= cfg.gps_fix_max_age_s:
            mode = "gps"
        elif lock_age is not None and abs(lock_age) <= cfg.dvl_max_gap_s and has_origin:
            mode = "dead_reckoning"
        else:
            mode = "none"
        heading = "none"
        for name, t in (("hdt", self._last_hdt_ns), ("dvl_compass", self._last_compass_ns),
                        ("course", self._last_course_ns)):
            a = age(t)
            if a is not None and abs(a) <= cfg.heading_max_age_s:
                heading = name
                break
        sigma = None
        if self._last_fix is not None and math.isfinite(self._last_fix.sigma_m):
            sigma = float(self._last_fix.sigma_m)
        if self._nmea.gate == "sigma" or sigma is None:
            # rejecting by sigma (or nothing accepted yet): the sigma the receiver says,
            # not that of the last fix accepted
            sigma = self._nmea.latest_sigma_m if self._nmea.latest_sigma_m is not None \
                else sigma
        clocks = {n: -c.offset_ns * 1e-9 for n, c in self.clocks.items()
                  if c.offset_ns is not None}
        return {"mode": mode, "gps_fix_age_s": fix_age, "dvl_age_s": dvl_age,
                "heading_source": heading, "bottom_lock": bool(bottom_lock),
                "gps_sigma_m": sigma, "gps_gate": self._nmea.gate,
                "clock_offset_s": clocks, "clock_retimed": sorted(self.retimed),
                **{k: int(v) for k, v in self.counts.items()}}
