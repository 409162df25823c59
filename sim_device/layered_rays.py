"""Rays through horizontally layered fluids: ray parameter, travel time, spreading.

A ray from a point in medium 0 (water) to a point below crosses media 0..n-1 with
vertical extents h_i and sound speeds c_i. Snell's law keeps the horizontal slowness
p = sin(phi_i)/c_i (phi from the vertical) constant, and the horizontal offset is

    rho(p) = sum_i h_i p / eta_i,        eta_i = sqrt(1/c_i^2 - p^2),

which increases monotonically from 0 to infinity on [0, 1/c_max). Fermat's condition
(cos(theta_w)/c_w = cos(theta_s)/c_s at the interface) is the same statement. We solve
for t = tan(phi) of the fastest medium (p = t / (c_max sqrt(1 + t^2)); the offset
sum h_i r_i t / sqrt(1 + t^2 (1 - r_i^2)), r_i = c_i/c_max <= 1, has no singularity near
the critical angle) by Brent's method inside a bracket that is proven to hold the root
(never Newton, whose steps fail near the critical angle, where d rho/dp is unbounded):
with a = sum h_i r_i and h_c the extent of the fastest media,

    t_lo = rho / a      gives rho(t_lo) <= rho,
    t_hi = rho / h_c    gives rho(t_hi) >= rho.

The travel time uses the tau-p form  T = p rho + sum_i h_i eta_i , which is stationary in
p at the solution (dT/dp = rho - rho(p) = 0), so an error dp costs only O(dp^2) in T.

Geometric spreading of a point source in medium m (energy flux along the ray tube, the
impedances cancel against the plane-wave pressure transmission coefficients):

    |p_r / P_s|^2 = |prod T_k|^2 / [eta_m^2 (sum h_i/eta_i)(sum h_i/(c_i^2 eta_i^3))]

which is 1/r^2 in a homogeneous medium and (h0 + h1 c1/c0)^-2 at normal incidence.

All functions are numba kernels (SI units); :func:`solve_leg` wraps them for numpy use.
The scalar functions the synthesis kernels call are defined once in :func:`build`, which
compiles them with a given decorator: numba's ``njit`` for the CPU (the module-level
names) and a CUDA device decorator for the GPU (:mod:`sim_device.synthesis_gpu`).
"""

from __future__ import annotations

import cmath
import math
from types import SimpleNamespace

import numba as nb
import numpy as np

#: Brent tolerance on t = tan(phi) of the fastest medium, relative to 1 + t; T is
#: stationary in p, so this is far below need.
T_TOL = 1e-12
_EPS = 2.220446049250313e-16

# ------------------------------------------------------------- two-medium lookup table
#
# Legs from the water into the first sediment layer are by far the most common. For two
# media the offset scales with the total vertical extent D = h0 + h1, so the normalised
# ray parameter s = p c_max depends only on w = h0/D and v = rho/(rho + D). A bilinear
# table of s(w, v) gives p to ~1e-6; the travel time, stationary in p, is then exact to
# ~1e-15 s. Each use checks the residual offset and falls back to Brent where the table
# is poor (rays near the critical angle just below the interface of a fast sediment).

#: table size (w, v); the residual offset, relative to D, that the table may leave; the
#: s below which the table is used unchecked (its travel-time error there is below
#: 5e-12 s per metre of D for speed ratios 0.8 to 1.7, tests/sim/test_refraction.py);
#: and the s from which Brent is used without trying the table
TABLE_SHAPE = (257, 1025)
TABLE_RESIDUAL = 1e-4
TABLE_TRUSTED = 0.9
TABLE_CEILING = 0.999999


def build(jit, jit_inline):
    """The scalar ray functions compiled with ``jit`` (called functions) and
    ``jit_inline`` (functions inlined into their callers): numba's ``njit`` for the CPU,
    ``cuda.jit(device=True)`` for both on the GPU. Returns a namespace of them.
    Two-argument min and max are :func:`_lesser` and :func:`_greater` (numba's builtins,
    ``select(b < a, b, a)``): the CUDA target of numba's bundled numba.cuda cannot compile
    the builtins' variadic implementation."""

    @jit_inline
    def _lesser(a, b):
        """min(a, b) as numba evaluates it."""
        return b if b < a else a  # noqa: FURB136 (see build)

    @jit_inline
    def _greater(a, b):
        """max(a, b) as numba evaluates it."""
        return b if b > a else a  # noqa: FURB136 (see build)

    @jit_inline
    def _offset(t, h, c, n, cmax):
        """Horizontal offset (m) of the ray whose fastest-medium angle has tan = t:
        sum h_i r_i t / sqrt(1 + t^2 (1 - r_i^2)), r_i = c_i/c_max (no singularity)."""
        acc = 0.0
        tt = t * t
        for i in range(n):
            if h[i] > 0.0:
                r = c[i] / cmax
                acc += h[i] * r * t / math.sqrt(1.0 + tt * (1.0 - r * r))
        return acc

    @jit
    def fastest(h, c, n):
        """Largest speed among media with positive extent (m/s); 0 if none."""
        cmax = 0.0
        for i in range(n):
            if h[i] > 0.0 and c[i] > cmax:
                cmax = c[i]
        return cmax

    @jit
    def ray_tan(rho, h, c, n):
        """Solve the ray covering horizontal offset ``rho`` (m) through media 0..n-1 of
        vertical extents ``h`` (m) and speeds ``c`` (m/s): returns t = tan(phi) in the
        fastest medium (p = t / (c_max sqrt(1 + t^2))). Brent in a proven bracket."""
        cmax = fastest(h, c, n)
        if cmax == 0.0 or rho <= 0.0:
            return 0.0
        a = 0.0
        hc = 0.0
        for i in range(n):
            if h[i] > 0.0:
                a += h[i] * c[i] / cmax
                if c[i] == cmax:
                    hc += h[i]
        lo = rho / a
        hi = rho / hc
        if hi - lo <= T_TOL * (1.0 + hi):
            return 0.5 * (lo + hi)
        fa = _offset(lo, h, c, n, cmax) - rho
        fb = _offset(hi, h, c, n, cmax) - rho
        if fa >= 0.0:
            return lo
        if fb <= 0.0:
            return hi
        # Brent (1973): inverse quadratic interpolation, secant and bisection, the root
        # staying bracketed between b and c at every step.
        a_, b_ = lo, hi
        c_, fc = a_, fa
        d = e = b_ - a_
        for _ in range(200):
            if (fb > 0.0) == (fc > 0.0):
                c_, fc = a_, fa
                d = e = b_ - a_
            if abs(fc) < abs(fb):
                a_, b_, c_ = b_, c_, b_
                fa, fb, fc = fb, fc, fb
            tol1 = 2.0 * _EPS * abs(b_) + 0.5 * T_TOL * (1.0 + abs(b_))
            xm = 0.5 * (c_ - b_)
            if abs(xm) <= tol1 or fb == 0.0:
                break
            if abs(e) >= tol1 and abs(fa) > abs(fb):
                s_ = fb / fa
                if a_ == c_:
                    p_ = 2.0 * xm * s_
                    q_ = 1.0 - s_
                else:
                    q_ = fa / fc
                    r_ = fb / fc
                    p_ = s_ * (2.0 * xm * q_ * (q_ - r_) - (b_ - a_) * (r_ - 1.0))
                    q_ = (q_ - 1.0) * (r_ - 1.0) * (s_ - 1.0)
                if p_ > 0.0:
                    q_ = -q_
                p_ = abs(p_)
                if 2.0 * p_ < _lesser(3.0 * xm * q_ - abs(tol1 * q_), abs(e * q_)):
                    e = d
                    d = p_ / q_
                else:
                    d = xm
                    e = d
            else:
                d = xm
                e = d
            a_, fa = b_, fb
            if abs(d) > tol1:
                b_ += d
            else:
                b_ += tol1 if xm > 0.0 else -tol1
            fb = _offset(b_, h, c, n, cmax) - rho
        return b_

    @jit_inline
    def ray_amplitude_terms(t, rho, h, c, alpha, n, src):
        """(p, tau, spreading, cos phi_0, attenuation in Np) of a ray through media 0..n-1
        with amplitude attenuation ``alpha`` (Np/m) over the path length h_i / cos(phi_i) in
        each medium.

        eta_i = sqrt(1/c_i^2 - p^2) is formed as sqrt(1 + t^2 (1 - r_i^2)) / (c_i sqrt(1 + t^2))
        (no cancellation near the critical angle); T = p rho + sum h_i eta_i."""
        cmax = fastest(h, c, n)
        if cmax == 0.0:
            cmax = c[0]
        q = math.sqrt(1.0 + t * t)
        p = t / (cmax * q)
        tt = t * t
        tau = p * rho
        s1 = 0.0
        s2 = 0.0
        eta_src = 0.0
        cos0 = 1.0
        att = 0.0
        for i in range(n):
            r = c[i] / cmax
            g = math.sqrt(1.0 + tt * (1.0 - r * r)) / q
            eta = g / c[i]
            if i == src:
                eta_src = eta
            if i == 0:
                cos0 = g
            if h[i] > 0.0:
                tau += h[i] * eta
                s1 += h[i] / eta
                s2 += h[i] / (c[i] * c[i] * eta * eta * eta)
                att += alpha[i] * h[i] / g
        den = eta_src * eta_src * s1 * s2
        spread = 1.0 / math.sqrt(den) if den > 0.0 else 0.0
        return p, tau, spread, cos0, att

    @jit
    def reflection(q, rho_ratio, nu, delta):
        """Rayleigh reflection coefficient (complex) at grazing angle with cos(theta) = q,
        lower/upper density ratio, speed ratio nu and loss parameter delta of the lower medium
        (PHYSICS.md section 2; P on the branch Im P >= 0)."""
        if q > 1.0:  # noqa: PLR1730 (NaN passes through, as before)
            q = 1.0
        sin_t = math.sqrt(_greater(0.0, 1.0 - q * q))
        kap = (1.0 + 1j * delta) / nu
        pp = cmath.sqrt(kap * kap - q * q)
        if pp.imag < 0.0:
            pp = -pp
        num = rho_ratio * sin_t - pp
        den = rho_ratio * sin_t + pp
        if den == 0.0:
            return complex((rho_ratio - 1.0) / (rho_ratio + 1.0), 0.0)
        return num / den

    @jit_inline
    def leg_extents(h_above, z, med, z_top, out):
        """Fill ``out[0..med]`` with the vertical extents of a leg from height ``h_above``
        (m above the interface) down to depth ``z`` in medium ``med`` (z_top: each medium's
        top depth; in water, medium 0, the extent is |h_above + z|). Returns the number of
        media crossed (med + 1)."""
        if med == 0:
            out[0] = abs(h_above + z)
            return 1
        out[0] = h_above
        for i in range(1, med):
            out[i] = z_top[i + 1] - z_top[i]
        out[med] = z - z_top[med]
        return med + 1

    @jit_inline
    def table_ray_tan(rho, h0, h1, c0, c1, tab, hbuf, cbuf):
        """t = tan(phi) in the faster medium (as :func:`ray_tan`) for a two-medium leg with
        extents h0 in water at c0 and h1 below at c1, from :func:`two_medium_table`, with
        Brent where the table's residual offset exceeds TABLE_RESIDUAL * (h0 + h1) (checked
        above s = TABLE_TRUSTED only)."""
        hbuf[0] = h0
        hbuf[1] = h1
        cbuf[0] = c0
        cbuf[1] = c1
        d = h0 + h1
        if rho <= 0.0 or h0 <= 0.0 or h1 <= 0.0:
            return ray_tan(rho, hbuf, cbuf, 2)
        cmax = c0 if c0 > c1 else c1  # noqa: FURB136
        nw, nv = tab.shape
        x = h0 / d * (nw - 1)
        y = rho / (rho + d) * (nv - 1)
        i = _lesser(int(x), nw - 2)
        j = _lesser(int(y), nv - 2)
        fx = x - i
        fy = y - j
        s = ((1.0 - fx) * ((1.0 - fy) * tab[i, j] + fy * tab[i, j + 1])
             + fx * ((1.0 - fy) * tab[i + 1, j] + fy * tab[i + 1, j + 1]))
        if s < TABLE_TRUSTED:
            return s / math.sqrt(1.0 - s * s)
        if s < TABLE_CEILING:
            t = s / math.sqrt(1.0 - s * s)
            if abs(_offset(t, hbuf, cbuf, 2, cmax) - rho) <= TABLE_RESIDUAL * d:
                return t
        return ray_tan(rho, hbuf, cbuf, 2)

    return SimpleNamespace(_lesser=_lesser, _greater=_greater, _offset=_offset,
                           fastest=fastest, ray_tan=ray_tan,
                           ray_amplitude_terms=ray_amplitude_terms, reflection=reflection,
                           leg_extents=leg_extents, table_ray_tan=table_ray_tan)


_cpu = build(nb.njit(cache=True), nb.njit(cache=True, inline="always"))
_offset = _cpu._offset
fastest = _cpu.fastest
ray_tan = _cpu.ray_tan
ray_amplitude_terms = _cpu.ray_amplitude_terms
reflection = _cpu.reflection
leg_extents = _cpu.leg_extents
table_ray_tan = _cpu.table_ray_tan


@nb.njit(cache=True)
def ray_parameter(rho, h, c, n):
    """Horizontal slowness p (s/m) of the ray covering ``rho`` (see :func:`ray_tan`)."""
    cmax = fastest(h, c, n)
    if cmax == 0.0:
        return 1.0 / c[0]
    t = ray_tan(rho, h, c, n)
    return t / (cmax * math.sqrt(1.0 + t * t))


@nb.njit(cache=True)
def ray_terms(t, rho, h, c, n, src):
    """For the ray with fastest-medium tan ``t``: slowness p (s/m), travel time (s),
    spreading amplitude (1/m) of a source in medium ``src``, and cos(phi_0), the
    cosine of the ray's angle from the vertical in medium 0 (no attenuation)."""
    p, tau, spread, cos0, _ = ray_amplitude_terms(t, rho, h, c, np.zeros(max(n, 1)), n, src)
    return p, tau, spread, cos0


def solve_leg(rho: float, h_above: float, z: float, med: int, c: np.ndarray,
              z_top: np.ndarray, source_medium: int = 0) -> dict:
    """One leg from a point ``h_above`` m above the interface to a point at depth ``z``
    in medium ``med``, ``rho`` m apart horizontally: ray parameter p (s/m), travel time
    (s), spreading (1/m) of a source in ``source_medium``, and the angle of the ray from
    the vertical in water (rad)."""
    h = np.zeros(max(med + 1, 1))
    n = leg_extents(h_above, z, med, z_top, h)
    t = ray_tan(rho, h, c, n)
    p, tau, spread, cos0 = ray_terms(t, rho, h, c, n, source_medium)
    return {"p": p, "time": tau, "spreading": spread,
            "water_angle": math.atan2(p * c[0], cos0), "extents": h[:n].copy()}


# two-medium lookup table (constants and design note at the top of the module)
@nb.njit(cache=True)
def _fill_table(tab, c0, c1):
    nw, nv = tab.shape
    h = np.empty(2)
    c = np.empty(2)
    c[0] = c0
    c[1] = c1
    cmax = max(c0, c1)
    for i in range(nw):
        w = i / (nw - 1)
        h[0] = w
        h[1] = 1.0 - w
        for j in range(nv):
            v = j / (nv - 1)
            if j == nv - 1:
                tab[i, j] = 1.0
                continue
            rho = v / (1.0 - v)
            tab[i, j] = ray_parameter(rho, h, c, 2) * cmax


def two_medium_table(c0: float, c1: float) -> np.ndarray:
    """Table of s = p max(c0, c1) over (w, v) for water speed c0 over sediment c1 (m/s)."""
    tab = np.empty(TABLE_SHAPE)
    _fill_table(tab, float(c0), float(c1))
    return tab
