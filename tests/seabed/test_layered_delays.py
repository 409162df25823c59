"""The imager's layered travel times (:func:`svss_proc.imaging.delays.layered_ray`)
against Fermat's principle computed independently: the total time minimised directly
over the horizontal positions where the ray crosses each boundary (high precision,
no ray parameter, no Snell), through the seed's sediments, at the extremes (zero offset,
grazing rays past the critical angle of a fast layer, a point on a boundary, just below
the interface, a thin layer, a deep point far off to the side)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import minimize

from svss_proc.imaging.delays import (SpeedProfile, build_table, height_curvature,
                                      layered_ray, one_way_time, vertical_slowness)

CW = 1500.0


def fermat_time(h, rho, z, tops, speeds):
    """Least travel time over the crossing points, minimised directly (BFGS on the
    crossing offsets, then Nelder-Mead polish, float64)."""
    ext, c = [h], [CW]
    for k, top in enumerate(tops):
        if z <= top:
            break
        bottom = tops[k + 1] if k + 1 < len(tops) else math.inf
        ext.append(min(z, bottom) - top)
        c.append(speeds[k])
    ext, c = np.array(ext), np.array(c)
    if ext.size == 1:
        return math.hypot(rho, h + z) / CW

    def total(x):
        xs = np.concatenate([[0.0], x, [rho]])
        return float(np.sum(np.sqrt(np.diff(xs) ** 2 + ext ** 2) / c))

    x0 = rho * np.cumsum(ext)[:-1] / ext.sum()
    r = minimize(total, x0, method="BFGS", options={"gtol": 1e-16, "maxiter": 10000})
    r = minimize(total, r.x, method="Nelder-Mead",
                 options={"xatol": 1e-13, "fatol": 1e-18, "maxiter": 20000})
    return r.fun


SILT_OVER_SAND = (np.array([0.0, 0.5]), np.array([1476.0, 1767.0]))
SAND_OVER_SILT = (np.array([0.0, 0.3]), np.array([1767.0, 1476.0]))
THREE = (np.array([0.0, 0.02, 0.6]), np.array([1476.0, 1900.0, 1650.0]))


@pytest.mark.parametrize("profile", [SILT_OVER_SAND, SAND_OVER_SILT, THREE],
                         ids=["silt/sand", "sand/silt", "thin fast layer"])
@pytest.mark.parametrize("h, rho, z", [
    (2.0, 0.0, 1.2),          # normal incidence
    (2.0, 0.7, 0.3),          # in the top layer
    (2.0, 1.3, 1.2),          # below the boundary
    (2.0, 1.0, 0.5),          # on the boundary
    (2.0, 0.9, 1e-6),         # just below the interface
    (1.5, 8.0, 1.9),          # grazing in the water, past the critical angle of a fast layer
    (2.5, 30.0, 0.8),         # far off to the side
    (0.3, 0.05, 2.0),         # low array, deep point
])
def test_layered_times_match_direct_fermat_minimisation(profile, h, rho, z):
    tops, speeds = profile
    t, eta, kappa = layered_ray(h, rho, z, CW, tops, speeds)
    ref = fermat_time(h, rho, z, tops, speeds)
    assert abs(t - ref) <= 1e-13 + 2e-11 * ref, (t, ref)
    # eta is dT/dh: a central difference of the independent minimum
    d = 1e-4
    up, down = (fermat_time(h + s, rho, z, tops, speeds) for s in (d, -d))
    assert abs(eta - (up - down) / (2 * d)) < 1e-8 / CW
    # kappa is d^2T/dh^2: a second difference of it over 2 cm
    d2 = 1e-2
    up, down = (fermat_time(h + s, rho, z, tops, speeds) for s in (d2, -d2))
    num = (up - 2 * ref + down) / d2 ** 2
    assert abs(kappa - num) <= 1e-3 * abs(num) + 1e-9 / CW, (kappa, num)


def test_one_layer_is_the_half_space_solver():
    tops, speeds = np.array([0.0]), np.array([1767.0])
    rng = np.random.default_rng(46)
    for _ in range(300):
        h, rho, z = rng.uniform(0.3, 4), rng.uniform(0, 20), rng.uniform(-0.5, 3)
        t, eta, kappa = layered_ray(h, rho, z, CW, tops, speeds)
        assert abs(t - one_way_time(h, rho, z, CW, 1767.0)) < 1e-15 + 1e-12 * t
        # the half-space solver stops at 1e-10 m of its crossing: eta to first order
        assert abs(eta - vertical_slowness(h, rho, z, CW, 1767.0)) < 1e-9 / CW
        assert abs(kappa - height_curvature(h, rho, z, CW, 1767.0)) <= (
            1e-6 * abs(kappa) + 1e-12 / CW)


def test_layer_of_the_half_space_speed_changes_nothing():
    """A 'layer' as fast as the half-space below it is no boundary at all."""
    one = (np.array([0.0]), np.array([1767.0]))
    two = (np.array([0.0, 0.4]), np.array([1767.0, 1767.0]))
    for h, rho, z in [(2.0, 0.3, 1.1), (2.0, 6.0, 0.4), (1.0, 0.0, 0.41)]:
        assert layered_ray(h, rho, z, CW, *two)[0] == pytest.approx(
            layered_ray(h, rho, z, CW, *one)[0], rel=1e-13)


def test_table_through_layers_holds_the_layered_times():
    """build_table with a layered profile: every node is layered_ray's time, and the
    same profile without layers gives the half-space table bit for bit."""
    prof = SpeedProfile((0.0, 0.5), (1476.0, 1767.0))
    tab = build_table(2.0, 4.0, -0.02, 2.02, 0.01, CW, 1767.0, prof)
    tops, speeds = np.array(prof.tops), np.array(prof.speeds)
    for i, j in [(0, 0), (0, 100), (37, 51), (150, 52), (399, 203), (250, 2)]:
        t, e, k = layered_ray(2.0, i * 0.01, -0.02 + j * 0.01, CW, tops, speeds)
        assert tab.time[i, j] == pytest.approx(t, rel=1e-14)
        assert tab.eta[i, j] == pytest.approx(e, rel=1e-12)
        assert tab.kappa[i, j] == pytest.approx(k, rel=1e-12, abs=1e-18)
    half = build_table(2.0, 4.0, -0.02, 2.02, 0.01, CW, 1767.0)
    same = build_table(2.0, 4.0, -0.02, 2.02, 0.01, CW, 1500.0,
                       SpeedProfile((0.0,), (1767.0,)))
    assert np.array_equal(half.time, same.time) and np.array_equal(half.eta, same.eta)
    assert np.allclose(half.kappa, same.kappa, rtol=1e-6, atol=1e-15)
