"""WGS-84 geodesy: geodetic <-> ECEF <-> the survey's local north-east-down plane."""

from __future__ import annotations

import math

import numpy as np

WGS84_A = 6378137.0                 #: semi-major axis, m
WGS84_F = 1.0 / 298.257223563       #: flattening
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)

# --------------------------------------------------------------------------- geodesy


def geodetic_to_ecef(lat_deg, lon_deg, h_m) -> np.ndarray:
    """WGS-84 geodetic (deg, deg, m) to ECEF (..., 3), m."""
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    h = np.asarray(h_m, dtype=np.float64)
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
    return np.stack([(n + h) * np.cos(lat) * np.cos(lon), (n + h) * np.cos(lat) * np.sin(lon),
                     (n * (1.0 - WGS84_E2) + h) * np.sin(lat)], axis=-1)


def ecef_to_geodetic(xyz) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ECEF (..., 3) m to WGS-84 (lat deg, lon deg, h m); fixed-point iteration on
    latitude, converged to < 1e-12 rad within 6 steps near the surface."""
    xyz = np.asarray(xyz, dtype=np.float64)
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    p = np.hypot(x, y)
    lon = np.arctan2(y, x)
    lat = np.arctan2(z, p * (1.0 - WGS84_E2))
    for _ in range(8):
        n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
        h = _height(p, z, lat, n)
        lat = np.arctan2(z, p * (1.0 - WGS84_E2 * n / (n + h)))
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
    return np.degrees(lat), np.degrees(lon), _height(p, z, lat, n)


def _height(p, z, lat, n):
    """Height above the ellipsoid, p cos(lat) + z sin(lat) - n (1 - e2 sin^2 lat): valid
    at the poles too (p / cos(lat) - n was 0/0 there: NaN on the polar axis)."""
    s = np.sin(lat)
    return p * np.cos(lat) + z * s - n * (1.0 - WGS84_E2 * s * s)


def ned_rotation(lat0_deg: float, lon0_deg: float) -> np.ndarray:
    """Matrix whose rows are the north, east and down unit vectors (ECEF) at the origin."""
    la, lo = math.radians(lat0_deg), math.radians(lon0_deg)
    sl, cl, so, co = math.sin(la), math.cos(la), math.sin(lo), math.cos(lo)
    return np.array([[-sl * co, -sl * so, cl], [-so, co, 0.0], [-cl * co, -cl * so, -sl]])


def geodetic_to_ned(lat_deg, lon_deg, h_m, origin: tuple[float, float, float]) -> np.ndarray:
    """Geodetic (deg, deg, m) to survey NED (..., 3) m about ``origin`` (lat, lon, h)."""
    d = geodetic_to_ecef(lat_deg, lon_deg, h_m) - geodetic_to_ecef(*origin)
    return d @ ned_rotation(origin[0], origin[1]).T


def ned_to_geodetic(ned, origin: tuple[float, float, float]):
    """Survey NED (..., 3) m to geodetic (lat deg, lon deg, h m)."""
    xyz = np.asarray(ned, dtype=np.float64) @ ned_rotation(origin[0], origin[1]) \
        + geodetic_to_ecef(*origin)
    return ecef_to_geodetic(xyz)


