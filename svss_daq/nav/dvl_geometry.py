"""Teledyne RDI DVL geometry: beam directions, beam -> instrument -> ship velocities,
altitude from bottom-track ranges (slant, along the beams) and the head's height above
the bottom from a DVL sample."""

from __future__ import annotations

import functools
import math

import numpy as np

from svss_daq.frames import body_to_ned

from .records import DvlSample

# --------------------------------------------------------------------------- DVL


def rdi_beam_vectors(beam_angle_rad: float, convex: bool = True) -> np.ndarray:
    """Outward unit vectors (4, 3) of beams 1-4 in RDI's instrument frame (X, Y, Z; Z
    along the head's axis away from the beams, Y toward beam 3), each ``beam_angle_rad``
    from the axis: the geometry for which :func:`beam_to_instrument` is exact when a beam
    velocity is the velocity's component toward the transducer, b_i = -v . u_i.
    Convex: beam 2 at +X, 1 at -X, 3 at +Y, 4 at -Y; concave swaps each pair."""
    s, c = math.sin(beam_angle_rad), math.cos(beam_angle_rad)
    k = 1.0 if convex else -1.0
    return np.array([[-k * s, 0.0, -c], [k * s, 0.0, -c], [0.0, k * s, -c], [0.0, -k * s, -c]])


def janus_beam_vectors(beam_angle_rad: float, convex: bool = True) -> np.ndarray:
    """Unit vectors (4, 3) of beams 1-4 in the body frame for a down-looking DVL with
    beam 3 forward (instrument X starboard, Y forward, Z up; :func:`rdi_beam_vectors`):
    convex 1 port, 2 starboard, 3 forward, 4 aft, each ``beam_angle_rad`` from the
    vertical."""
    u = rdi_beam_vectors(beam_angle_rad, convex)
    return np.stack([u[:, 1], u[:, 0], -u[:, 2]], axis=-1)


def beam_to_instrument(beam_m_s, beam_angle_rad: float, convex: bool = True) -> np.ndarray:
    """RDI beam velocities (4,) m/s, positive toward the transducer, to instrument
    (X, Y, Z, error) m/s (Teledyne RDI, "ADCP Coordinate Transformation"):
    X = c a (b1 - b2), Y = c a (b4 - b3), Z = b (b1 + b2 + b3 + b4),
    e = d (b1 + b2 - b3 - b4), a = 1/(2 sin theta), b = 1/(4 cos theta), d = a/sqrt(2),
    c = +1 convex, -1 concave. NaN in any beam gives NaN (see :func:`three_beam_fill`)."""
    b1, b2, b3, b4 = (float(x) for x in beam_m_s)
    a = 1.0 / (2.0 * math.sin(beam_angle_rad))
    bb = 1.0 / (4.0 * math.cos(beam_angle_rad))
    c = 1.0 if convex else -1.0
    d = a / math.sqrt(2.0)
    return np.array([c * a * (b1 - b2), c * a * (b4 - b3), bb * (b1 + b2 + b3 + b4),
                     d * (b1 + b2 - b3 - b4)])


def three_beam_fill(beam_m_s) -> np.ndarray:
    """Beam velocities (4,) with one bad (NaN) beam replaced by the value that makes the
    error velocity zero (RDI's 3-beam solution): b1 + b2 = b3 + b4. Unchanged with no
    bad beam; all NaN with more than one."""
    b = np.array(beam_m_s, dtype=np.float64)[:4]
    bad = ~np.isfinite(b)
    if not bad.any():
        return b
    if bad.sum() > 1:
        return np.full(4, np.nan)
    k = int(np.flatnonzero(bad)[0])
    pair, other = ((0, 1), (2, 3)) if k < 2 else ((2, 3), (0, 1))
    mate = pair[1] if k == pair[0] else pair[0]
    b[k] = b[other[0]] + b[other[1]] - b[mate]
    return b


def instrument_to_ship(xyz, heading_alignment_rad: float, up_looking: bool = False
                       ) -> np.ndarray:
    """Instrument (X, Y, Z) to ship (X starboard, Y forward, Z up) coordinates: for an
    up-looking head first a 180 deg roll (X, Z negated, RDI), then the heading alignment
    EA (beam 3's azimuth clockwise from the bow): X' = cos EA X + sin EA Y,
    Y' = -sin EA X + cos EA Y. Tilts are not applied (the navigation applies roll and
    pitch to ship coordinates itself)."""
    x, y, z = (float(v) for v in xyz[:3])
    if up_looking:
        x, z = -x, -z
    ce, se = math.cos(heading_alignment_rad), math.sin(heading_alignment_rad)
    return np.array([ce * x + se * y, -se * x + ce * y, z])


def body_beam_vectors(beam_angle_rad: float, alignment_rad: float = 0.0,
                      convex: bool = True) -> np.ndarray:
    """Unit vectors (4, 3) of beams 1-4 in the body frame (x forward, y starboard, z
    down) for a down-looking head whose beam 3 lies at ``alignment_rad`` clockwise from
    the body x axis (RDI's heading alignment EA, as :func:`instrument_to_ship` applies
    it): :func:`janus_beam_vectors` turned about body z."""
    c, s = math.cos(alignment_rad), math.sin(alignment_rad)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return janus_beam_vectors(beam_angle_rad, convex) @ turn.T


def altitude_from_ranges(ranges_m, roll_rad: float, pitch_rad: float, beam_angle_rad: float,
                         dvl_lever_m, min_beams: int = 3,
                         vertical_range_m: float = float("nan"),
                         alignment_rad: float = 0.0, convex: bool = True) -> float:
    """Height of the body origin above a flat bottom from DVL *slant* ranges (along each
    beam, m; RDI's vertical ranges divided by cos(beam angle) first, as
    :func:`~svss_daq.nav.pd0_samples.dvl_sample_from_pd0` does): the mean over at least
    ``min_beams`` valid beams of range x the down component of the beam (at
    ``beam_angle_rad`` from the head's axis, beam 3 at ``alignment_rad`` from the bow,
    ``convex`` pattern) turned by roll and pitch; with fewer valid ranges (or no beam
    angle) from the vertical beam's range along the head's axis (body z) x cos(roll)
    cos(pitch), else NaN. Plus the head's depth below the body origin (``dvl_lever_m``,
    body frame). Heading does not matter."""
    r = np.asarray(ranges_m, dtype=np.float64)
    ok = np.isfinite(r) & (r > 0)
    rot = body_to_ned(roll_rad, pitch_rad, 0.0)
    if ok.sum() >= min_beams and math.isfinite(beam_angle_rad):
        vert = (body_beam_vectors(beam_angle_rad, alignment_rad, convex) @ rot.T)[:, 2]
        below_head = float(np.mean(r[ok] * vert[ok]))
    elif math.isfinite(vertical_range_m) and vertical_range_m > 0:
        below_head = vertical_range_m * float(rot[2, 2])
    else:
        return float("nan")
    return below_head + float((rot @ np.asarray(dvl_lever_m, dtype=np.float64))[2])


def head_height_m(d: DvlSample, min_beams: int = 3,
                  beam_angle_rad: float = float("nan")) -> float:
    """Height of the DVL head above a flat bottom from one :class:`DvlSample`, m (NaN:
    unknown): its slant ranges, roll, pitch and head geometry (the sample's beam angle,
    which came from the ensemble's fixed leader; ``beam_angle_rad``, the configured one,
    only where the sample has none), the vertical beam's range where fewer than
    ``min_beams`` (pass ``navigation.dvl_min_beams``) ranges are valid."""
    angle = d.beam_angle_rad if math.isfinite(d.beam_angle_rad) else beam_angle_rad
    return altitude_from_ranges(d.ranges_m, d.roll_rad, d.pitch_rad, angle, (0.0, 0.0, 0.0),
                                min_beams, d.vertical_range_m, d.beam_alignment_rad,
                                d.beams_convex)


@functools.lru_cache(maxsize=8192)
def _sample_altitude(d: "DvlSample", beam_angle_rad: float, dvl_lever_m: tuple,
                     min_beams: int) -> float:
    """Height of the body origin above the bottom from one DVL sample (its own head
    geometry; ``beam_angle_rad`` only where it has no beam angle), computed once (a
    navigator poses each ping from the same history of samples)."""
    h = head_height_m(d, min_beams, beam_angle_rad)
    rot = body_to_ned(d.roll_rad, d.pitch_rad, 0.0)
    return h + float((rot @ np.asarray(dvl_lever_m, dtype=np.float64))[2])


#: how far off the plane of the other beams' footprints one of four may lie, as a
#: fraction of their mean range (RDI's river recording: 1.2 % at the 99th percentile)
OFF_PLANE_FRACTION = 0.05


def plausible_bed(foot: np.ndarray, max_slope_deg: float, range_sigma_m: float,
                  off_plane_fraction: float = OFF_PLANE_FRACTION) -> bool:
    """Whether the footprints (n >= 3, 3) about the head lie on one bed no steeper than
    ``max_slope_deg``: the plane through them (least squares in depth) is the bed one
    sample sees, and with four beams each footprint lies on it to within
    ``off_plane_fraction`` of the mean range plus three range sigmas. Otherwise a beam
    is not on the bed the DVL tracks (a head tilted toward the surface or a bank, a
    fish, a wall). Turning the footprints about the vertical changes neither."""
    a = np.stack([np.ones(len(foot)), foot[:, 0], foot[:, 1]], -1)
    coef, *_ = np.linalg.lstsq(a, foot[:, 2], rcond=None)
    if math.hypot(coef[1], coef[2]) > math.tan(math.radians(max_slope_deg)):
        return False
    if len(foot) < 4:
        return True
    off = float(np.max(np.abs(a @ coef - foot[:, 2])))
    return off <= off_plane_fraction * float(np.mean(np.linalg.norm(foot, axis=1))) \
        + 3.0 * range_sigma_m


@functools.lru_cache(maxsize=8192)
def level_footprints(d: DvlSample, beam_angle_rad: float, min_beams: int,
                     max_slope_deg: float, range_sigma_m: float,
                     off_plane_fraction: float = OFF_PLANE_FRACTION):
    """The footprints (n, 3) of one sample's valid beams about the head, turned by its
    roll and pitch but not its heading (x along the body's heading, y to its right, z
    down), computed once (a navigator poses each ping from the same history of
    samples); ``beam_angle_rad`` only where the sample has no beam angle. None where
    fewer than ``min_beams`` ranges are valid (or no beam angle is known); an empty
    (0, 3) array where they lie on no plausible bed (:func:`plausible_bed`)."""
    r = np.asarray(d.ranges_m, dtype=np.float64).reshape(-1)[:4]
    angle = d.beam_angle_rad if math.isfinite(d.beam_angle_rad) else beam_angle_rad
    ok = np.isfinite(r) & (r > 0)
    if r.size < 4 or ok.sum() < min_beams or not math.isfinite(angle):
        return None
    u = body_beam_vectors(angle, d.beam_alignment_rad, d.beams_convex) \
        @ body_to_ned(d.roll_rad, d.pitch_rad, 0.0).T
    foot = r[ok, None] * u[ok]
    if not plausible_bed(foot, max_slope_deg, range_sigma_m, off_plane_fraction):
        foot = np.zeros((0, 3))
    foot.setflags(write=False)
    return foot
