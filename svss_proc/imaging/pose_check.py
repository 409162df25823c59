"""Is a ping's pose plausible on the survey line? Judged before a ping may open or close
tiles, so that a navigation glitch cannot hijack the tile bookkeeping.

Each ping's array is placed in the tile frame (:func:`svss_daq.geometry.place_array`);
the checks are, in order: attitude (roll, pitch), the projector's height above the
interface, its cross-track distance from the track line, and a jump from the last
accepted ping further than the platform can have moved (``max_speed_m_s`` times the
time between them, plus ``jump_slack_m``). A jump is refused; but when
``reanchor_pings`` consecutive refused pings agree with one another, the platform has
truly moved (a gap in the recording, a reacquired fix) and the track follows them.
Limits come from ``[ping_gate]`` of the processing configuration.

Before any of that, the navigation's own verdict on the pose (its quality flags,
:data:`svss_daq.ping.NAV_NO_HEADING` ...): :func:`pose_flags_problem` refuses a pose
without heading or without position, and a held, dead-reckoned, re-timed or
fallback-heading pose where ``[ping_gate]`` says such a pose may not image.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

from svss_daq.checked import once
from svss_daq.config import PingGateConfig
from svss_daq.ping import (NAV_CLOCK_RETIMED, NAV_DEAD_RECKONED, NAV_GPS_FIX,
                           NAV_HEADING_FROM_COMPASS, NAV_HEADING_FROM_COURSE, NAV_HELD,
                           NAV_NO_HEADING, NavSnapshot)
from svss_daq.ping_gate import PingRejected

log = logging.getLogger(__name__)

#: flag -> (the [ping_gate] key of its policy, the reason a refused pose is given; its
#: words before the parenthesis are the count's key)
FLAG_POLICIES = (
    (NAV_HELD, "held", "held pose (extrapolated past the last navigation record)"),
    (NAV_DEAD_RECKONED, "dead_reckoned",
     "dead-reckoned pose (no GPS fix at the ping, position from the DVL)"),
    (NAV_CLOCK_RETIMED, "clock_retimed",
     "re-timed pose (instrument clocks disagreed; records placed by receive time)"),
    (NAV_HEADING_FROM_COURSE, "heading_from_course",
     "heading from course (GPS course over ground, no heading sensor in time)"),
    (NAV_HEADING_FROM_COMPASS, "heading_from_compass",
     "heading from compass (the DVL's magnetic compass)"),
)


def pose_flags_problem(nav: NavSnapshot, cfg: PingGateConfig) -> str | None:
    """Why the navigation's flags (``nav.quality``) keep a pose from imaging, None when
    they do not: no heading (NAV_NO_HEADING: lever arms and the array's orientation
    unknown), no position (north or east NaN: no GPS fix and no dead reckoning), or a
    flag whose ``[ping_gate]`` policy is "refuse" (:data:`FLAG_POLICIES`). A snapshot
    that is not one, or a quality that is not an integer, is left to the ping gate."""
    if not isinstance(nav, NavSnapshot):
        return None
    q = nav.quality
    if isinstance(q, bool) or not isinstance(q, int):
        return None
    if q & NAV_NO_HEADING:
        return (f"pose without heading (NAV_NO_HEADING: no heading sensor, compass or "
                f"course in time; quality {q})")
    unknown = [name for name in ("north_m", "east_m")
               if isinstance(getattr(nav, name), float) and math.isnan(getattr(nav, name))]
    if unknown:
        why = ("no GPS fix and no dead reckoning" if not q & (NAV_GPS_FIX | NAV_DEAD_RECKONED)
               else "flagged positioned but NaN")
        return f"pose without position ({' and '.join(unknown)} NaN: {why}; quality {q})"
    for flag, key, reason in FLAG_POLICIES:
        if q & flag and getattr(cfg, key) == "refuse":
            return f"{reason}; ping_gate.{key} = \"refuse\""
    return None


def check_pose_flags(ping, cfg: PingGateConfig) -> None:
    """Raise :class:`~svss_daq.ping_gate.PingRejected` when :func:`pose_flags_problem`
    refuses the ping's pose; once per ping and ``cfg`` (:mod:`svss_daq.checked`: the
    worker's check before its gate is not made again by the imager)."""
    reason = once(ping, ("pose_flags", cfg),
                  lambda: pose_flags_problem(getattr(ping, "nav", None), cfg))
    if reason is not None:
        raise PingRejected(getattr(ping, "sequence", "?"), reason)


def attitude_height_offset_problem(nav: NavSnapshot, tx_tile, cfg: PingGateConfig
                                   ) -> str | None:
    """Why a pose is implausible on its own (None when it is plausible): roll or pitch
    beyond the limits, projector height above the interface (``-tx_tile[2]``, m) outside
    ``cfg.height_m``, cross-track offset ``|tx_tile[1]|`` beyond ``max_line_offset_m``."""
    for name, value, limit in (("roll", nav.roll_rad, cfg.max_roll_deg),
                               ("pitch", nav.pitch_rad, cfg.max_pitch_deg)):
        if abs(math.degrees(value)) > limit:
            return f"{name} {math.degrees(value):.1f} deg beyond +-{limit:g} deg"
    h = -float(tx_tile[2])
    lo, hi = cfg.height_m
    if not lo <= h <= hi:
        return (f"projector height {h:.2f} m above the interface outside "
                f"[{lo:g}, {hi:g}] m")
    if abs(float(tx_tile[1])) > cfg.max_line_offset_m:
        return (f"cross-track offset {float(tx_tile[1]):.1f} m from the track line beyond "
                f"{cfg.max_line_offset_m:g} m")
    return None


@dataclass
class _Fix:
    time_ns: int
    along: float
    cross: float


@dataclass
class TrackGuard:
    """Refuses implausible poses and jumps off the track; re-anchors after a true move."""
    cfg: PingGateConfig
    anchor: _Fix | None = None
    candidates: list = field(default_factory=list)
    reanchored: int = 0

    def _reachable(self, a: _Fix, b: _Fix) -> tuple[bool, float, float]:
        dt = abs(b.time_ns - a.time_ns) * 1e-9
        dist = math.hypot(b.along - a.along, b.cross - a.cross)
        allowed = self.cfg.max_speed_m_s * dt + self.cfg.jump_slack_m
        return dist <= allowed, dist, allowed

    def check(self, sequence: int, nav: NavSnapshot, tx_tile) -> _Fix:
        """Raise :class:`~svss_daq.ping_gate.PingRejected` for an implausible pose (a
        refused jump is remembered as a candidate for re-anchoring); otherwise return
        the ping's fix, to be taken as the track's latest point by :meth:`commit` once
        the ping is imaged."""
        reason = attitude_height_offset_problem(nav, tx_tile, self.cfg)
        if reason is not None:
            raise PingRejected(sequence, reason)
        fix = _Fix(int(nav.time_ns), float(tx_tile[0]), float(tx_tile[1]))
        if self.anchor is not None:
            ok, dist, allowed = self._reachable(self.anchor, fix)
            if not ok:
                if self.candidates and not self._reachable(self.candidates[-1], fix)[0]:
                    self.candidates.clear()
                self.candidates.append(fix)
                if len(self.candidates) < self.cfg.reanchor_pings:
                    raise PingRejected(sequence, f"position jump of {dist:.1f} m from the "
                                       f"last accepted ping (at most {allowed:.1f} m)")
                self.reanchored += 1
                log.warning("ping %d: %d consecutive pings agree on a position %.1f m from "
                            "the previous track; the track follows them", sequence,
                            len(self.candidates), dist)
        return fix

    def commit(self, fix: _Fix) -> None:
        """Take an accepted ping's fix as the track's latest point."""
        self.candidates.clear()
        self.anchor = fix
