"""GPS fixes and headings from decoded NMEA 0183 records."""

from __future__ import annotations

import math
from typing import Iterable, Optional

from .records import GpsFix, HeadingSample

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


def samples_from_nmea(records: Iterable, course_min_speed_m_s: float = 0.3,
                      max_sigma_m: float = math.inf, counts: Optional[dict] = None
                      ) -> tuple[list[GpsFix], list[HeadingSample]]:
    """GPS fixes (GGA with a real fix and a date; else RMC with status A) and headings
    (HDT; RMC course above ``course_min_speed_m_s`` as a fallback) from NMEA records of
    ``svss_daq.drivers.nmea``. A GST with the fix's time of day gives the fix its sigma
    (:func:`gst_sigma_m`); a fix with sigma above ``max_sigma_m`` is rejected, as are
    GGA quality 0 or 6 and RMC status V or mode E/N: each counted in
    ``counts["gps_rejected"]`` (when a dict is given). Records without ``time_ns`` are
    skipped (HDT has no time of its own: give ``(host_time_ns, record)`` pairs)."""
    from svss_daq.drivers import nmea
    fixes, heads = [], []
    gga_times = set()
    pending_rmc = []
    sigma_by_tod: dict = {}
    recs = list(records)
    for rec in recs:
        r = rec[1] if isinstance(rec, tuple) else rec
        if isinstance(r, nmea.GstStatistics) and r.time_of_day_ns is not None:
            sigma_by_tod[r.time_of_day_ns] = gst_sigma_m(r)
    rejected = 0
    for rec in recs:
        t_host = None
        if isinstance(rec, tuple):
            t_host, rec = rec
        if isinstance(rec, nmea.HdtHeading):
            if rec.heading_rad is not None and t_host is not None:
                heads.append(HeadingSample(int(t_host), float(rec.heading_rad)))
            continue
        t = getattr(rec, "time_ns", None)
        if t is None:
            continue
        if isinstance(rec, nmea.GgaFix):
            if rec.latitude_deg is None or rec.longitude_deg is None:
                if rec.fix_quality not in GGA_NOT_A_FIX:
                    continue
            sigma = sigma_by_tod.get(rec.time_of_day_ns, float("nan"))
            gga_times.add(t)  # an RMC of the same time does not stand in for a rejected GGA
            if rec.fix_quality in GGA_NOT_A_FIX or sigma > max_sigma_m:
                rejected += 1
                continue
            h = float("nan")
            if rec.altitude_msl_m is not None:
                h = rec.altitude_msl_m + (rec.geoid_separation_m or 0.0)
            fixes.append(GpsFix(t, rec.latitude_deg, rec.longitude_deg, h, rec.fix_quality,
                                sigma))
        elif isinstance(rec, nmea.RmcFix):
            if rec.valid and (rec.mode or "A").upper() not in RMC_MODE_NOT_A_FIX:
                pending_rmc.append(rec)
            else:
                rejected += 1
    for rec in pending_rmc:
        if rec.time_ns not in gga_times and rec.latitude_deg is not None and rec.longitude_deg is not None:
            sigma = sigma_by_tod.get(rec.time_of_day_ns, float("nan"))
            if sigma > max_sigma_m:
                rejected += 1
            else:
                fixes.append(GpsFix(rec.time_ns, rec.latitude_deg, rec.longitude_deg,
                                    float("nan"), 1, sigma))
        if rec.course_rad is not None and (rec.speed_mps or 0.0) > course_min_speed_m_s:
            heads.append(HeadingSample(rec.time_ns, float(rec.course_rad), from_course=True))
    fixes.sort(key=lambda f: f.time_ns)
    heads.sort(key=lambda h: h.time_ns)
    if counts is not None:
        counts["gps_rejected"] = counts.get("gps_rejected", 0) + rejected
    return fixes, heads


