"""Rays through layered fluids against Fermat's principle, Snell's law, ray-tube spreading
and the imager's own two-medium solver; extremes: normal incidence, zero offset, grazing
rays just below a fast sediment's interface, vanishing layers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_device.acoustics import reflection_coefficient
from sim_device.layered_rays import (leg_extents, ray_tan, ray_terms, reflection,
                                   solve_leg, table_ray_tan, two_medium_table)
from sim_device.synthesis import ray_amplitude_terms, two_medium_terms
from tests.references import layered_time

C_W = 1500.0
SAND, SILT = 1767.0, 1476.0


def solve(rho, h, c, src=0):
    h = np.asarray(h, float)
    c = np.asarray(c, float)
    t = ray_tan(rho, h, c, h.size)
    return ray_terms(t, rho, h, c, h.size, src), t


@pytest.mark.parametrize("c1", [SAND, SILT, 3000.0, 1000.0])
@pytest.mark.parametrize("rho, h0, h1", [(0.0, 2.0, 1.0), (0.3, 2.0, 1.0), (1.7, 2.0, 0.4),
                                         (4.0, 2.0, 3.0), (9.0, 1.0, 0.05),
                                         (2.0, 2.0, 1e-9), (2.0, 1e-9, 1.0)])
def test_travel_time_is_fermats_least_time(c1, rho, h0, h1):
    (p, tau, spread, cos0), t = solve(rho, [h0, h1], [C_W, c1])
    assert tau == pytest.approx(layered_time(rho, [h0, h1], [C_W, c1]), rel=1e-11, abs=1e-15)
    # Snell: sin(phi_i)/c_i is the same in both media; t = tan(phi) of the faster one
    cmax = max(C_W, c1)
    tan = [r * t / math.sqrt(1 + t * t * (1 - r * r)) for r in (C_W / cmax, c1 / cmax)]
    sin = [x / math.hypot(1.0, x) for x in tan]
    assert sin[0] / C_W == pytest.approx(sin[1] / c1, rel=1e-12)
    assert h0 * tan[0] + h1 * tan[1] == pytest.approx(rho, abs=1e-9 * (1 + rho))
    assert p == pytest.approx(sin[0] / C_W, rel=1e-12)
    assert cos0 == pytest.approx(1.0 / math.hypot(1.0, tan[0]), rel=1e-12)


def test_three_media_and_deep_layer_extents():
    c = np.array([C_W, SILT, 1800.0])
    z_top = np.array([-np.inf, 0.0, 1.0])
    h = np.zeros(3)
    n = leg_extents(2.0, 1.6, 2, z_top, h)
    assert n == 3 and np.allclose(h, [2.0, 1.0, 0.6])
    (p, tau, *_), _ = solve(1.3, h, c)
    assert tau == pytest.approx(layered_time(1.3, h, c), rel=1e-9)
    # a point in the water: one straight leg whatever its side of the element
    assert leg_extents(2.0, -0.5, 0, z_top, h) == 1 and h[0] == 1.5
    assert leg_extents(2.0, -3.0, 0, z_top, h) == 1 and h[0] == 1.0


def test_fast_sediment_rays_reach_the_water_above_the_critical_angle():
    # PHYSICS.md section 2: from a buried point in sand the ray always reaches the water
    # above theta_c (grazing), i.e. p < 1/c_sand, even for huge offsets just below the
    # interface, and the solve stays finite and accurate there (no Newton steps).
    crit = math.acos(C_W / SAND)
    for rho in (1.0, 10.0, 100.0, 1e4):
        (p, tau, spread, cos0), t = solve(rho, [2.0, 1e-6], [C_W, SAND])
        assert p <= 1.0 / SAND and math.isfinite(t)
        sin_w = (C_W / SAND) * t / math.sqrt(1 + t * t)       # sin(phi_w) = nu^-1 sin(phi_s)
        grazing = math.pi / 2 - math.asin(sin_w)
        assert grazing >= crit - 1e-12
        assert math.isfinite(tau) and math.isfinite(spread) and spread > 0
        assert tau == pytest.approx(layered_time(rho, [2.0, 1e-6], [C_W, SAND]), rel=1e-10)


def test_zero_offset_and_vanishing_extents():
    (p, tau, spread, cos0), t = solve(0.0, [2.0, 1.0], [C_W, SAND])
    assert p == 0.0 and t == 0.0 and cos0 == 1.0
    assert tau == pytest.approx(2.0 / C_W + 1.0 / SAND, rel=1e-15)
    # normal-incidence spreading of a source in water: 1 / (h0 + h1 c1/c0)
    assert spread == pytest.approx(1.0 / (2.0 + 1.0 * SAND / C_W), rel=1e-12)
    # homogeneous: 1/r whatever the split of one medium into two
    (p, tau, spread, _), _ = solve(1.2, [1.5, 0.7], [C_W, C_W])
    r = math.hypot(1.2, 2.2)
    assert tau == pytest.approx(r / C_W, rel=1e-13)
    assert spread == pytest.approx(1.0 / r, rel=1e-12)


@pytest.mark.parametrize("c1", [SAND, SILT])
@pytest.mark.parametrize("src", [0, 1])
def test_spreading_matches_a_numerical_ray_tube(c1, src):
    # |p_r / P_s|^2 = |T|^2 sin(phi_s) / (rho cos(phi_s) d rho / d phi_s) from energy
    # conservation in a ray tube; here without |T|^2, d rho / d phi_s by finite differences
    h0, h1, rho = 2.0, 0.8, 1.1
    c = np.array([C_W, c1])
    h = np.array([h0, h1])
    (p, tau, spread, _), _ = solve(rho, h, c, src)

    def offset(phi_s):
        s = math.sin(phi_s) / c[src]
        return sum(hi * s * ci / math.sqrt(1 - (s * ci) ** 2) for hi, ci in zip(h, c))

    phi = math.asin(p * c[src])
    d = 1e-6
    drho = (offset(phi + d) - offset(phi - d)) / (2 * d)
    expect = math.sqrt(math.sin(phi) / (rho * math.cos(phi) * drho))
    assert spread == pytest.approx(expect, rel=1e-6)


@pytest.mark.parametrize("c1", [SAND, SILT, 2500.0, 1200.0])
def test_two_medium_table_agrees_with_brent(c1):
    tab = two_medium_table(C_W, c1)
    rng = np.random.default_rng(7)
    n = 4000
    h0 = rng.uniform(0.05, 8.0, n)
    h1 = rng.uniform(0.0, 1.0, n) ** 3 * 6.0 + 1e-9
    rho = rng.uniform(0.0, 1.0, n) ** 2 * 12.0
    hb, cb = np.empty(2), np.empty(2)
    c = np.array([C_W, c1])
    worst = 0.0
    for k in range(n):
        h = np.array([h0[k], h1[k]])
        t_tab = table_ray_tan(rho[k], h0[k], h1[k], C_W, c1, tab, hb, cb)
        t_ref = ray_tan(rho[k], h, c, 2)
        tau_tab = ray_terms(t_tab, rho[k], h, c, 2, 0)[1]
        tau_ref = ray_terms(t_ref, rho[k], h, c, 2, 0)[1]
        worst = max(worst, abs(tau_tab - tau_ref))
    # travel time exact to far below a thousandth of a period (36 us)
    assert worst < 1e-10


def test_two_medium_terms_equal_the_general_terms():
    c = np.array([C_W, SAND])
    alpha = np.array([1e-4, 1.59])
    for rho, h0, h1, src in [(0.0, 2.0, 1.0, 0), (1.3, 2.0, 0.5, 1), (3.0, 7.0, 2.0, 0)]:
        h = np.array([h0, h1])
        t = ray_tan(rho, h, c, 2)
        a = ray_amplitude_terms(t, rho, h, c, alpha, 2, src)
        b = two_medium_terms(t, rho, h0, h1, c[0], c[1], alpha[0], alpha[1], src)
        np.testing.assert_allclose(a, b, rtol=1e-12)
        # attenuation along the refracted path: alpha_i h_i / cos(phi_i)
        p = a[0]
        path = h0 / math.sqrt(1 - (p * c[0]) ** 2) * alpha[0] + h1 / math.sqrt(
            1 - (p * c[1]) ** 2) * alpha[1]
        assert a[4] == pytest.approx(path, rel=1e-12)


def test_agrees_with_the_imagers_refraction_solver():
    # one physics, two solvers: the imager's safeguarded two-medium Fermat solve
    from svss_proc.imaging.delays import one_way_time
    rng = np.random.default_rng(3)
    for _ in range(200):
        h, z, rho = rng.uniform(0.5, 4), rng.uniform(1e-3, 3), rng.uniform(0, 5)
        cs = rng.choice([SAND, SILT])
        ours = solve(rho, [h, z], [C_W, cs])[0][1]
        assert ours == pytest.approx(one_way_time(h, rho, z, C_W, cs), rel=1e-10)


@pytest.mark.parametrize("rho_r, nu, delta", [(1.845, 1.1782, 0.01624), (1.147, 0.9832, 0.00194),
                                               (1.845, 1.1782, 0.0), (1.0, 1.0, 0.0)])
def test_kernel_reflection_equals_the_acoustics_module(rho_r, nu, delta):
    theta = np.concatenate([np.linspace(0, np.pi / 2, 181),
                            [math.acos(1 / nu) if nu > 1 else 0.3]])
    ours = np.array([reflection(math.cos(t), rho_r, nu, delta) for t in theta])
    ref = reflection_coefficient(theta, rho_r, nu, delta)
    np.testing.assert_allclose(ours[:-1], ref[:-1], rtol=0, atol=1e-12)
    # at the critical angle itself P = sqrt(kappa^2 - cos^2) takes the root of a rounding
    # residual (~1e-16), so the two forms may differ by sqrt(eps) ~ 1e-8 there
    np.testing.assert_allclose(ours[-1], ref[-1], rtol=0, atol=3e-8 if nu > 1 else 1e-12)


def test_solve_leg_wrapper():
    c = np.array([C_W, SAND])
    z_top = np.array([-np.inf, 0.0])
    out = solve_leg(1.0, 2.0, 1.0, 1, c, z_top)
    assert out["time"] == pytest.approx(layered_time(1.0, [2.0, 1.0], c), rel=1e-12)
    assert 0 < out["water_angle"] < math.atan2(1.0, 2.0)      # bent towards the normal
