"""Independent references shared by several test files.

Each is written out here from first principles or from the documented layout, with
numpy and scipy only: none calls the project's code, so a test that compares the
project against one of them can fail when the project is wrong.

- :func:`refracted_time`: least one-way time across a flat water/sediment interface by
  brute-force Fermat minimisation (the imager's and the simulator's solvers are checked
  against it); :func:`layered_time` the same through one to three flat layers given as
  thicknesses; :func:`layered_path` between two points through any number of horizontal
  boundaries, minimising over every crossing point (the simulator's layered rays and
  target paths are checked against them).
- :func:`direct_sum`: the backprojection sum voxel by voxel, element by element, in
  float64 (the CPU and GPU kernels are checked against it).
- :func:`body_to_ned_written_out` and :func:`receivers_written_out`: the body-to-survey
  rotation in closed form and the receive array's element positions from the documented
  layout (the geometry and the simulator's echoes are checked against them).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize, minimize_scalar

# ---------------------------------------------------------------------- refraction


def refracted_time(p, q, c_water, c_sediment, xatol=1e-12):
    """Least one-way travel time between ``p`` in the water (z < 0) and ``q``, with a flat
    interface at z = 0: straight at ``c_water`` when ``q`` is at or above the interface
    (or the speeds are equal), otherwise Fermat's least time found by bounded 1-D
    minimisation over the horizontal distance of the crossing point from ``p``."""
    p, q = np.asarray(p, float), np.asarray(q, float)
    if q[2] <= 0 or c_sediment == c_water:
        return float(np.linalg.norm(q - p)) / c_water
    rho = float(np.hypot(*(q[:2] - p[:2])))
    h, z = -float(p[2]), float(q[2])
    res = minimize_scalar(lambda x: np.hypot(x, h) / c_water + np.hypot(rho - x, z) / c_sediment,
                          bounds=(0, rho), method="bounded", options={"xatol": xatol})
    return float(res.fun)


def layered_time(rho, h, c):
    """Least travel time across flat layers of thicknesses ``h`` and speeds ``c`` (one to
    three media) over the horizontal distance ``rho``, by direct minimisation over the
    crossing points: two media by bisection on dT/dx to machine precision, three by
    nested bounded minimisation (independent of the ray-parameter form)."""
    h = np.asarray(h, float)
    c = np.asarray(c, float)
    if len(h) == 1:
        return math.hypot(rho, h[0]) / c[0]
    if len(h) == 2:
        # the crossing x where dT/dx = 0 (monotone), by bisection to machine precision
        f = lambda x: math.hypot(x, h[0]) / c[0] + math.hypot(rho - x, h[1]) / c[1]
        if rho == 0.0:
            return f(0.0)
        d = lambda x: (x / (c[0] * math.hypot(x, h[0]))
                       - (rho - x) / (c[1] * math.hypot(rho - x, h[1])))
        lo, hi = 0.0, rho
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            if mid in (lo, hi):
                break
            lo, hi = (mid, hi) if d(mid) < 0 else (lo, mid)
        return min(f(lo), f(hi))
    # three media: nested minimisation
    def inner(x1):
        g = lambda x2: (math.hypot(x1, h[0]) / c[0] + math.hypot(x2 - x1, h[1]) / c[1]
                        + math.hypot(rho - x2, h[2]) / c[2])
        return minimize_scalar(g, bounds=(x1, rho), method="bounded",
                               options={"xatol": 1e-12}).fun
    return minimize_scalar(inner, bounds=(0.0, rho), method="bounded",
                           options={"xatol": 1e-12}).fun


def layered_path(e, t, speeds, depths, crossings=False):
    """Least travel time from element ``e`` (above z = 0) to ``t`` through horizontal
    boundaries at ``depths`` (first 0), minimising over every crossing point
    (Nelder-Mead from the straight line, then polished by BFGS). With
    ``crossings``, also the crossing points (n, 3)."""
    n = len(depths)
    z = [e[2]] + list(depths) + [t[2]]

    def time(v):
        pts = [np.array(e)] + [np.array([v[2 * i], v[2 * i + 1], depths[i]])
                                for i in range(n)] + [np.array(t)]
        return sum(np.linalg.norm(pts[i + 1] - pts[i]) / speeds[i] for i in range(n + 1))

    frac = [(depths[i] - z[0]) / (z[-1] - z[0]) for i in range(n)]
    x0 = np.concatenate([np.asarray(e[:2]) + f * (np.asarray(t[:2]) - np.asarray(e[:2]))
                         for f in frac])
    r = minimize(time, x0, method="Nelder-Mead",
                 options={"xatol": 1e-11, "fatol": 1e-16, "maxiter": 40000,
                          "maxfev": 80000})
    r = minimize(time, r.x, method="BFGS", options={"gtol": 1e-14})
    if crossings:
        return r.fun, np.array([[r.x[2 * i], r.x[2 * i + 1], depths[i]] for i in range(n)])
    return r.fun


# ---------------------------------------------------------------------- backprojection


def keys(s):
    """Keys cubic convolution kernel, a = -1/2."""
    s = abs(s)
    if s < 1:
        return 1.5 * s**3 - 2.5 * s**2 + 1
    if s < 2:
        return -0.5 * s**3 + 2.5 * s**2 - 4 * s + 2
    return 0.0


def sample(y, u, interp):
    """``y`` at fractional sample ``u`` ("nearest", "linear" or "cubic"); None where the
    interpolator's taps leave the record."""
    n = y.size
    if interp == "nearest":
        i = int(np.floor(u + 0.5))
        return y[i] if 0 <= i < n else None
    if interp == "linear":
        i = int(np.floor(u))
        return y[i] + (u - i) * (y[i + 1] - y[i]) if 0 <= i < n - 1 else None
    i = int(np.floor(u))
    if not 1 <= i < n - 2:
        return None
    return sum(keys(u - j) * y[j] for j in range(i - 1, i + 3))


def direct_sum(data, t0, dt, fc, tx, rx, bore, cos_tx, cos_rx, along, cross, depth, gating,
               interp, mode, apod, c_water, c_sediment, count=False):
    """The backprojected image, float64, one voxel and element at a time: for each voxel
    inside both beam cones (with ``gating``), the sum over elements of ``apod`` times the
    baseband ``data`` (channels x samples, sample n at ``t0 + n dt``) at the two-way
    time, times exp(+j 2 pi fc tau). ``mode`` "straight" uses straight rays at
    ``c_water``; any other mode the refracted least time (:func:`refracted_time`).
    With ``count``, also the number of (voxel, element) terms summed (nonzero weight, in
    the cones, taps inside the record)."""
    img = np.zeros((along.size, cross.size, depth.size), dtype=np.complex128)
    n_terms = 0

    def one_way(p, v):
        if mode == "straight":
            return float(np.linalg.norm(v - p)) / c_water
        return refracted_time(p, v, c_water, c_sediment)

    for i, x in enumerate(along):
        for j, y in enumerate(cross):
            for k, z in enumerate(depth):
                v = np.array([x, y, z])
                r1 = np.linalg.norm(v - tx)
                if gating and (v - tx) @ bore < r1 * cos_tx:
                    continue
                t1 = one_way(tx, v)
                for ch in range(rx.shape[0]):
                    r2 = np.linalg.norm(v - rx[ch])
                    if gating and (v - rx[ch]) @ bore < r2 * cos_rx:
                        continue
                    tau = t1 + one_way(rx[ch], v)
                    s = sample(data[ch], (tau - t0) / dt, interp)
                    if s is not None:
                        img[i, j, k] += apod[ch] * s * np.exp(2j * np.pi * fc * tau)
                        n_terms += int(apod[ch] != 0)
    return (img, n_terms) if count else img


# ---------------------------------------------------------------------- geometry


def body_to_ned_written_out(roll, pitch, heading):
    """Body (x forward, y starboard, z down) to NED rotation for heading psi, pitch theta
    and roll phi (yaw, then pitch, then roll), its nine entries written out."""
    cf, sf = math.cos(roll), math.sin(roll)
    ct, st = math.cos(pitch), math.sin(pitch)
    cp, sp = math.cos(heading), math.sin(heading)
    return np.array([
        [cp * ct, cp * st * sf - sp * cf, cp * st * cf + sp * sf],
        [sp * ct, sp * st * sf + cp * cf, sp * st * cf - cp * sf],
        [-st, ct * sf, ct * cf],
    ])


PITCH_M = 0.091
# Array frame (x forward, y starboard, z down, origin at the centre of the footprint),
# docs/config.md and config/hardware.toml: an aft 4 x 12 section centred 0.182 m aft and
# a forward 4 x 8 section centred 0.182 m forward, both centred cross-track, 9.1 cm pitch.
AFT_ROWS_X = (-0.3185, -0.2275, -0.1365, -0.0455)      # aft to forward
AFT_COLS_Y = tuple(round(PITCH_M * (c - 5.5), 4) for c in range(12))   # +-0.5005, port first
FWD_ROWS_X = (0.0455, 0.1365, 0.2275, 0.3185)
FWD_COLS_Y = (-0.3185, -0.2275, -0.1365, -0.0455, 0.0455, 0.1365, 0.2275, 0.3185)


def receivers_written_out():
    """The 80 receivers in channel order, array frame, m: module by module (4 rows x 2
    columns, eight channels), aft section first, modules port to starboard; within a
    module row by row from aft, port channel first."""
    out = []
    for rows_x, cols_y in ((AFT_ROWS_X, AFT_COLS_Y), (FWD_ROWS_X, FWD_COLS_Y)):
        for m in range(len(cols_y) // 2):
            for x in rows_x:
                out += [(x, cols_y[2 * m], 0.0), (x, cols_y[2 * m + 1], 0.0)]
    return np.array(out)
