"""Simulated dual-antenna GNSS receiver: NMEA 0183 GGA, RMC, VTG, HDT (``rate_hz``) and
ZDA (``zda_rate_hz``) on a pseudo-terminal (:class:`~sim_device.devices.serial_device.SerialDevice`).

Each epoch samples the true pose at the fix time, places the antenna with the lever arm
``gps_antenna_m`` rotated by the attitude, converts it from the survey NED frame to
WGS-84 about the configured origin (:func:`svss_daq.navigation.ned_to_geodetic`), adds
white noise (position, height, velocity, heading) and sends the epoch's sentences
``latency_s`` after the fix time, which is what their time fields carry. The heading is
that of the body x axis (antenna baseline along x).

Outage (:meth:`GpsEmulator.outage`): as a real receiver that loses the sky, it keeps
talking: GGA with fix quality 0 and empty position, RMC status V (mode N), VTG and HDT
with empty fields (a GNSS compass has no heading without satellites); ZDA goes on from
the receiver's clock. Navigation therefore sees no fix and no heading.
"""

from __future__ import annotations

import logging
import math
import threading
from typing import Callable

import numpy as np

from svss_daq.protocols import nmea_encoder as enc
from svss_daq.frames import body_to_ned
from svss_daq.navigation import ned_to_geodetic
from svss_daq.ping import NavSnapshot
from sim_device.devices.clock import SimClock
from sim_device.devices.instruments_config import GpsSimConfig
from sim_device.devices.serial_device import ScheduledSerialDevice

__all__ = ["GpsEmulator", "antenna_ned"]

logger = logging.getLogger(__name__)

_MODE = {1: "A", 2: "D", 4: "R", 5: "F"}
_DIFF_S = 0.05  # half-window of the central difference for the antenna velocity, s


def antenna_ned(pose: NavSnapshot, lever_m) -> np.ndarray:
    """NED position (m) of a point at body-frame ``lever_m`` for ``pose``."""
    rot = body_to_ned(pose.roll_rad, pose.pitch_rad, pose.heading_rad)
    return np.array([pose.north_m, pose.east_m, pose.down_m]) + rot @ np.asarray(lever_m, float)


class GpsEmulator(ScheduledSerialDevice):
    """The receiver at ``<directory>/<name>``. ``pose_fn(true_ns) -> NavSnapshot``: the
    true pose; ``lever_arms``: :class:`svss_daq.config.LeverArms`."""

    def __init__(self, cfg: GpsSimConfig, lever_arms, clock: SimClock,
                 pose_fn: Callable[[int], NavSnapshot], directory, name: str = "gps") -> None:
        super().__init__(directory, name, clock, {"fix": (1.0 / cfg.rate_hz, cfg.latency_s),
                                                  "zda": (1.0 / cfg.zda_rate_hz, cfg.latency_s)})
        self.cfg = cfg
        self.lever_m = np.asarray(lever_arms.gps_antenna_m, dtype=np.float64)
        self.pose_fn = pose_fn
        self.origin = (cfg.origin_latitude_deg, cfg.origin_longitude_deg, cfg.origin_height_m)
        self._rng = np.random.default_rng(cfg.seed)
        self._outage_from_ns = -1
        self._outage_until_ns = -1
        self._olock = threading.Lock()
        self.epochs_without_fix = 0

    def outage(self, seconds: float) -> None:
        """No fix and no heading for the next ``seconds`` of simulated time (returns at
        once)."""
        if not seconds >= 0:
            raise ValueError(f"{self.name}: outage seconds: expected >= 0, found {seconds!r}")
        with self._olock:
            # from now: an epoch of an earlier time, sent late by a loaded host, had its
            # fix
            self._outage_from_ns = self.clock.true_ns()
            self._outage_until_ns = self._outage_from_ns + int(seconds * 1e9)
        self._fault("outage", f"no fix for {seconds:.3f} s (fix quality 0, RMC V, empty HDT)")

    def _in_outage(self, t_ns: int) -> bool:
        with self._olock:
            return self._outage_from_ns <= t_ns < self._outage_until_ns

    def _emit(self, stream: str, t_true_ns: int, t_clock_ns: int) -> bytes:
        c = self.cfg
        if stream == "zda":
            return enc.zda(c.talker, t_clock_ns)
        if self._in_outage(t_true_ns):
            self.epochs_without_fix += 1
            return (enc.gga(c.talker, t_clock_ns, None, None, 0)
                    + enc.rmc(c.talker, t_clock_ns, False, None, None, None, None)
                    + enc.vtg(c.talker, None, None, "N") + enc.hdt(c.heading_talker, None))
        pose = self.pose_fn(t_true_ns)
        ant = antenna_ned(pose, self.lever_m)
        dt = int(_DIFF_S * 1e9)
        vel = (antenna_ned(self.pose_fn(t_true_ns + dt), self.lever_m)
               - antenna_ned(self.pose_fn(t_true_ns - dt), self.lever_m)) / (2 * _DIFF_S)
        rng = self._rng
        noisy = ant + rng.normal(0.0, 1.0, 3) * (c.position_sigma_m, c.position_sigma_m,
                                                 c.height_sigma_m)
        lat, lon, h = ned_to_geodetic(noisy, self.origin)
        vn, ve = vel[:2] + rng.normal(0.0, c.velocity_sigma_m_s, 2)
        speed, course = math.hypot(vn, ve), math.atan2(ve, vn)
        heading = pose.heading_rad + math.radians(c.heading_sigma_deg) * rng.normal()
        mode = _MODE[c.fix_quality]
        return (enc.gga(c.talker, t_clock_ns, float(lat), float(lon), c.fix_quality,
                        c.satellites, c.hdop, float(h) - c.geoid_separation_m,
                        c.geoid_separation_m)
                + enc.rmc(c.talker, t_clock_ns, True, float(lat), float(lon), speed, course, mode)
                + enc.vtg(c.talker, course, speed, mode)
                + enc.hdt(c.heading_talker, heading))
