"""The collecting navigator: instrument records in, poses and a quality summary out."""

from __future__ import annotations

import logging
import math
from typing import Iterable, Optional

import numpy as np

from .fusion import compute_poses
from .nmea_samples import samples_from_nmea
from .pd0_samples import dvl_sample_from_pd0
from svss_daq.ping import NavSnapshot

from .records import DvlSample, GpsFix, HeadingSample

logger = logging.getLogger(__name__)

class Navigator:
    """Collects GPS, heading and DVL samples and poses pings from them.

    ``add_nmea`` takes records (or ``(host_time_ns, record)`` pairs) from
    ``svss_daq.drivers.nmea``; ``add_pd0`` PD0 ensembles. ``poses(times_ns)`` calls
    :func:`compute_poses` on everything collected (kept for ``history_s``);
    ``quality(now_ns)`` summarises the state for a status stream.
    """

    def __init__(self, cfg, lever_arms, history_s: float = 600.0) -> None:
        self.cfg, self.lever_arms, self.history_ns = cfg, lever_arms, int(history_s * 1e9)
        self.fixes: list[GpsFix] = []
        self.headings: list[HeadingSample] = []
        self.dvl: list[DvlSample] = []
        self.origin: Optional[tuple[float, float, float]] = None
        self.counts = {"gps_fixes": 0, "gps_rejected": 0, "dvl_samples": 0, "dvl_no_lock": 0}
        self._last_fix: Optional[GpsFix] = None
        self._last_dvl: Optional[DvlSample] = None
        self._last_lock_ns: Optional[int] = None
        self._last_hdt_ns: Optional[int] = None
        self._last_course_ns: Optional[int] = None
        self._last_compass_ns: Optional[int] = None

    def add_fix(self, f: GpsFix) -> None:
        if self.origin is None and self.cfg.origin_latitude_deg is None:
            self.origin = (f.latitude_deg, f.longitude_deg, 0.0 if math.isnan(f.height_m) else f.height_m)
            logger.info("navigation: survey origin set to the first fix %.8f, %.8f",
                        f.latitude_deg, f.longitude_deg)
        self.fixes.append(f)
        self.counts["gps_fixes"] += 1
        if self._last_fix is None or f.time_ns >= self._last_fix.time_ns:
            self._last_fix = f

    def add_nmea(self, records: Iterable) -> None:
        fixes, heads = samples_from_nmea(records, self.cfg.course_min_speed_m_s,
                                         self.cfg.gps_max_sigma_m, self.counts)
        for f in fixes:
            self.add_fix(f)
        for h in heads:
            if h.from_course:
                self._last_course_ns = max(self._last_course_ns or h.time_ns, h.time_ns)
            else:
                self._last_hdt_ns = max(self._last_hdt_ns or h.time_ns, h.time_ns)
        self.headings += heads

    def add_pd0(self, ensemble) -> None:
        d = dvl_sample_from_pd0(ensemble, self.cfg.dvl_min_beams,
                                math.radians(self.cfg.dvl_beam_angle_deg),
                                math.radians(self.cfg.magnetic_declination_deg))
        if d is not None:
            self.add_dvl(d)

    def add_dvl(self, d: DvlSample) -> None:
        self.dvl.append(d)
        self.counts["dvl_samples"] += 1
        if self._last_dvl is None or d.time_ns >= self._last_dvl.time_ns:
            self._last_dvl = d
        if d.bottom_lock:
            self._last_lock_ns = max(self._last_lock_ns or d.time_ns, d.time_ns)
        else:
            self.counts["dvl_no_lock"] += 1
        if math.isfinite(d.heading_rad):
            self._last_compass_ns = max(self._last_compass_ns or d.time_ns, d.time_ns)

    def prune(self, before_ns: int) -> None:
        self.fixes = [f for f in self.fixes if f.time_ns >= before_ns]
        self.headings = [h for h in self.headings if h.time_ns >= before_ns]
        self.dvl = [d for d in self.dvl if d.time_ns >= before_ns]

    def poses(self, times_ns) -> list[NavSnapshot]:
        times = np.asarray(times_ns, dtype=np.int64).reshape(-1)
        if times.size:
            self.prune(int(times.min()) - self.history_ns)
        return compute_poses(times, self.fixes, self.headings, self.dvl, self.cfg,
                             self.lever_arms, self.origin)

    def quality(self, now_ns: int) -> dict:
        """JSON-serialisable state at ``now_ns`` (O(1)): ``mode`` ("gps" within
        ``gps_fix_max_age_s`` of the last fix, "dead_reckoning" with bottom lock within
        ``dvl_max_gap_s`` and a survey origin, else "none"), ``gps_fix_age_s``,
        ``dvl_age_s`` (s, null: never), ``heading_source`` ("hdt", "dvl_compass",
        "course" or "none": the first within ``heading_max_age_s``), ``bottom_lock``,
        ``gps_sigma_m`` (GST sigma of the last fix, null: not sent) and the counters
        ``gps_fixes``, ``gps_rejected``, ``dvl_samples``, ``dvl_no_lock``."""
        cfg = self.cfg

        def age(t):
            return None if t is None else (int(now_ns) - int(t)) * 1e-9

        fix_age = age(None if self._last_fix is None else self._last_fix.time_ns)
        dvl_age = age(None if self._last_dvl is None else self._last_dvl.time_ns)
        lock_age = age(self._last_lock_ns)
        bottom_lock = (self._last_dvl is not None and self._last_dvl.bottom_lock
                       and dvl_age is not None and abs(dvl_age) <= cfg.dvl_max_gap_s)
        has_origin = self.origin is not None or cfg.origin_latitude_deg is not None
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
        return {"mode": mode, "gps_fix_age_s": fix_age, "dvl_age_s": dvl_age,
                "heading_source": heading, "bottom_lock": bool(bottom_lock),
                "gps_sigma_m": sigma, **{k: int(v) for k, v in self.counts.items()}}

