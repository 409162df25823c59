"""Simulated Teledyne RDI DVL (Workhorse Navigator, bottom track): PD0 ensembles on a
pseudo-terminal (:class:`~sim_device.devices.serial_device.SerialDevice`).

Each ensemble samples the true pose at its ping time (the time in its variable leader)
and is sent ``latency_s`` later. Contents:

* heading, pitch, roll: the true attitude plus compass / tilt-sensor white noise;
* bottom-track velocity: the head's velocity over ground (lever arm ``dvl_m``: central
  difference of the head's true position, so rotation is included), in the body frame
  plus white noise, sent as RDI does: the bottom's velocity relative to the instrument
  (negated), in ship (X stbd, Y fwd, Z up) or earth coordinates (rotated with the
  *reported* attitude, as the instrument does); the error velocity is noise;
* ranges: what RDI sends, the *vertical* range per beam: the range along each Janus
  beam (RDI's convex layout, :func:`~svss_daq.navigation.janus_beam_vectors`: 1 port,
  2 starboard, 3 forward, 4 aft, ``beam_angle_deg`` from the head's axis, turned by the
  true attitude) to a flat bottom at the track's depth (``body_down_m + altitude_m``),
  or to the scene's sloping bed (``bed``: down = k0 + kn north + ke east), plus noise, times cos(``beam_angle_deg``), not corrected for pitch and roll (the
  manual's bottom-track range); a beam whose range along it is beyond ``max_range_m``
  finds no bottom (0). With fewer than three beams on the bottom the velocity is bad
  (-32768). The fixed leader carries ``beam_angle_deg``.

Lost bottom lock (:meth:`DvlEmulator.lose_bottom_lock`, or the configured dropout
``dropout_start_s`` .. + ``dropout_s`` after the track's start): what the instrument then
sends, bad velocities (-32768: RDI's "no bottom lock" value) and ranges 0 in every beam,
ensembles still flowing.

Error cases of the instrument (configured, default none): a velocity scale error (an
error in the sound speed at the transducer or in the beam angle) multiplies the
measured velocity by 1 + ``velocity_scale_error``; a mounting misalignment of
``misalignment_deg`` about the vertical (the head turned to starboard, not in the heading
alignment EA the fixed leader states) makes the head measure the body's velocity turned
the other way: v_head = (1 + s) R_z(alpha)^T v_body, then the noise. For a forward
velocity v a head turned alpha to starboard reports v cos(alpha) forward and
-v sin(alpha) to starboard (toward port). The attitude it reports is unaffected.
"""

from __future__ import annotations

import logging
import math
import threading
from typing import Callable

import numpy as np

from svss_daq.protocols.pd0_encoder import Pd0Setup, encode_ensemble
from svss_daq.frames import body_to_ned
from svss_daq.navigation import janus_beam_vectors
from svss_daq.ping import NavSnapshot
from sim_device.devices.clock import SimClock
from sim_device.devices.gps import antenna_ned
from sim_device.devices.instruments_config import DvlSimConfig
from sim_device.devices.serial_device import ScheduledSerialDevice

__all__ = ["DvlEmulator"]

logger = logging.getLogger(__name__)

_DIFF_S = 0.05  # half-window of the central difference for the head velocity, s


class DvlEmulator(ScheduledSerialDevice):
    """The DVL at ``<directory>/<name>``. ``pose_fn(true_ns) -> NavSnapshot``: the true
    pose (its ``down_m + altitude_m`` is the bottom's depth, unless ``bed`` gives the
    bottom as a plane, down = k0 + kn north + ke east: :func:`sim_device.bed_plane.ned_plane`,
    or ``bed_ranges(head_ned, beam_directions_ned)`` gives each beam's slant range to any
    bed: :func:`sim_device.bed_surface.ned_beam_ranges`);
    ``lever_arms``: :class:`svss_daq.config.LeverArms`."""

    def __init__(self, cfg: DvlSimConfig, lever_arms, clock: SimClock,
                 pose_fn: Callable[[int], NavSnapshot], directory, name: str = "dvl",
                 bed: tuple[float, float, float] | None = None,
                 bed_ranges: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
                 ) -> None:
        super().__init__(directory, name, clock, {"ensemble": (1.0 / cfg.rate_hz, cfg.latency_s)})
        self.cfg = cfg
        self.setup = Pd0Setup(frequency_hz=cfg.frequency_khz * 1e3,
                              beam_angle_deg=cfg.beam_angle_deg,
                              coordinate_system=cfg.coordinate_system,
                              serial_number=cfg.serial_number)
        self.setup.check()
        self.lever_m = np.asarray(lever_arms.dvl_m, dtype=np.float64)
        self.pose_fn = pose_fn
        self.bed = bed
        self.bed_ranges = bed_ranges
        self.beams = janus_beam_vectors(math.radians(cfg.beam_angle_deg))
        self._rng = np.random.default_rng(cfg.seed)
        self._lost_from_ns = -1
        self._lost_until_ns = -1
        self._llock = threading.Lock()
        self.ensemble_number = 0  #: number of the last ensemble built (first is 1)
        a = math.radians(cfg.misalignment_deg)
        #: body velocity -> what the head measures (scale and misalignment), body axes
        self.error_matrix = (1.0 + cfg.velocity_scale_error) * np.array(
            [[math.cos(a), math.sin(a), 0.0], [-math.sin(a), math.cos(a), 0.0],
             [0.0, 0.0, 1.0]])
        self._dropout_ns = (clock.start_ns + int(round(cfg.dropout_start_s * 1e9)),
                            clock.start_ns + int(round((cfg.dropout_start_s + cfg.dropout_s)
                                                       * 1e9)))
        self.ensembles_without_lock = 0

    def lose_bottom_lock(self, seconds: float) -> None:
        """No bottom track (bad velocities, no ranges) for the next ``seconds`` of
        simulated time (returns at once)."""
        if not seconds >= 0:
            raise ValueError(f"{self.name}: lose_bottom_lock seconds: expected >= 0, found "
                             f"{seconds!r}")
        with self._llock:
            # from now: an ensemble of an earlier time, sent late by a loaded host, had
            # its lock (it counted as lost when the window had no start)
            self._lost_from_ns = self.clock.true_ns()
            self._lost_until_ns = self._lost_from_ns + int(seconds * 1e9)
        self._fault("bottom lock lost", f"for {seconds:.3f} s (velocity -32768, range 0)")

    def _emit(self, stream: str, t_true_ns: int, t_clock_ns: int) -> bytes:
        c, rng = self.cfg, self._rng
        self.ensemble_number += 1
        pose = self.pose_fn(t_true_ns)
        heading = pose.heading_rad + math.radians(c.heading_sigma_deg) * rng.normal()
        pitch = pose.pitch_rad + math.radians(c.tilt_sigma_deg) * rng.normal()
        roll = pose.roll_rad + math.radians(c.tilt_sigma_deg) * rng.normal()
        with self._llock:
            lost = (self._lost_from_ns <= t_true_ns < self._lost_until_ns
                    or self._dropout_ns[0] <= t_true_ns < self._dropout_ns[1])
        if lost:
            self.ensembles_without_lock += 1
            vel = [math.nan] * 4
            ranges = [math.nan] * 4
        else:
            rot = body_to_ned(pose.roll_rad, pose.pitch_rad, pose.heading_rad)
            head = antenna_ned(pose, self.lever_m)
            dt = int(_DIFF_S * 1e9)
            v_ned = (antenna_ned(self.pose_fn(t_true_ns + dt), self.lever_m)
                     - antenna_ned(self.pose_fn(t_true_ns - dt), self.lever_m)) / (2 * _DIFF_S)
            v_body = (self.error_matrix @ (rot.T @ v_ned)
                      + rng.normal(0.0, c.velocity_sigma_m_s, 3))
            k0, kn, ke = ((pose.down_m + pose.altitude_m, 0.0, 0.0) if self.bed is None
                          else self.bed)
            # the head's height above the bottom below it, and each beam's closing rate
            # on the bottom per metre along it (its vertical part on a flat bottom)
            height = k0 + kn * head[0] + ke * head[1] - head[2]
            d = self.beams @ rot.T
            vert = d[:, 2] - kn * d[:, 0] - ke * d[:, 1]
            slant = (self.bed_ranges(head, d) if self.bed_ranges is not None else
                     [height / v if v > 0 else math.nan for v in vert])
            ranges = [r + c.range_sigma_m * rng.normal() if math.isfinite(r) else math.nan
                      for r in slant]
            cos_beam = math.cos(math.radians(c.beam_angle_deg))
            ranges = [r * cos_beam if 0 < r <= c.max_range_m else math.nan for r in ranges]
            err = float(rng.normal(0.0, c.velocity_sigma_m_s))
            if sum(math.isfinite(r) for r in ranges) < 3:
                vel = [math.nan] * 4
            elif c.coordinate_system == "ship":
                vel = [-v_body[1], -v_body[0], v_body[2], err]
            else:  # earth: rotated with the attitude the instrument measured
                ned = body_to_ned(roll, pitch, heading) @ v_body
                vel = [-ned[1], -ned[0], ned[2], err]
        return encode_ensemble(self.setup, ensemble_number=self.ensemble_number,
                               time_ns=t_clock_ns, heading_rad=heading, pitch_rad=pitch,
                               roll_rad=roll, bt_velocity_m_s=vel, bt_range_m=ranges,
                               sound_speed_m_s=c.sound_speed_m_s, depth_m=c.transducer_depth_m,
                               salinity_ppt=c.salinity_ppt, temperature_c=c.temperature_c)
