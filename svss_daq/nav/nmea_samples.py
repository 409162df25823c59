"""GPS fixes and headings from decoded NMEA 0183 records.

:class:`NmeaSampler` takes the records one at a time, as a receiver sends them, and
pairs each fix with its epoch's GST by the sentences' time of day (never by arrival or
by how records were batched); :func:`samples_from_nmea` is the same for a whole list.
"""

from __future__ import annotations

import collections
import logging
import math
from dataclasses import dataclass
from typing import Iterable, Optional

from .records import GpsFix, HeadingSample

logger = logging.getLogger(__name__)


def gst_sigma_m(rec) -> float:
    """Horizontal 1-sigma (DRMS, m) of a GST record: sqrt(sigma_lat^2 + sigma_lon^2),
    else from the error ellipse's semi-axes; NaN when neither is sent."""
    a, b = rec.sigma_latitude_m, rec.sigma_longitude_m
    if a is None or b is None:
        a, b = rec.sigma_major_m, rec.sigma_minor_m
    if a is None or b is None:
        return float("nan")
    return math.hypot(a, b)


#: GGA fix qualities that are not a GNSS fix: 0 invalid, 6 estimated (dead reckoning)
GGA_NOT_A_FIX = (0, 6)
#: RMC/GLL mode letters that are not a GNSS fix: E estimated, N not valid
RMC_MODE_NOT_A_FIX = ("E", "N")

_DAY_NS = 86_400 * 10**9
#: GST sigmas kept for pairing (by time of day): many epochs more than a GST can lag
_SIGMAS_KEPT = 256
#: HDT records kept while waiting for the first timed GPS record (their clock reference)
_HDT_WAITING_KEPT = 16
#: a receiver that has sent GST counts as still sending it until none has come for this
#: long (s): its fixes wait for their own GST (at most fix_max_age_s) meanwhile
GST_STOPPED_S = 5.0
#: an RMC course is a heading only where the receiver has moved: over at least this
#: baseline (s) to the fix it is judged against, its displacement at the course speed
#: threshold's pace or more and its bearing within COURSE_MAX_DEVIATION_DEG of the course
COURSE_BASELINE_S = 5.0
COURSE_MAX_DEVIATION_DEG = 30.0
_COURSE_KEPT_S = 10.0
_EARTH_RADIUS_M = 6_371_000.0


def _tod_after(a: int, b: int) -> bool:
    """Whether time of day ``a`` is after ``b`` (across midnight: within half a day)."""
    d = (a - b) % _DAY_NS
    return 0 < d < _DAY_NS // 2


@dataclass
class _Epoch:
    """One receiver epoch (one time of day): its GGA and RMC, what was decided."""
    time_ns: int
    tod_ns: int
    gga: object = None
    rmc: object = None
    fix: Optional[GpsFix] = None     # the fix given out (None: none, or not decided yet)
    decided: bool = False
    own_sigma: bool = False          # decided with its own GST's sigma


class NmeaSampler:
    """GPS fixes and headings from NMEA records fed as they arrive (:meth:`feed`).

    Fixes: GGA with a real fix and a date, else (an epoch without GGA) RMC with status
    A; GGA quality 0 or 6 and RMC status V or mode E/N are rejected, and an RMC does
    not stand in for its epoch's GGA (a GGA arriving after its epoch's RMC replaces the
    RMC's fix, which :meth:`feed` then retracts). GST gives the fix of the same **time of
    day** its sigma (:func:`gst_sigma_m`), whichever of the two arrives first; a fix
    with sigma above ``max_sigma_m`` is rejected.

    A fix whose GST has not arrived, from a receiver that sends GST (a GST within
    ``fix_max_age_s`` of the fix), is *pending*: given out only once its GST arrives,
    or, when a later epoch's GST arrives or the receiver's clock has gone
    ``fix_max_age_s`` past it (its GST was lost), gated with the receiver's latest
    sigma (counted ``gps_gst_missing``). A receiver that has stopped sending GST has
    its fixes gated with the last sigma it sent. Whether a receiver sends GST is learnt
    from its first epoch: that one waits for a record of a later time; if its GST has
    not come by then, the receiver sends none and its fixes are given out at once with
    an unknown sigma (NaN). Should a GST for an epoch so decided arrive after all (a
    receiver that sends GST after the next epoch's sentences), the fix is retracted
    and given out again with its sigma, or rejected.

    Headings: HDT; RMC course above ``course_min_speed_m_s`` where the receiver has
    moved along it (:meth:`_course_ok`; flagged ``from_course``).
    HDT has no time of its own: fed as a ``(receive_ns, record)`` pair it takes the
    time of the receiver's latest timed record plus the receive time elapsed since that
    record arrived (so it is on the receiver's clock); where the timed records came
    without receive times, ``receive_ns`` is taken as the HDT's own time (the caller
    stamped it with its epoch).

    Counters (in ``counts``): ``gps_rejected`` (every rejected fix),
    ``gps_rejected_sigma`` (of those, by sigma), ``gps_gst_missing``. Every change of
    the gate's state (accepting, rejecting by sigma, rejecting non-fixes) is logged with
    its reason, once, and the sigma gate's changes are put in :attr:`notices` as
    ``(kind, detail, logging level)`` for the acquisition's events.
    """

    def __init__(self, course_min_speed_m_s: float = 0.3, max_sigma_m: float = math.inf,
                 fix_max_age_s: float = 1.5, counts: Optional[dict] = None) -> None:
        self.course_min_speed_m_s = course_min_speed_m_s
        self.max_sigma_m = max_sigma_m
        self.max_age_ns = int(fix_max_age_s * 1e9)
        self.counts = counts if counts is not None else {}
        for k in ("gps_rejected", "gps_rejected_sigma", "gps_gst_missing"):
            self.counts.setdefault(k, 0)
        self.notices: list = []
        self.gate = "accepting"          # or "sigma", "no_fix"
        self.decided_ns: Optional[int] = None   # the latest decided epoch's time
        self.gps_now_ns: Optional[int] = None   # the receiver's latest time
        self._epochs: dict[int, _Epoch] = {}    # by time of day
        self._sigmas: collections.OrderedDict = collections.OrderedDict()
        self._last_sigma: Optional[float] = None
        self._sends_gst: Optional[bool] = None      # None: not known yet
        self._last_gst_ns: Optional[int] = None     # receiver time of the last GST
        self._last_gst_tod: Optional[int] = None
        self._gst_missing_run = False
        self._timed: Optional[tuple] = None         # (time_ns, receive_ns or None)
        self._hdt_waiting: collections.deque = collections.deque(maxlen=_HDT_WAITING_KEPT)
        #: (time ns, latitude, longitude) of recent RMC fixes, for the course gate
        self._course_fixes: collections.deque = collections.deque()
        self._out_fixes: list = []
        self._out_heads: list = []
        self._retracted: list = []

    @property
    def latest_sigma_m(self) -> float | None:
        """The receiver's latest GST sigma (DRMS, m), whether its fix was accepted or
        not; None before any."""
        return self._last_sigma

    # -- input -------------------------------------------------------------------------

    def feed(self, records: Iterable) -> tuple[list[GpsFix], list[HeadingSample], list[GpsFix]]:
        """Take records (or ``(receive_ns, record)`` pairs); return the fixes and
        headings decided by them (time order) and the fixes given out earlier that
        are withdrawn (to be removed by identity)."""
        from svss_daq.protocols import nmea
        for item in records:
            rx = None
            if isinstance(item, tuple):
                rx, rec = item
            else:
                rec = item
            if isinstance(rec, nmea.HdtHeading):
                self._hdt(rx, rec)
                continue
            t = getattr(rec, "time_ns", None)
            if t is None:
                # a GST before any dated record (GST first in its epoch, at the start):
                # its sigma still pairs with its epoch by time of day
                if isinstance(rec, nmea.GstStatistics):
                    self._gst(rec)
                continue
            self._timed_record(t, rx)
            if isinstance(rec, nmea.GstStatistics):
                self._gst(rec)
            elif isinstance(rec, nmea.GgaFix):
                self._gga(rec)
            elif isinstance(rec, nmea.RmcFix):
                self._rmc(rec)
            self._settle(final=False)
        return self._take()

    def flush(self) -> tuple[list[GpsFix], list[HeadingSample], list[GpsFix]]:
        """Decide every pending epoch now (the end of a recording)."""
        self._settle(final=True)
        return self._take()

    def _take(self):
        f, h, r = self._out_fixes, self._out_heads, self._retracted
        self._out_fixes, self._out_heads, self._retracted = [], [], []
        f.sort(key=lambda x: x.time_ns)
        h.sort(key=lambda x: x.time_ns)
        return f, h, r

    def _timed_record(self, t: int, rx: Optional[int]) -> None:
        self.gps_now_ns = t if self.gps_now_ns is None else max(self.gps_now_ns, t)
        first = self._timed is None
        self._timed = (t, rx)
        if first:
            for rx_h, heading in self._hdt_waiting:
                self._hdt(rx_h, heading)
            self._hdt_waiting.clear()

    def _hdt(self, rx: Optional[int], rec) -> None:
        if rec.heading_rad is None or rx is None:
            return
        if self._timed is None:          # no clock reference yet: wait for one
            self._hdt_waiting.append((rx, rec))
            return
        t_ref, rx_ref = self._timed
        t = int(rx) if rx_ref is None else t_ref + (int(rx) - rx_ref)
        self._out_heads.append(HeadingSample(t, float(rec.heading_rad)))

    def _gst(self, rec) -> None:
        tod = rec.time_of_day_ns
        if tod is None:
            return
        sigma = gst_sigma_m(rec)
        self._sigmas[tod] = sigma
        self._sigmas.move_to_end(tod)
        while len(self._sigmas) > _SIGMAS_KEPT:
            self._sigmas.popitem(last=False)
        if math.isfinite(sigma):
            self._last_sigma = sigma
        self._sends_gst = True
        if rec.time_ns is not None:
            self._last_gst_ns = rec.time_ns
        if self._last_gst_tod is None or _tod_after(tod, self._last_gst_tod):
            self._last_gst_tod = tod
        ep = self._epochs.get(tod)
        if ep is not None and ep.decided and not ep.own_sigma and (ep.gga or ep.rmc):
            # decided before the receiver was known to send GST: decide again
            if ep.fix is not None:
                self._retracted.append(ep.fix)
            elif self._rejected_for_sigma_only(ep):
                self.counts["gps_rejected"] -= 1
                self.counts["gps_rejected_sigma"] -= 1
            else:
                return
            ep.decided, ep.fix = False, None

    def _rejected_for_sigma_only(self, ep: _Epoch) -> bool:
        return ep.gga is None or ep.gga.fix_quality not in GGA_NOT_A_FIX

    def _epoch(self, rec) -> _Epoch:
        tod = rec.time_of_day_ns
        ep = self._epochs.get(tod)
        if ep is None or abs(ep.time_ns - rec.time_ns) >= _DAY_NS // 2:
            ep = self._epochs[tod] = _Epoch(int(rec.time_ns), tod)
        return ep

    def _gga(self, rec) -> None:
        if rec.time_of_day_ns is None:
            return
        if (rec.latitude_deg is None or rec.longitude_deg is None) \
                and rec.fix_quality not in GGA_NOT_A_FIX:
            return
        ep = self._epoch(rec)
        if ep.gga is not None:
            return                       # a repeated GGA: the first one counts
        ep.gga = rec
        if ep.decided:                   # decided on its RMC: the GGA rules
            if ep.fix is not None:
                self._retracted.append(ep.fix)
            ep.decided, ep.fix = False, None

    def _rmc(self, rec) -> None:
        if not (rec.valid and (rec.mode or "A").upper() not in RMC_MODE_NOT_A_FIX):
            self._reject("no_fix", f"RMC status {'A' if rec.valid else 'V'} mode "
                         f"{rec.mode or '-'} at {_tod_text(rec.time_of_day_ns)}")
            return
        if self._course_ok(rec):
            self._out_heads.append(HeadingSample(int(rec.time_ns), float(rec.course_rad),
                                                 from_course=True))
        if rec.latitude_deg is None or rec.longitude_deg is None or rec.time_of_day_ns is None:
            return
        ep = self._epoch(rec)
        if ep.rmc is None:
            ep.rmc = rec

    def _course_ok(self, rec) -> bool:
        """The RMC course is the platform's heading: its speed above
        ``course_min_speed_m_s`` and the receiver displaced, over at least
        :data:`COURSE_BASELINE_S` to an earlier RMC fix, at that pace or more and along
        the course (within :data:`COURSE_MAX_DEVIATION_DEG`). A receiver standing still
        reports speed noise (0.16-0.39 m/s) with a course that turns at random: its
        displacement stays within its position noise and points anywhere."""
        lat, lon = rec.latitude_deg, rec.longitude_deg
        t = getattr(rec, "time_ns", None)
        if lat is None or lon is None or t is None:
            return False
        hist = self._course_fixes
        while hist and (t - hist[0][0] > _COURSE_KEPT_S * 1e9 or t < hist[0][0]):
            hist.popleft()
        hist.append((int(t), float(lat), float(lon)))
        if rec.course_rad is None or not (rec.speed_mps or 0.0) > self.course_min_speed_m_s:
            return False
        base = None
        for t0, lat0, lon0 in reversed(hist):
            if t - t0 >= COURSE_BASELINE_S * 1e9:
                base = (t0, lat0, lon0)
                break
        if base is None:
            return False
        t0, lat0, lon0 = base
        north = math.radians(lat - lat0) * _EARTH_RADIUS_M
        east = math.radians(lon - lon0) * _EARTH_RADIUS_M * math.cos(math.radians(lat))
        dist = math.hypot(north, east)
        if dist < self.course_min_speed_m_s * (t - t0) * 1e-9:
            return False
        dev = (math.atan2(east, north) - float(rec.course_rad) + math.pi) % (2 * math.pi) \
            - math.pi
        return abs(dev) <= math.radians(COURSE_MAX_DEVIATION_DEG)

    # -- decisions ---------------------------------------------------------------------

    def _gst_flowing(self, ep: _Epoch) -> bool:
        """The receiver still sends GST: one within :data:`GST_STOPPED_S` (or the fix
        age, if longer) of the epoch. A receiver losing every other GST (2 s apart at
        1 Hz) still sends them: its fixes wait for their own GST, each lost one counted
        once, none decided with another epoch's sigma and then retracted by its own."""
        if self._last_gst_ns is None:        # GSTs seen before any dated record only
            return bool(self._sends_gst)
        return (abs(ep.time_ns - self._last_gst_ns)
                <= max(self.max_age_ns, int(GST_STOPPED_S * 1e9)))

    def _settle(self, final: bool) -> None:
        now = self.gps_now_ns
        for tod, ep in sorted(self._epochs.items(), key=lambda kv: kv[1].time_ns):
            if ep.decided:
                if now is not None and now - ep.time_ns > 2 * self.max_age_ns:
                    del self._epochs[tod]       # too old for a late GST or GGA to matter
                continue
            aged = final or (now is not None and now - ep.time_ns > self.max_age_ns)
            later = now is not None and now > ep.time_ns
            if ep.gga is None and ep.rmc is None:
                continue
            rec = ep.gga if ep.gga is not None else ep.rmc
            if ep.gga is not None and ep.gga.fix_quality in GGA_NOT_A_FIX:
                ep.decided = True
                self._mark_decided(ep)
                self._reject("no_fix", f"GGA fix quality {ep.gga.fix_quality} at "
                             f"{_tod_text(tod)}")
                continue
            sigma = self._sigmas.get(tod)
            own = sigma is not None
            if sigma is None:
                if self._sends_gst is None:
                    # not known yet whether the receiver sends GST: its first epoch
                    # waits for a record of a later time to tell
                    if not (later or aged):
                        continue
                    self._sends_gst = False
                    sigma = float("nan")
                elif self._gst_flowing(ep):
                    gst_later = (self._last_gst_tod is not None
                                 and _tod_after(self._last_gst_tod, tod))
                    if not (gst_later or aged):
                        continue                 # pending: its GST is on its way
                    sigma = self._gst_missing(ep)
                elif self._last_gst_ns is not None:   # the receiver stopped sending GST
                    sigma = self._gst_missing(ep)
                else:
                    sigma = float("nan")
            else:
                self._gst_missing_run = False
            ep.decided, ep.own_sigma = True, own
            self._mark_decided(ep)
            if sigma > self.max_sigma_m:
                self.counts["gps_rejected_sigma"] += 1
                self._reject("sigma", f"GST sigma {sigma:.2f} m > navigation.gps_max_sigma_m "
                             f"{self.max_sigma_m:g} m at {_tod_text(tod)}"
                             + ("" if own else " (its own GST missing: the receiver's "
                                                "latest sigma)"))
                continue
            h = float("nan")
            if ep.gga is not None and rec.altitude_msl_m is not None:
                h = rec.altitude_msl_m + (rec.geoid_separation_m or 0.0)
            q = ep.gga.fix_quality if ep.gga is not None else 1
            ep.fix = GpsFix(ep.time_ns, rec.latitude_deg, rec.longitude_deg, h, q, sigma)
            self._out_fixes.append(ep.fix)
            self._accept(sigma)

    def _mark_decided(self, ep: _Epoch) -> None:
        self.decided_ns = ep.time_ns if self.decided_ns is None else max(self.decided_ns,
                                                                           ep.time_ns)

    def _gst_missing(self, ep: _Epoch) -> float:
        self.counts["gps_gst_missing"] += 1
        if not self._gst_missing_run:
            self._gst_missing_run = True
            logger.info("navigation: no GST for the GPS fix at %s; gated with the receiver's "
                        "latest sigma %s m (counted in gps_gst_missing)", _tod_text(ep.tod_ns),
                        "unknown" if self._last_sigma is None else f"{self._last_sigma:.2f}")
        return self._last_sigma if self._last_sigma is not None else float("nan")

    def _reject(self, why: str, detail: str) -> None:
        self.counts["gps_rejected"] += 1
        if self.gate == why:
            return
        old, self.gate = self.gate, why
        logger.warning("navigation: GPS fixes rejected: %s (rejected in all: %d, by sigma "
                       "%d)", detail, self.counts["gps_rejected"],
                       self.counts["gps_rejected_sigma"])
        if why == "sigma":
            self.notices.append(("navigation.gps_sigma_rejected",
                                 f"GPS fixes rejected: {detail}; "
                                 f"{self.counts['gps_rejected_sigma']} rejected by sigma so far",
                                 logging.WARNING))
        elif old == "sigma":
            self._sigma_gate_open(f"rejecting for another reason: {detail}")

    def _accept(self, sigma: float) -> None:
        if self.gate == "accepting":
            return
        old, self.gate = self.gate, "accepting"
        s = "unknown" if math.isnan(sigma) else f"{sigma:.2f} m"
        logger.info("navigation: GPS fixes accepted again (sigma %s); rejected in all: %d, "
                    "by sigma %d", s, self.counts["gps_rejected"],
                    self.counts["gps_rejected_sigma"])
        if old == "sigma":
            self._sigma_gate_open(f"sigma {s}")

    def _sigma_gate_open(self, detail: str) -> None:
        self.notices.append(("navigation.gps_sigma_accepted",
                             f"GPS fixes no longer rejected by sigma ({detail}); "
                             f"{self.counts['gps_rejected_sigma']} rejected by sigma in all",
                             logging.INFO))


def _tod_text(tod_ns: Optional[int]) -> str:
    if tod_ns is None:
        return "an unknown time"
    s = tod_ns / 1e9
    return f"{int(s // 3600):02d}:{int(s % 3600 // 60):02d}:{s % 60:05.2f} UTC"


def samples_from_nmea(records: Iterable, course_min_speed_m_s: float = 0.3,
                      max_sigma_m: float = math.inf, counts: Optional[dict] = None,
                      fix_max_age_s: float = 1.5
                      ) -> tuple[list[GpsFix], list[HeadingSample]]:
    """GPS fixes and headings from a whole list of NMEA records of
    ``svss_daq.protocols.nmea`` (records, or ``(receive_ns, record)`` pairs): a
    :class:`NmeaSampler` fed them all and flushed. Rejections are counted in
    ``counts["gps_rejected"]`` (when a dict is given; also ``gps_rejected_sigma`` and
    ``gps_gst_missing``). Records without ``time_ns`` are skipped (HDT has no time of
    its own: give pairs, see :class:`NmeaSampler`)."""
    c = {} if counts is None else counts
    s = NmeaSampler(course_min_speed_m_s, max_sigma_m, fix_max_age_s, c)
    fixes, heads, gone = s.feed(records)
    f2, h2, gone2 = s.flush()
    gone = {id(f) for f in gone + gone2}
    fixes = sorted([f for f in fixes + f2 if id(f) not in gone], key=lambda f: f.time_ns)
    heads = sorted(heads + h2, key=lambda h: h.time_ns)
    return fixes, heads
