"""DVL samples from decoded PD0 ensembles."""

from __future__ import annotations

import logging
import math
from typing import Optional

import numpy as np

from svss_daq.frames import body_to_ned

from .dvl_geometry import beam_to_instrument, instrument_to_ship, three_beam_fill
from .headings import wrap_angle
from .records import DvlSample

logger = logging.getLogger(__name__)

#: Disagreements already logged (one warning each, not one per ensemble).
_warned: set = set()

#: Angles closer than this are the same setting (RDI sends 0.01 deg steps at best), rad.
_SAME_ANGLE_RAD = math.radians(0.005)


def _warn_once(key: tuple, msg: str, *args) -> None:
    if key not in _warned:
        _warned.add(key)
        logger.warning(msg, *args)


def _beam_angle(fx, configured: Optional[float], number: int) -> Optional[float]:
    """The fixed leader's beam angle; ``configured`` only where it sends none; a
    warning (once per pair of values) where both are known and differ."""
    if fx.beam_angle_rad is None:
        return configured
    if configured is not None and abs(fx.beam_angle_rad - configured) > _SAME_ANGLE_RAD:
        _warn_once(("beam angle", fx.serial_number, round(math.degrees(fx.beam_angle_rad), 3),
                    round(math.degrees(configured), 3)),
                   "PD0 ensemble %d (serial %s): the fixed leader's beam angle %.2f deg "
                   "differs from navigation.dvl_beam_angle_deg %.2f deg: using the "
                   "instrument's", number, fx.serial_number, math.degrees(fx.beam_angle_rad),
                   math.degrees(configured))
    return fx.beam_angle_rad


def _declination(fx, configured_rad: float, number: int) -> float:
    """What to add to the instrument's heading for true north: the configured
    declination where the instrument applies none (EB 0), else nothing (its heading
    already holds EB), with a warning (once per pair) where both are set and differ."""
    if fx.heading_bias_rad == 0.0:
        return configured_rad
    if configured_rad != 0.0 and abs(fx.heading_bias_rad - configured_rad) > _SAME_ANGLE_RAD:
        _warn_once(("declination", fx.serial_number, round(math.degrees(fx.heading_bias_rad), 3),
                    round(math.degrees(configured_rad), 3)),
                   "PD0 ensemble %d (serial %s): the instrument applies a heading bias (EB) "
                   "of %.2f deg and navigation.magnetic_declination_deg is %.2f deg: using "
                   "the instrument's (its heading already includes EB)", number,
                   fx.serial_number, math.degrees(fx.heading_bias_rad),
                   math.degrees(configured_rad))
    return 0.0


def dvl_sample_from_pd0(ens, min_beams: int = 3, beam_angle_rad: Optional[float] = None,
                        declination_rad: float = 0.0) -> Optional[DvlSample]:
    """A :class:`DvlSample` from a decoded PD0 ensemble (``svss_daq.protocols.pd0``).

    Bottom-track velocity is RDI's velocity of the bottom relative to the instrument,
    so the head's velocity is its negative. Coordinate systems: ``beam`` (to instrument
    with the beam angle and beam pattern; one bad beam is filled by
    :func:`three_beam_fill` when ``min_beams`` <= 3, else the velocity is bad),
    ``instrument`` (to ship with the heading alignment and orientation), ``ship`` (X
    starboard, Y forward, Z up, mapped to body x = Y, y = X, z = -Z) and ``earth``
    (east, north, up: rotated back into the body frame with the ensemble's heading,
    pitch and roll).

    Beam angle: the fixed leader's; ``beam_angle_rad`` (``navigation.dvl_beam_angle_deg``)
    only where it sends none, and a warning, once, where the two differ. RDI's
    bottom-track ranges are vertical (range along the beam x cos(beam angle), not
    corrected for pitch and roll): the sample holds them along the beams (divided by the
    cosine) with the angle, so that :func:`~svss_daq.nav.dvl_geometry.head_height_m`
    turns them by the true attitude. Heading: the instrument's less its heading
    alignment EA, plus ``declination_rad`` (``navigation.magnetic_declination_deg``)
    where the instrument applies no heading bias EB (a warning, once, where both are set
    and differ).

    An ensemble without bottom track gives a sample with NaN velocity and ranges and its
    attitude and heading. Returns None only without a valid time.
    """
    t = ens.variable.time_ns
    if t is None:
        return None
    bt = ens.bottom_track
    fx = ens.fixed
    number = ens.variable.ensemble_number
    roll, pitch = float(ens.variable.roll_rad), float(ens.variable.pitch_rad)
    angle = _beam_angle(fx, beam_angle_rad, number)
    cs = fx.coordinate_system
    body = np.full(3, np.nan)
    rng = np.full(4, np.nan)
    if bt is not None:
        if cs in ("beam", "instrument"):
            if cs == "beam":
                if angle is None:
                    raise ValueError(f"PD0 ensemble {number}: beam coordinates without a "
                                     "beam angle (fixed leader system configuration bits "
                                     "8-9 'other', no beam angle byte)")
                b = np.asarray(bt.velocity_mps[:4], dtype=np.float64)
                if min_beams <= 3:
                    b = three_beam_fill(b)
                xyz = beam_to_instrument(b, angle, fx.beam_pattern == "convex")[:3]
            else:
                xyz = np.asarray(bt.velocity_mps[:3], dtype=np.float64)
            v = -instrument_to_ship(xyz, fx.heading_alignment_rad, fx.orientation == "up")
            body = np.array([v[1], v[0], -v[2]])
        elif cs == "ship":
            v = -np.asarray(bt.velocity_mps[:3], dtype=np.float64)
            body = np.array([v[1], v[0], -v[2]])
        else:  # earth
            v = -np.asarray(bt.velocity_mps[:3], dtype=np.float64)
            ned = np.array([v[1], v[0], -v[2]])
            # the body's heading is the instrument's less its alignment EA, as for the
            # compass below (the earth velocity turned back with the instrument's own
            # heading would come out EA off the body axes)
            hdg = float(ens.variable.heading_rad) - fx.heading_alignment_rad
            body = body_to_ned(roll, pitch, hdg).T @ ned
        if angle is not None:
            rr = np.asarray(bt.range_m, dtype=np.float64)[:4]
            rng[:len(rr)] = rr / math.cos(angle)  # RDI's vertical range -> along the beam
        else:
            _warn_once(("no beam angle", fx.serial_number),
                       "PD0 ensemble %d (serial %s): no beam angle in the fixed leader and "
                       "none configured: bottom-track ranges unused", number,
                       fx.serial_number)
    vb = getattr(ens, "vertical_beam", None)
    vr = float(vb.range_m) if vb is not None else float("nan")
    hdg = float(wrap_angle(float(ens.variable.heading_rad) - fx.heading_alignment_rad
                           + _declination(fx, declination_rad, number)))
    return DvlSample(int(t), tuple(float(x) for x in body), tuple(float(x) for x in rng),
                     roll, pitch, vr, hdg,
                     beam_angle_rad=float("nan") if angle is None else float(angle),
                     beam_alignment_rad=float(fx.heading_alignment_rad),
                     beams_convex=fx.beam_pattern == "convex")
