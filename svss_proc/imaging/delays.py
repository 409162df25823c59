"""Imaging delays: travel times through a flat water-sediment interface (Fermat's
principle), exactly per voxel and element or from a per-ping table.

Geometry: an element at height ``h`` > 0 above the interface, a point at depth ``z`` > 0
below it and horizontal offset ``rho`` >= 0. The ray crosses the interface at horizontal
distance ``x`` from the element, where the travel time

    T(x) = sqrt(x^2 + h^2) / c_w + sqrt((rho - x)^2 + z^2) / c_s

is least; T'(x) = x / (c_w r_w) - (rho - x) / (c_s r_s) increases monotonically from
T'(0) <= 0 to T'(rho) >= 0, so the crossing is the root of T' bracketed by [0, rho]
(Snell: cos(theta_w) / c_w = cos(theta_s) / c_s). The root is found by safeguarded Newton
steps inside a shrinking bracket (bisection whenever Newton leaves it), which converges
near the critical angle too, where plain Newton stalls. Points at or above the interface
(z <= 0) are reached by a straight ray in water.

The scalar functions are built once for the CPU and once for the GPU
(:func:`build_refraction`); the kernels choose between straight rays, the table and the
exact path (:mod:`svss_proc.imaging.kernel_math`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace

import numba as nb
import numpy as np


def build_refraction(jit):
    """The scalar refraction functions compiled with ``jit`` (numba's CPU ``njit`` or a
    CUDA device decorator), so that CPU and GPU kernels share one definition."""

    @jit
    def fermat_crossing(h, rho, z, cw, cs):
        """Horizontal distance (m) from the element to where the ray crosses the interface.

        h: element height above the interface (m, > 0); rho: horizontal offset (m, >= 0);
        z: depth below the interface (m, > 0); cw, cs: water and sediment speeds (m/s).
        Safeguarded Newton inside a shrinking bracket, to 1e-10 m.
        """
        if rho <= 0.0:
            return 0.0
        lo = 0.0
        hi = rho
        x = rho * h / (h + z)                # the straight line's crossing
        for _ in range(100):
            rw = math.sqrt(x * x + h * h)
            rs = math.sqrt((rho - x) * (rho - x) + z * z)
            # rs = 0 when the point lies on the interface to rounding (z * z underflows,
            # z < 1e-154 m) and x = rho: the sediment leg vanishes (was 0/0)
            g = x / (cw * rw) - ((rho - x) / (cs * rs) if rs > 0.0 else 0.0)
            if g > 0.0:
                hi = x
            else:
                lo = x
            # (h/r)^2/(c r): r^3 underflowed to 0 for r < 1e-103 m (z ~ 1e-122 m)
            dg = (h / rw) * (h / rw) / (cw * rw) + ((z / rs) * (z / rs) / (cs * rs)
                                                    if rs > 0.0 else 0.0)
            xn = x - g / dg
            if not (lo < xn < hi):
                xn = 0.5 * (lo + hi)
            if abs(xn - x) <= 1e-10 or hi - lo <= 1e-10:
                return xn
            x = xn
        return x

    @jit
    def one_way_time(h, rho, z, cw, cs):
        """One-way travel time (s) from an element at height h above the interface to a
        point at horizontal offset rho and depth z (straight in water when z <= 0)."""
        if z <= 0.0:
            dz = h + z
            return math.sqrt(rho * rho + dz * dz) / cw
        x = fermat_crossing(h, rho, z, cw, cs)
        return math.sqrt(x * x + h * h) / cw + math.sqrt((rho - x) ** 2 + z * z) / cs

    @jit
    def vertical_slowness(h, rho, z, cw, cs):
        """dT/dh (s/m): the water-side vertical slowness of the ray, sqrt(1/cw^2 - p^2)
        with p = cos(theta_w) / cw the ray parameter."""
        if z <= 0.0:
            dz = h + z
            r = math.sqrt(rho * rho + dz * dz)
            return dz / (cw * r) if r > 0.0 else 1.0 / cw
        x = fermat_crossing(h, rho, z, cw, cs)
        return h / (cw * math.sqrt(x * x + h * h))

    return SimpleNamespace(fermat_crossing=fermat_crossing, one_way_time=one_way_time,
                           vertical_slowness=vertical_slowness)


_cpu = build_refraction(nb.njit(cache=True))
fermat_crossing = _cpu.fermat_crossing
one_way_time = _cpu.one_way_time
vertical_slowness = _cpu.vertical_slowness


@dataclass(frozen=True)
class TravelTimeTable:
    """One-way travel times from an element at height ``h_ref`` above the interface,
    on a regular grid of horizontal offset rho (from 0, step ``drho``) and depth z (from
    ``z0``, step ``dz``), with the vertical slowness for a first-order correction to
    other element heights: T(h, rho, z) ~ T(h_ref, rho, z) + (h - h_ref) * eta."""
    h_ref: float
    drho: float
    z0: float
    dz: float
    time: np.ndarray    # (n_rho, n_z) s
    eta: np.ndarray     # (n_rho, n_z) s/m

    @property
    def rho_max(self) -> float:
        """The largest offset the table was built for (m; :func:`build_table`'s margin of
        two nodes beyond it)."""
        return (self.time.shape[0] - 2) * self.drho


@nb.njit(parallel=True, cache=True)
def _fill_table(h, drho, z0, dz, cw, cs, time, eta):
    n_rho, n_z = time.shape
    for i in nb.prange(n_rho):
        rho = i * drho
        for j in range(n_z):
            z = z0 + j * dz
            time[i, j] = one_way_time(h, rho, z, cw, cs)
            eta[i, j] = vertical_slowness(h, rho, z, cw, cs)


def build_table(h_ref: float, rho_max: float, z_min: float, z_max: float, step: float,
                water_sound_speed: float, sediment_sound_speed: float) -> TravelTimeTable:
    """Tabulate one-way times for offsets 0..rho_max and depths z_min..z_max (m), for
    the water and sediment sound speeds (m/s)."""
    if h_ref <= 0:
        raise ValueError(f"travel-time table: element height above the interface must be "
                         f"positive, got {h_ref} m")
    n_rho = int(math.ceil(rho_max / step)) + 2
    n_z = int(math.ceil((z_max - z_min) / step)) + 2
    time = np.empty((n_rho, n_z))
    eta = np.empty((n_rho, n_z))
    _fill_table(h_ref, step, z_min, step, water_sound_speed, sediment_sound_speed, time, eta)
    return TravelTimeTable(h_ref, step, z_min, step, time, eta)
