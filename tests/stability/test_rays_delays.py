"""Travel times and rays at their extremes: the imager's Fermat solver and the
simulator's layered ray solver against mpmath at grazing offsets to 10 km, near the
critical angle and at the interface itself; the kernels' float32 travel times at ranges
to 10 km; spreading in a homogeneous medium to 10 km; the refraction table at its edges."""

from __future__ import annotations

import math

import mpmath as mp
import numba as nb
import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from sim_device.layered_rays import ray_tan, ray_terms, solve_leg
from svss_proc.imaging.cpu_kernel import _cpu
from svss_proc.imaging.delays import (
    build_table,
    fermat_crossing,
    one_way_time,
    vertical_slowness,
)
from svss_proc.imaging.kernel_args import EXACT, STRAIGHT, TABLE, TravelTimes

from ._sweep import sweep

CW = 1500.0
heights = st.one_of(st.floats(1e-3, 100.0), st.sampled_from([1e-3, 2.0, 100.0]))
depths = st.one_of(st.floats(1e-4, 100.0), st.sampled_from([1e-4, 1.0]))
offsets = st.one_of(st.floats(0.0, 1e4), st.sampled_from([0.0, 1e-12, 1e-3, 1e4]))
speeds = st.one_of(st.floats(1200.0, 3000.0), st.sampled_from([1500.0, 1500.0 * (1 + 1e-9)]))


def fermat_mp(h, rho, z, cw, cs):
    """(x, T) of the least-time path, 30 digits, by bisection on T'(x) over [0, rho]."""
    with mp.workdps(30):
        h, rho, z, cw, cs = (mp.mpf(v) for v in (h, rho, z, cw, cs))
        if rho == 0:
            return 0.0, float(h / cw + z / cs)

        def g(x):
            return x / (cw * mp.sqrt(x * x + h * h)) - (rho - x) / (cs * mp.sqrt(
                (rho - x) ** 2 + z * z))
        # T is stationary at the root: x to 2^-70 of rho leaves T exact to 40 digits
        lo, hi = mp.mpf(0), rho
        for _ in range(70):
            mid = (lo + hi) / 2
            if g(mid) > 0:
                hi = mid
            else:
                lo = mid
        x = (lo + hi) / 2
        t = mp.sqrt(x * x + h * h) / cw + mp.sqrt((rho - x) ** 2 + z * z) / cs
        return float(x), float(t)


@sweep(50)
@given(heights, offsets, depths, speeds)
def test_fermat_time_matches_mpmath_from_nadir_to_10_km(h, rho, z, cs):
    x = fermat_crossing(h, rho, z, CW, cs)
    t = one_way_time(h, rho, z, CW, cs)
    _, t_ref = fermat_mp(h, rho, z, CW, cs)
    assert 0.0 <= x <= rho and math.isfinite(t)
    # T is stationary in x: the time is exact to rounding even where x is ill-conditioned
    assert abs(t - t_ref) <= 1e-13 * t_ref
    eta = vertical_slowness(h, rho, z, CW, cs)
    assert 0.0 <= eta <= 1.0 / CW * (1 + 1e-12)


@sweep(40)
@given(heights, offsets, depths, st.floats(1e-9, 1e-2))
def test_fermat_near_the_critical_angle(h, rho, z, excess):
    """A fast sediment with the ray near grazing in the sediment: T' is flat in x there."""
    cs = CW * (1 + excess)
    t = one_way_time(h, rho, z, CW, cs)
    assert abs(t - fermat_mp(h, rho, z, CW, cs)[1]) <= 1e-13 * t


def layered_mp(rho, h, c):
    """Travel time of the layered ray covering offset rho, 40 digits (bisection on p)."""
    with mp.workdps(40):
        h = [mp.mpf(v) for v in h]
        c = [mp.mpf(v) for v in c]
        rho = mp.mpf(rho)
        cmax = max(c)

        def offset(t):        # in t = tan of the fastest medium's angle, as the solver
            p = t / (cmax * mp.sqrt(1 + t * t))
            return sum(hi_ * p / mp.sqrt(1 / ci ** 2 - p * p) for hi_, ci in zip(h, c)) - rho
        if rho == 0:
            t = mp.mpf(0)
        else:
            a = sum(hi_ * ci / cmax for hi_, ci in zip(h, c))
            hc = sum(hi_ for hi_, ci in zip(h, c) if ci == cmax)
            lo, hi = rho / a, rho / hc
            for _ in range(80):       # bisection; T is stationary in p
                mid = (lo + hi) / 2
                if offset(mid) > 0:
                    hi = mid
                else:
                    lo = mid
            t = (lo + hi) / 2
        p = t / (cmax * mp.sqrt(1 + t * t))
        return float(p * rho + sum(hi_ * mp.sqrt(1 / ci ** 2 - p * p) for hi_, ci in zip(h, c)))


@sweep(40)
@given(offsets, st.lists(st.floats(1e-3, 50.0), min_size=1, max_size=4),
       st.lists(st.floats(1300.0, 2500.0), min_size=4, max_size=4))
def test_layered_ray_time_matches_mpmath_at_grazing(rho, h, c):
    h = np.array(h)
    c = np.array(c[: h.size])
    t = ray_tan(rho, h, c, h.size)
    p, tau, spread, cos0 = ray_terms(t, rho, h, c, h.size, 0)
    assert all(math.isfinite(v) for v in (t, p, tau, spread, cos0)) and spread > 0
    assert abs(tau - layered_mp(rho, h, c)) <= 1e-12 * tau


@sweep(30)
@given(st.floats(0.0, 1e4), st.floats(1e-3, 100.0), st.floats(1e-3, 100.0))
def test_homogeneous_spreading_is_one_over_range_to_10_km(rho, h0, h1):
    c = np.array([CW, CW])
    leg = solve_leg(rho, h0, h1, 1, c, np.array([-np.inf, 0.0]))
    r = math.hypot(rho, h0 + h1)
    assert abs(leg["time"] - r / CW) <= 1e-13 * r / CW
    assert abs(leg["spreading"] * r - 1.0) <= 1e-9


_travel_time = _cpu.travel_time


@nb.njit        # no on-disk cache: numba's cache would not see changes in delays.py
def _kernel_time(mode, dx, dy, z, h, tt):
    return _travel_time(mode, dx, dy, z, h, tt)


def _straight32(cw):
    empty = np.zeros((2, 2))
    return TravelTimes(np.float32(1.0 / cw), cw, cw, empty, empty, 1.0, 0.0, 1.0, 1.0)


@sweep(60)
@given(st.floats(-1e4, 1e4), st.floats(-1e4, 1e4), st.floats(-50.0, 200.0),
       st.floats(0.1, 100.0))
def test_float32_straight_travel_time_to_10_km(dx, dy, z, h):
    """The float32 kernel's straight-ray time stays within a few float32 roundings of
    the exact time at ranges to 14 km: at most 6 eps32 t, i.e. 0.25 samples of the
    62.5 kHz baseband at 10 km (0.7 rad of carrier phase): float32 is for tiles, not for
    absolute ranges of kilometres."""
    f = np.float32
    t32 = _kernel_time(STRAIGHT, f(dx), f(dy), f(z), f(h), _straight32(CW))
    with mp.workdps(30):
        ref = float(mp.sqrt(mp.mpf(float(f(dx))) ** 2 + mp.mpf(float(f(dy))) ** 2
                            + (mp.mpf(float(f(z))) + mp.mpf(float(f(h)))) ** 2) / CW)
    assert math.isfinite(float(t32))
    assert abs(float(t32) - ref) <= 6 * np.finfo(np.float32).eps * ref + 1e-12
    # float64 geometry: exact to rounding
    t64 = _kernel_time(STRAIGHT, dx, dy, z, h, TravelTimes(1.0 / CW, CW, CW, *(
        np.zeros((2, 2)),) * 2, 1.0, 0.0, 1.0, 1.0))
    exact = math.sqrt(dx * dx + dy * dy + (z + h) ** 2) / CW
    assert abs(t64 - exact) <= 4e-16 * exact + 1e-300


@sweep(25)
@given(st.floats(0.5, 5.0), st.floats(1300.0, 2200.0), st.floats(0.0, 30.0),
       st.floats(0.0, 3.0), st.floats(-1.0, 1.0))
def test_table_time_finite_and_bilinear_inside_and_clamped_outside(h, cs, rho, z, dh):
    """The refraction table read anywhere (beyond its last column and row it clamps):
    finite; inside, exactly the bilinear interpolation of the exact node times plus the
    first-order height correction (nodes computed here with one_way_time and
    vertical_slowness), and near the exact time (the bilinear error of a 5 cm step,
    largest near the critical angle; the default 1 cm step is 25 times closer)."""
    step = 0.05
    tab = build_table(h, 20.0, -step, 2.0 + step, step, CW, cs)
    tt = TravelTimes(1.0 / CW, CW, cs, tab.time, tab.eta, 1.0 / tab.drho, tab.z0,
                     1.0 / tab.dz, tab.h_ref)
    hh = max(h + 0.1 * dh, 0.05)
    t = _kernel_time(TABLE, rho, 0.0, z, hh, tt)
    assert math.isfinite(t) and t > 0
    u, v = rho / step, (z - tab.z0) / step
    i, j = int(u), int(v)
    if i + 1 < tab.time.shape[0] and j + 1 < tab.time.shape[1]:
        a, b = u - i, v - j

        def node(ii, jj):
            r, zz = ii * step, tab.z0 + jj * step
            return (one_way_time(h, r, zz, CW, cs), vertical_slowness(h, r, zz, CW, cs))
        (t00, e00), (t01, e01), (t10, e10), (t11, e11) = (node(i, j), node(i, j + 1),
                                                          node(i + 1, j),
                                                          node(i + 1, j + 1))
        bil_t = (1 - a) * ((1 - b) * t00 + b * t01) + a * ((1 - b) * t10 + b * t11)
        bil_e = (1 - a) * ((1 - b) * e00 + b * e01) + a * ((1 - b) * e10 + b * e11)
        assert abs(t - (bil_t + (hh - h) * bil_e)) <= 1e-12 * t
        exact = _kernel_time(EXACT, rho, 0.0, z, hh, tt)
        # T jumps at z = 0 beyond the critical distance (z <= 0: the straight water
        # ray; z > 0: the refracted path, faster), so a cell straddling the interface
        # interpolates across the jump (tens of us): only cells below it are compared
        if tab.z0 + j * step > 0.0:
            assert abs(t - exact) <= 5e-6 + 2e-6 * abs(hh - h) / 0.1
