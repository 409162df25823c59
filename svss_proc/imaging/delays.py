"""Imaging delays: travel times through a flat water-sediment interface (Fermat's
principle), exactly per voxel and element or from a per-ping table; the table also
through horizontal sediment layers (:func:`layered_ray`, :class:`SpeedProfile`).

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
    def height_curvature(h, rho, z, cw, cs):
        """d^2T/dh^2 (s/m^2): how the vertical slowness changes with the element's
        height, p^2 cw^2 / (cos^2(theta_w) dX/dp) with X(p) = sum_j e_j c_j p / cos_j the
        ray's horizontal reach (sin^2(theta) / (c r) for a straight ray)."""
        if z <= 0.0:
            dz = h + z
            r = math.sqrt(rho * rho + dz * dz)
            return rho * rho / (cw * r * r * r) if r > 0.0 else 0.0
        x = fermat_crossing(h, rho, z, cw, cs)
        rw = math.sqrt(x * x + h * h)
        p = x / (cw * rw)
        cos_w = h / rw
        q = 1.0 - (cs * p) * (cs * p)
        if q <= 1e-24:                       # at the critical angle: dX/dp unbounded
            return 0.0
        cos_s = math.sqrt(q)
        dxdp = h * cw / (cos_w * cos_w * cos_w) + z * cs / (cos_s * cos_s * cos_s)
        return p * p * cw * cw / (cos_w * cos_w * dxdp)

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
                           vertical_slowness=vertical_slowness,
                           height_curvature=height_curvature)


_cpu = build_refraction(nb.njit(cache=True))
fermat_crossing = _cpu.fermat_crossing
one_way_time = _cpu.one_way_time
vertical_slowness = _cpu.vertical_slowness
height_curvature = _cpu.height_curvature


@nb.njit(cache=True)
def layered_ray(h, rho, z, cw, tops, speeds):
    """(one-way time s, water-side vertical slowness dT/dh s/m, its derivative
    d^2T/dh^2 s/m^2) from an element at height h
    above the interface to a point at horizontal offset rho and depth z below it,
    through horizontal sediment layers: layer k from depth ``tops[k]`` (``tops[0]`` = 0)
    down to ``tops[k + 1]`` (the last: a half-space) at ``speeds[k]`` m/s.

    The ray crosses media j (the water, each layer above the point's, the point's own
    down to z) of vertical extents e_j at speeds c_j with one horizontal slowness p
    (Snell). With c_m the fastest of them, r_j = c_j / c_m and t the tangent of the
    ray's angle from the vertical in that medium, the horizontal reach is

        X(t) = sum_j e_j r_j t / sqrt(1 + t^2 (1 - r_j^2)),

    increasing from 0 to infinity without a singularity at the critical angle. Its root
    X(t) = rho lies in [rho / sum e_j r_j, rho / E_m] (E_m the extent of the fastest
    media: X(t) >= E_m t) and is found by Newton steps kept inside that shrinking bracket.
    The time uses the tau-p form T = p rho + sum_j e_j cos_j / c_j, stationary in p,
    so the root's residual enters only to second order. With the water's cosine cos_0
    and dX/dp = sum_j e_j c_j / cos_j^3, d^2T/dh^2 = p^2 cw^2 / (cos_0^2 dX/dp)."""
    if z <= 0.0:
        dz = h + z
        r = math.sqrt(rho * rho + dz * dz)
        if r <= 0.0:
            return 0.0, 1.0 / cw, 0.0
        return r / cw, dz / (cw * r), rho * rho / (cw * r * r * r)
    n = tops.size
    k = 0
    while k + 1 < n and z > tops[k + 1]:
        k += 1
    m = k + 2                                   # the water, layers 0..k
    ext = np.empty(m)
    spd = np.empty(m)
    ext[0] = h
    spd[0] = cw
    for j in range(k + 1):
        spd[j + 1] = speeds[j]
        ext[j + 1] = (tops[j + 1] if j < k else z) - tops[j]
    cm = spd.max()
    sum_er = 0.0
    e_fast = 0.0
    for j in range(m):
        sum_er += ext[j] * spd[j] / cm
        if spd[j] == cm:
            e_fast += ext[j]
    t = 0.0
    if rho > 0.0:
        lo = rho / sum_er
        hi = rho / e_fast
        t = lo
        for _ in range(200):
            x = 0.0
            dx = 0.0
            for j in range(m):
                r = spd[j] / cm
                q = 1.0 + t * t * (1.0 - r * r)
                x += ext[j] * r * t / math.sqrt(q)
                dx += ext[j] * r / (q * math.sqrt(q))
            g = x - rho
            if g > 0.0:
                hi = t
            else:
                lo = t
            tn = t - g / dx
            if not (lo < tn < hi):
                tn = 0.5 * (lo + hi)
            if abs(tn - t) <= 1e-14 * (1.0 + t) or hi - lo <= 1e-14 * (1.0 + t):
                t = tn
                break
            t = tn
    s2 = t * t / (1.0 + t * t)                 # sin^2 in the fastest medium
    p = math.sqrt(s2) / cm
    time = p * rho
    eta0 = 0.0
    cos0 = 1.0
    dxdp = 0.0
    grazing = False
    for j in range(m):
        r = spd[j] / cm
        cosj = math.sqrt(max(1.0 - r * r * s2, 0.0))
        time += ext[j] * cosj / spd[j]
        if j == 0:
            eta0 = cosj / spd[j]
            cos0 = cosj
        if cosj <= 1e-12:
            grazing = True
        else:
            dxdp += ext[j] * spd[j] / (cosj * cosj * cosj)
    kappa = 0.0
    if not grazing and dxdp > 0.0 and cos0 > 0.0:
        kappa = p * p * cw * cw / (cos0 * cos0 * dxdp)
    return time, eta0, kappa


@dataclass(frozen=True)
class SpeedProfile:
    """The sediment below the interface: layers from depths ``tops`` (m, ``tops[0]`` = 0)
    at ``speeds`` (m/s), the last a half-space."""
    tops: tuple[float, ...]
    speeds: tuple[float, ...]

    @classmethod
    def of(cls, imaging) -> "SpeedProfile":
        """From a processing configuration's ``[imaging]``: its ``sediment_layers`` over
        the half-space ``sediment_sound_speed_m_s``."""
        tops, speeds, d = [0.0], [], 0.0
        for layer in imaging.sediment_layers:
            d += layer.thickness_m
            tops.append(d)
            speeds.append(layer.sound_speed_m_s)
        speeds.append(imaging.sediment_sound_speed_m_s)
        return cls(tuple(tops), tuple(float(c) for c in speeds))

    @property
    def layered(self) -> bool:
        return len(self.speeds) > 1


@dataclass(frozen=True)
class TravelTimeTable:
    """One-way travel times from an element at height ``h_ref`` above the interface,
    on a regular grid of horizontal offset rho (from 0, step ``drho``) and depth z (from
    ``z0``, step ``dz``), with the vertical slowness and its derivative for a
    second-order correction to other element heights:
    T(h, rho, z) ~ T(h_ref, rho, z) + dh eta + dh^2 kappa / 2, dh = h - h_ref (the
    kernels use the first order alone on a level interface, where the table's height is
    the ping's own to 5 mm, and the second over a sloping one, where the interface's
    depth at each column shifts the heights by decimetres)."""
    h_ref: float
    drho: float
    z0: float
    dz: float
    time: np.ndarray    # (n_rho, n_z) s
    eta: np.ndarray     # (n_rho, n_z) s/m
    kappa: np.ndarray   # (n_rho, n_z) s/m^2

    @property
    def rho_max(self) -> float:
        """The largest offset the table was built for (m; :func:`build_table`'s margin of
        two nodes beyond it)."""
        return (self.time.shape[0] - 2) * self.drho


@nb.njit(parallel=True, cache=True)
def _fill_layered(h, drho, z0, dz, cw, tops, speeds, time, eta, kappa):
    n_rho, n_z = time.shape
    for i in nb.prange(n_rho):
        rho = i * drho
        for j in range(n_z):
            time[i, j], eta[i, j], kappa[i, j] = layered_ray(h, rho, z0 + j * dz, cw,
                                                             tops, speeds)


@nb.njit(parallel=True, cache=True)
def _fill_table(h, drho, z0, dz, cw, cs, time, eta, kappa):
    n_rho, n_z = time.shape
    for i in nb.prange(n_rho):
        rho = i * drho
        for j in range(n_z):
            z = z0 + j * dz
            time[i, j] = one_way_time(h, rho, z, cw, cs)
            eta[i, j] = vertical_slowness(h, rho, z, cw, cs)
            kappa[i, j] = height_curvature(h, rho, z, cw, cs)


def build_table(h_ref: float, rho_max: float, z_min: float, z_max: float, step: float,
                water_sound_speed: float, sediment_sound_speed: float,
                profile: SpeedProfile | None = None) -> TravelTimeTable:
    """Tabulate one-way times for offsets 0..rho_max and depths z_min..z_max (m), for
    the water and sediment sound speeds (m/s), or through a layered ``profile`` (then
    ``sediment_sound_speed`` is not used)."""
    if h_ref <= 0:
        raise ValueError(f"travel-time table: element height above the interface must be "
                         f"positive, got {h_ref} m")
    n_rho = int(math.ceil(rho_max / step)) + 2
    n_z = int(math.ceil((z_max - z_min) / step)) + 2
    time = np.empty((n_rho, n_z))
    eta = np.empty((n_rho, n_z))
    kappa = np.empty((n_rho, n_z))
    if profile is not None and profile.layered:
        _fill_layered(h_ref, step, z_min, step, water_sound_speed,
                      np.asarray(profile.tops, dtype=np.float64),
                      np.asarray(profile.speeds, dtype=np.float64), time, eta, kappa)
    else:
        cs = profile.speeds[0] if profile is not None else sediment_sound_speed
        _fill_table(h_ref, step, z_min, step, water_sound_speed, cs, time, eta, kappa)
    return TravelTimeTable(h_ref, step, z_min, step, time, eta, kappa)
