"""Coordinate frames and array geometry at their extremes: rotations at any angle
(gimbal lock included), the tile frame and the local geodetic frame to 10 km and at the
poles (against mpmath), and degenerate arrays (one element, collinear elements)."""

from __future__ import annotations

import math

import mpmath as mp
import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from sim_device.fidelity import resolution_cell
from svss_daq.config import ReceiveArray, ReceiveSection
from svss_daq.frames import TrackLine, body_to_ned
from svss_daq.geometry import ArrayGeometry, place_array, section_positions
from svss_daq.navigation import (
    WGS84_A,
    WGS84_E2,
    ecef_to_geodetic,
    geodetic_to_ecef,
    geodetic_to_ned,
    ned_to_geodetic,
)
from svss_daq.ping import NavSnapshot
from svss_proc.imaging.imager import receive_apodisation

from ._sweep import sweep

angles = st.one_of(st.floats(-1e3, 1e3), st.sampled_from(
    [0.0, math.pi, -math.pi, math.pi / 2, -math.pi / 2, 2 * math.pi, 1e3]))
far = st.floats(-1e4, 1e4)


@sweep(60)
@given(angles, angles, angles)
def test_body_to_ned_is_a_rotation_at_any_angle(roll, pitch, heading):
    r = body_to_ned(roll, pitch, heading)
    assert np.all(np.isfinite(r))
    assert np.allclose(r @ r.T, np.eye(3), atol=2e-15 * 3)
    assert abs(np.linalg.det(r) - 1.0) <= 1e-14
    # pitch = +-90 deg (gimbal lock): the body x axis points straight up or down
    if abs(abs(pitch) - math.pi / 2) < 1e-15:
        assert abs(abs(r[2, 0]) - 1.0) <= 1e-15


@sweep(60)
@given(far, far, st.floats(-100.0, 100.0), angles, far, far, st.floats(-50.0, 50.0))
def test_tile_frame_round_trip_at_10_km(n0, e0, down, heading, n, e, d):
    line = TrackLine((n0, e0), heading, down)
    ned = np.array([n, e, d])
    atd = line.ned_to_tile(ned)
    back = line.tile_to_ned(atd)
    assert np.all(np.abs(back - ned) <= 1e-11 * (1 + np.abs([n0, e0, down]).max()
                                                 + np.abs(ned).max()))
    # distances are kept: a rigid motion
    assert abs(np.hypot(*atd[:2]) - math.hypot(n - n0, e - e0)) <= 1e-11 * 3e4
    rot = line.rotation_from_ned()
    assert np.allclose(rot @ (ned - [n0, e0, down]), atd, atol=1e-9)


def ecef_mp(lat, lon, h):
    with mp.workdps(40):
        la, lo = mp.radians(lat), mp.radians(lon)
        n = WGS84_A / mp.sqrt(1 - WGS84_E2 * mp.sin(la) ** 2)
        return np.array([float((n + h) * mp.cos(la) * mp.cos(lo)),
                         float((n + h) * mp.cos(la) * mp.sin(lo)),
                         float((n * (1 - WGS84_E2) + h) * mp.sin(la))])


lats = st.one_of(st.floats(-90.0, 90.0), st.sampled_from([90.0, -90.0, 0.0, 89.9999999]))
lons = st.one_of(st.floats(-180.0, 180.0), st.sampled_from([180.0, -180.0, 0.0]))


@sweep(60)
@given(lats, lons, st.floats(-1000.0, 1e4))
def test_geodetic_round_trip_everywhere_including_the_poles(lat, lon, h):
    """Regression: on the polar axis (x = y = 0) the height was p/cos(lat) - N = 0/0."""
    xyz = geodetic_to_ecef(lat, lon, h)
    assert np.all(np.abs(xyz - ecef_mp(lat, lon, h)) <= 1e-8)
    la, lo, hh = (float(v) for v in ecef_to_geodetic(xyz))
    assert abs(la - lat) <= 1e-9 and abs(hh - h) <= 1e-6
    if abs(lat) < 89.99:
        assert abs((lo - lon + 180.0) % 360.0 - 180.0) <= 1e-9
    # exactly on the polar axis (the Earth's centre, z = 0, has no geodetic position)
    if abs(xyz[2]) > 1e6:
        with np.errstate(all="raise"):
            la, lo, hh = (float(v) for v in ecef_to_geodetic(np.array([0.0, 0.0, xyz[2]])))
        assert abs(abs(la) - 90.0) <= 1e-9
        assert abs(hh - (abs(xyz[2]) - WGS84_A * math.sqrt(1 - WGS84_E2))) <= 1e-6


@sweep(40)
@given(lats, lons, far, far, st.floats(-100.0, 100.0))
def test_local_frame_round_trip_to_10_km(lat0, lon0, n, e, d):
    origin = (lat0, lon0, 0.0)
    ned = np.array([n, e, d])
    lat, lon, h = ned_to_geodetic(ned, origin)
    assert all(math.isfinite(float(v)) for v in (lat, lon, h))
    back = geodetic_to_ned(lat, lon, h, origin)
    assert np.all(np.abs(back - ned) <= 1e-5)


def _nav(n, e, d, roll, pitch, heading, alt=2.0):
    return NavSnapshot(0, n, e, d, 0.0, 0.0, 0.0, roll, pitch, heading, alt)


@sweep(40)
@given(st.integers(1, 12), st.sampled_from(["one", "line_x", "line_y", "line_z"]),
       far, far, angles, angles, angles)
def test_place_degenerate_arrays_far_from_the_origin(n, shape, north, east, r, p, hd):
    """One element, or all elements on a line: placing is a rigid motion, the
    apodisation stays finite and the resolution cell finite and positive."""
    if shape == "one":
        rx = np.array([[0.1, -0.2, 0.3]])
    else:
        axis = {"line_x": 0, "line_y": 1, "line_z": 2}[shape]
        rx = np.zeros((n, 3))
        rx[:, axis] = np.arange(n) * 0.091
    geo = ArrayGeometry(rx, np.array([[0.5, 0.0, 0.0]]), np.array([0.0, 0.0, 1.0]),
                        math.radians(25), math.radians(50))
    line = TrackLine((north - 5.0, east + 5.0), 0.3, 2.0)
    placed = place_array(geo, _nav(north, east, 0.0, r, p, hd), 0, line)
    assert np.all(np.isfinite(placed.rx)) and placed.rx.shape == rx.shape
    d0 = np.linalg.norm(rx[:, None] - rx[None], axis=-1)
    d1 = np.linalg.norm(placed.rx[:, None] - placed.rx[None], axis=-1)
    assert np.allclose(d0, d1, atol=1e-9)
    assert abs(np.linalg.norm(placed.bore) - 1.0) <= 1e-14
    w = receive_apodisation(rx, "hann")
    assert np.all(np.isfinite(w)) and np.all(w > 0) and abs(w.mean() - 1.0) <= 1e-12
    cell = resolution_cell(rx, 0.091, 15e3, 27.5e3, 2.0, 1500.0, 1767.0)
    assert all(math.isfinite(v) and v > 0 for v in (cell.along, cell.across, cell.volume))


@sweep(20)
@given(st.integers(1, 4), st.integers(1, 4), st.integers(1, 3), st.integers(1, 3))
def test_section_positions_of_tiny_sections(mr, mc, nr, nc):
    arr = ReceiveArray(0.05, mr, mc, (ReceiveSection("s", mr * nr, mc * nc, (0.1, 0.0, 0.0)),))
    (pos,) = section_positions(arr)
    assert pos.shape == (mr * nr * mc * nc, 3)
    assert np.allclose(pos.mean(axis=0), [0.1, 0.0, 0.0])       # centred on the section
    assert len({tuple(np.round(p, 9)) for p in pos}) == pos.shape[0]   # all distinct
