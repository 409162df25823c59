"""The ping gate: what a ping must be before anything images, records or publishes it.

A ping that decodes can still be wrong: more channels than the array has, a projector
that does not exist, a sample rate of zero, a NaN or infinite pose, a transmit time
that goes backwards. :class:`PingGate` checks each ping against the hardware
configuration it claims and against the pings admitted before it; a refused ping is
logged with its sequence number and reason, counted by reason, and never stops a run.

These are checks against the instrument and physics, independent of any track: the
pose's plausibility along a survey line (jumps, attitude, height above the interface)
is judged where the track is known, by the imager (:mod:`svss_proc.imaging.pose_check`).
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import math

import numpy as np

from .checked import carry, once
from .config import HardwareConfig, Loaded
from .ping import NavSnapshot, Ping

log = logging.getLogger(__name__)

#: physical bounds of a navigation snapshot, field -> (lo, hi); NaN never passes,
#: except for the geodetic position, which is NaN when unknown
NAV_BOUNDS = {
    "north_m": (-2.1e7, 2.1e7), "east_m": (-2.1e7, 2.1e7), "down_m": (-1e3, 1.2e4),
    "vel_north_m_s": (-50.0, 50.0), "vel_east_m_s": (-50.0, 50.0),
    "vel_down_m_s": (-50.0, 50.0),
    "roll_rad": (-math.pi / 2, math.pi / 2), "pitch_rad": (-math.pi / 2, math.pi / 2),
    "heading_rad": (-4 * math.pi, 4 * math.pi), "altitude_m": (0.0, 1e3),
}
GEODETIC_BOUNDS = {"latitude_deg": (-90.0, 90.0), "longitude_deg": (-180.0, 360.0)}
#: largest distance between a snapshot's time and the ping's transmit time, ns
NAV_TIME_TOLERANCE_NS = 60 * 10**9
#: largest receive-window start after transmit, ns
MAX_WINDOW_START_NS = 10**9


class PingRejected(ValueError):
    """A ping refused by a gate: ``sequence`` and ``reason`` (a short phrase)."""

    def __init__(self, sequence, reason: str):
        super().__init__(f"ping {sequence}: {reason}")
        self.sequence = sequence
        self.reason = reason


def nav_problem(nav: NavSnapshot, transmit_time_ns: int) -> str | None:
    """Why a navigation snapshot is not physical (None when it is)."""
    for name, (lo, hi) in NAV_BOUNDS.items():
        v = getattr(nav, name)
        if not (isinstance(v, (int, float)) and lo <= v <= hi):
            return f"navigation {name} = {v!r} outside [{lo:g}, {hi:g}]"
    for name, (lo, hi) in GEODETIC_BOUNDS.items():
        v = getattr(nav, name)
        if not isinstance(v, (int, float)) or not (math.isnan(v) or lo <= v <= hi):
            return f"navigation {name} = {v!r} outside [{lo:g}, {hi:g}] (NaN: unknown)"
    if abs(int(nav.time_ns) - int(transmit_time_ns)) > NAV_TIME_TOLERANCE_NS:
        return (f"navigation time {nav.time_ns} ns is more than "
                f"{NAV_TIME_TOLERANCE_NS // 10**9} s from the transmit time "
                f"{transmit_time_ns} ns")
    return None


def ping_problem(ping: Ping, hardware: Loaded[HardwareConfig]) -> str | None:
    """Why ``ping`` cannot have come from the instrument ``hardware`` describes (None
    when it can): its record (:func:`record_problem`), then its navigation
    (:func:`nav_problem`)."""
    return record_problem(ping, hardware) or _pose_problem(ping)


def _pose_problem(ping: Ping) -> str | None:
    if not isinstance(ping.nav, NavSnapshot):
        return f"navigation of type {type(ping.nav).__name__}"
    return nav_problem(ping.nav, ping.transmit_time_ns)


def record_problem(ping: Ping, hardware: Loaded[HardwareConfig]) -> str | None:
    """Why ``ping``'s record (all but its pose) cannot have come from the instrument
    ``hardware`` describes (None when it can). Checks the types, the sample array's
    shape, dtype and ADC range, the projector index, the sample rate, the window start
    and the configuration id; a ping read back damaged (``Ping.damage``: its samples
    failed their checksum) is refused first."""
    damage = getattr(ping, "damage", None)
    if damage:
        return f"damaged on disk ({damage})"
    hw = hardware.value
    dig = hw.digitiser
    for name in ("sequence", "projector", "transmit_time_ns", "window_start_ns"):
        v = getattr(ping, name)
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
            return f"{name} {v!r} is not an integer"
    if ping.sequence < 0:
        return f"sequence {ping.sequence} is negative"
    if ping.config_id and ping.config_id != hardware.id:
        return (f"acquired with hardware config {ping.config_id!r}; this chain runs "
                f"{hardware.id!r} ({hardware.source})")
    s = ping.samples
    if not isinstance(s, np.ndarray) or s.ndim != 2:
        return f"samples are not a 2-D array (got {type(s).__name__})"
    if s.shape != (dig.n_channels, dig.window_samples):
        return (f"samples of shape {s.shape}; the digitiser records "
                f"({dig.n_channels} channels, {dig.window_samples} samples)")
    if s.dtype.kind not in "iu":
        return f"samples of dtype {s.dtype}; expected integer ADC codes"
    full = 1 << (dig.bits - 1)
    if s.size and (int(s.min()) < -full or int(s.max()) > full - 1):
        return (f"sample codes span [{int(s.min())}, {int(s.max())}], outside the "
                f"{dig.bits}-bit ADC range [{-full}, {full - 1}]")
    n_proj = len(hw.projectors.positions_m)
    if not 0 <= ping.projector < n_proj:
        return f"projector {ping.projector} outside 0..{n_proj - 1}"
    fs = ping.sample_rate_hz
    if not (isinstance(fs, (int, float)) and math.isfinite(fs)
            and abs(fs - dig.sample_rate_hz) <= 1e-9 * dig.sample_rate_hz):
        return f"sample rate {fs!r} Hz; the digitiser samples at {dig.sample_rate_hz:g} Hz"
    if not 0 <= ping.window_start_ns <= MAX_WINDOW_START_NS:
        return (f"window start {ping.window_start_ns} ns outside 0..{MAX_WINDOW_START_NS} "
                "ns after transmit")
    if ping.transmit_time_ns <= 0:
        return f"transmit time {ping.transmit_time_ns} ns is not after the epoch"
    return None


#: the :mod:`svss_daq.checked` key of :func:`record_problem` under a configuration
_RECORD = "record_problem"


def checked_ping_problem(ping: Ping, hardware: Loaded[HardwareConfig]) -> str | None:
    """:func:`ping_problem`, its record's part made once per ping and hardware
    configuration (:mod:`svss_daq.checked`): a ping that passed it at a gate is not
    checked (nor its samples scanned) again by the imager, nor is a re-posed copy
    (:func:`reposed`); a refused one is refused again alike. The pose's part (a few
    comparisons) is made each time."""
    return (once(ping, (_RECORD, hardware.id), lambda: record_problem(ping, hardware))
            or _pose_problem(ping))


def reposed(ping: Ping, nav: NavSnapshot) -> Ping:
    """``ping`` with the pose ``nav``: a new ping object that keeps the record checks
    ``ping`` passed (its samples are the same array), so that only its pose is checked
    again (the live micronavigation's fused poses)."""
    out = dataclasses.replace(ping, nav=nav)
    carry(ping, out, lambda key: isinstance(key, tuple) and key[:1] == (_RECORD,))
    return out


@dataclasses.dataclass
class PingGate:
    """Admits the pings of one stream: :func:`ping_problem` for each (once per ping:
    :func:`checked_ping_problem`), and transmit times strictly increasing over the
    admitted pings. Counts refusals by reason."""
    hardware: Loaded[HardwareConfig]
    name: str = "ping gate"
    refused: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    admitted: int = 0
    last_time_ns: int | None = None

    def check(self, ping: Ping) -> None:
        """Raise :class:`PingRejected` when ``ping`` may not pass; change nothing."""
        reason = checked_ping_problem(ping, self.hardware)
        if reason is None and self.last_time_ns is not None \
                and ping.transmit_time_ns <= self.last_time_ns:
            reason = (f"transmit time {ping.transmit_time_ns} ns not after the previous "
                      f"admitted ping's {self.last_time_ns} ns (duplicate or out of order)")
        if reason is not None:
            raise PingRejected(getattr(ping, "sequence", "?"), reason)

    def admit(self, ping: Ping) -> bool:
        """True when ``ping`` passes (and is then taken as the latest); otherwise log the
        refusal with its sequence and reason, count it and return False."""
        try:
            self.check(ping)
        except PingRejected as exc:
            self.refuse(exc)
            return False
        self.last_time_ns = ping.transmit_time_ns
        self.admitted += 1
        return True

    def refuse(self, exc: PingRejected) -> None:
        """Log and count a refusal (also one made by a later stage)."""
        self.refused[_reason_key(exc.reason)] += 1
        log.warning("%s: refused ping %s: %s", self.name, exc.sequence, exc.reason)

    @property
    def n_refused(self) -> int:
        return sum(self.refused.values())


def _reason_key(reason: str) -> str:
    """A short, stable category for counting: the reason up to its first number or
    quote (e.g. 'samples of shape', 'projector', 'navigation roll_rad')."""
    out = []
    for word in reason.split():
        if any(ch.isdigit() for ch in word) or word[:1] in "'\"(-[=":
            break
        out.append(word)
    return " ".join(out) or reason[:30]
