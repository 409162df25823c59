"""DVL samples from decoded PD0 ensembles."""

from __future__ import annotations

from typing import Optional

import numpy as np

from svss_daq.frames import body_to_ned

from .dvl_geometry import beam_to_instrument, instrument_to_ship, three_beam_fill
from .headings import wrap_angle
from .records import DvlSample

def dvl_sample_from_pd0(ens, min_beams: int = 3,
                        beam_angle_rad: Optional[float] = None) -> Optional[DvlSample]:
    """A :class:`DvlSample` from a decoded PD0 ensemble (``svss_daq.drivers.pd0``).

    Bottom-track velocity is RDI's velocity of the bottom relative to the instrument,
    so the head's velocity is its negative. Coordinate systems: ``beam`` (to instrument
    with the fixed leader's beam angle, else ``beam_angle_rad``, and beam pattern; one
    bad beam is filled by :func:`three_beam_fill` when ``min_beams`` <= 3, else the
    velocity is bad), ``instrument`` (to ship with the heading alignment and
    orientation), ``ship`` (X starboard, Y forward, Z up, mapped to body x = Y, y = X,
    z = -Z) and ``earth`` (east, north, up: rotated back into the body frame with the
    ensemble's heading, pitch and roll). Returns None without a time or bottom track.
    """
    bt = ens.bottom_track
    t = ens.variable.time_ns
    if bt is None or t is None:
        return None
    fx = ens.fixed
    roll, pitch = float(ens.variable.roll_rad), float(ens.variable.pitch_rad)
    cs = fx.coordinate_system
    if cs in ("beam", "instrument"):
        if cs == "beam":
            angle = fx.beam_angle_rad if fx.beam_angle_rad is not None else beam_angle_rad
            if angle is None:
                raise ValueError(f"PD0 ensemble {ens.variable.ensemble_number}: beam "
                                 "coordinates without a beam angle (fixed leader system "
                                 "configuration bits 8-9 'other', no beam angle byte)")
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
        body = body_to_ned(roll, pitch, float(ens.variable.heading_rad)).T @ ned
    rng = np.full(4, np.nan)
    rr = np.asarray(bt.range_m, dtype=np.float64)[:4]
    rng[:len(rr)] = rr
    vb = getattr(ens, "vertical_beam", None)
    vr = float(vb.range_m) if vb is not None else float("nan")
    hdg = float(wrap_angle(float(ens.variable.heading_rad) - fx.heading_alignment_rad))
    return DvlSample(int(t), tuple(float(x) for x in body), tuple(float(x) for x in rng),
                     roll, pitch, vr, hdg)


