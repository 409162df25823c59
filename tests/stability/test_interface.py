"""Interface reflection and transmission at their extremes, against mpmath (50 digits):
grazing 0 and 90 degrees, exactly at and around the critical angle, lossless and
lossy (to a loss parameter of 10) sediments, density and speed ratios 1e-3 to 1e3."""

from __future__ import annotations

import math

import mpmath as mp
import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from sim_device.acoustics.interface import (
    band_limited_rms_roughness,
    critical_angle,
    eckart_factor,
    reflection_coefficient,
    snell_grazing_angle,
    transmission_coefficient,
    transmitted_angle,
)
from sim_device.layered_rays import reflection as ray_reflection

from ._sweep import sweep

mp.mp.dps = 50
HALF_PI = math.pi / 2

ratios = st.one_of(st.floats(0.2, 5.0), st.sampled_from([1.0, 1e-3, 1e3, 1.0 + 1e-12]))
losses = st.one_of(st.just(0.0), st.floats(1e-9, 1e-2), st.floats(1e-2, 10.0))


@st.composite
def grazing(draw, nu):
    """A grazing angle: anywhere, the ends, or at and around the critical angle."""
    kind = draw(st.sampled_from(["any", "ends", "critical"]))
    if kind == "ends":
        return draw(st.sampled_from([0.0, HALF_PI, 5e-324, 1e-300, HALF_PI - 1e-16]))
    if kind == "critical" and nu > 1.0:
        tc = math.acos(1.0 / nu)
        off = draw(st.sampled_from([0.0, 1e-15, -1e-15, 1e-9, -1e-9, 1e-6, -1e-6]))
        return min(max(tc + off, 0.0), HALF_PI)
    return draw(st.floats(0.0, HALF_PI))


def tolerance(theta, rho, nu, delta):
    """What rounding may cost R in double precision: kappa^2 - cos^2 (or its near-grazing
    form) carries an absolute error dA ~ 8 eps (|kappa|^2 + 1), so P is off by
    dA / 2|P| (sqrt(dA) where P itself is that small: at the critical angle), and R
    by |dR/dP| dP = 2 rho sin / |rho sin + P|^2 dP. Far from the critical angle this is
    ~1e-15; at a critical angle of 1e-6 rad it is ~1e-2."""
    kap = (1 + 1j * delta) / nu
    p = complex(mp.sqrt(mp.mpc(kap) ** 2 - 1 + mp.sin(mp.mpf(theta)) ** 2))
    da = 8 * 2.22e-16 * (abs(kap) ** 2 + 1)
    dp = da / (2 * abs(p)) if abs(p) ** 2 > da else math.sqrt(da)
    a = rho * math.sin(theta)
    den = abs(a + p) ** 2
    return 1e-12 + (min(2.0, 4 * (2 * a + abs(p)) * dp / den) if den > 0 else 2.0)


def r_mp(theta, rho, nu, delta):
    """R(theta) in 50 digits: P on the branch Im P >= 0 (Re P >= 0 where Im P = 0)."""
    th, rho, nu = mp.mpf(theta), mp.mpf(rho), mp.mpf(nu)
    kap = (1 + 1j * mp.mpf(delta)) / nu
    p = mp.sqrt(kap ** 2 - 1 + mp.sin(th) ** 2)     # = kappa^2 - cos^2, exactly
    if p.imag < 0 or (p.imag == 0 and p.real < 0):
        p = -p
    a = rho * mp.sin(th)
    if a + p == 0:
        return mp.mpc((rho - 1) / (rho + 1))
    return (a - p) / (a + p)


@sweep(150)
@given(st.data(), ratios, ratios, losses)
def test_reflection_matches_mpmath_and_is_bounded(data, rho, nu, delta):
    theta = data.draw(grazing(nu))
    r = complex(reflection_coefficient(theta, rho, nu, delta))
    t = complex(transmission_coefficient(theta, rho, nu, delta))
    ref = complex(r_mp(theta, rho, nu, delta))
    assert math.isfinite(r.real) and math.isfinite(r.imag)
    assert abs(r) <= 1.0 + 1e-12                     # no energy created, delta >= 0
    # kappa^2 - cos^2 cancels at the critical angle: R is as accurate as its condition
    tol = tolerance(theta, rho, nu, delta)
    assert abs(r - ref) <= tol, (theta, rho, nu, delta, r, ref, tol)
    assert abs(t - (1.0 + r)) <= 1e-15 and abs(t) <= 2.0 + 1e-12
    # the ray code's scalar version (numba, given cos(theta)) agrees with the numpy one
    q = math.cos(theta)
    rr = ray_reflection(q, rho, nu, delta)
    th_q = math.acos(q)
    # (cos theta as input fixes theta only to eps / sin theta: 1e-9 for that)
    assert abs(rr - complex(reflection_coefficient(th_q, rho, nu, delta))) <= 2 * tolerance(
        th_q, rho, nu, delta) + 1e-9


@sweep(40)
@given(ratios, ratios, losses)
def test_reflection_limits_at_grazing_and_normal_incidence(rho, nu, delta):
    kap = (1 + 1j * delta) / nu
    r0 = complex(reflection_coefficient(0.0, rho, nu, delta))
    r90 = complex(reflection_coefficient(HALF_PI, rho, nu, delta))
    assert abs(r90 - (rho - kap) / (rho + kap)) <= 1e-12   # normal incidence
    if abs(kap - 1.0) > 1e-6:
        assert abs(r0 + 1.0) <= 1e-12                       # grazing: R = -1
    assert abs(r0) <= 1.0 + 1e-12


@sweep(40)
@given(st.floats(1.0 + 1e-9, 5.0), ratios)
def test_total_reflection_below_the_critical_angle_of_a_lossless_sediment(nu, rho):
    tc = float(critical_angle(nu))
    assert 0.0 < tc < HALF_PI
    th = np.linspace(0.0, tc, 50)[:-1]         # at tc itself rounding decides
    assert np.allclose(np.abs(reflection_coefficient(th, rho, nu, 0.0)), 1.0, atol=1e-12)
    assert math.isnan(float(critical_angle(1.0 / nu)))       # slow sediment: none


@sweep(60)
@given(st.data(), st.floats(0.2, 5.0), losses)
def test_transmitted_angle_is_finite_and_obeys_snell(data, nu, delta):
    theta = data.draw(grazing(nu))
    tt = complex(transmitted_angle(theta, nu, delta))
    assert math.isfinite(tt.real) and math.isfinite(tt.imag)
    kap = (1 + 1j * delta) / nu
    # cos(theta_t) = cos(theta) / kappa (complex Snell)
    assert abs(complex(mp.cos(mp.mpc(tt))) - math.cos(theta) / kap) <= 1e-7 * (1 + abs(kap))
    s = complex(snell_grazing_angle(theta, 1500.0, 1500.0 * nu))
    assert math.isfinite(s.real) and math.isfinite(s.imag)
    assert abs(complex(mp.cos(mp.mpc(s))) - math.cos(theta) * nu) <= 1e-7 * (1 + nu)


@sweep(60)
@given(st.floats(0.0, HALF_PI), st.floats(1.0, 1e6), st.floats(0.0, 100.0))
def test_eckart_factor_bounded_for_any_roughness(theta, f, h):
    e = float(eckart_factor(theta, f, h, 1500.0))
    assert 0.0 <= e <= 1.0
    k = 2 * mp.pi * f / 1500
    assert abs(e - float(mp.exp(-2 * (k * h * mp.sin(theta)) ** 2))) <= 1e-12


@sweep(80)
@given(st.one_of(st.floats(2.0 + 1e-15, 3.99), st.floats(1.2, 2.0 - 1e-15),
                 st.sampled_from([2.0, 2.0 + 1e-13, 2.0 - 1e-11, 2.0 + 1e-9])),
       st.floats(1e-6, 10.0), st.floats(10.0, 1e6), st.floats(1e-8, 1.0))
def test_band_limited_roughness_continuous_through_gamma_two(g, kmin, ratio, w2):
    """Regression: (K_min^e - K_max^e)/-e lost 7 digits at gamma = 2 + 1e-11."""
    kmax = kmin * ratio
    h = float(band_limited_rms_roughness(w2, g, kmin, kmax))
    e = 2 - mp.mpf(g)
    span = mp.log(mp.mpf(kmax) / mp.mpf(kmin))
    power = span if e == 0 else (mp.mpf(kmin) ** e - mp.mpf(kmax) ** e) / -e
    assert abs(h / float(mp.sqrt(2 * mp.pi * w2 * power)) - 1.0) <= 1e-12
    if g > 2.0:                                        # the unbounded band converges
        hinf = float(band_limited_rms_roughness(w2, g, kmin, np.inf))
        assert math.isfinite(hinf) and hinf >= h * (1 - 1e-12)
