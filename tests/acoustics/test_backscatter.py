"""APL-UW TR 9407 bottom backscatter: PHYSICS.md tables, theory, blend and extremes."""

import math
import warnings

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.special import erfc, gamma

from sim_device.acoustics.attenuation import sediment_attenuation_db_per_m
from sim_device.acoustics.backscatter import (BLEND_CENTRE, blend_weight, bottom_backscatter,
                                              composite_cutoff_wavenumber, kirchhoff_parameters,
                                              large_scale_slope_variance, shadowing_factor,
                                              sigma2_from_volume_strength, sigma_composite,
                                              sigma_interface, sigma_kirchhoff,
                                              sigma_perturbation, sigma_total, sigma_volume,
                                              volume_strength_from_sigma2)
from svss_daq.decibels import power_to_db
from sim_device.acoustics.interface import reflection_coefficient, vertical_wavenumber_ratio
from sim_device.acoustics.sediments import Sediment

C_W = 1500.0
F = 20e3
RHO, NU, DELTA = 1.845, 1.1782, 0.01624          # medium sand, TR 9407 row
W2, GAMMA = 1.406e-4, 3.25                       # PHYSICS.md section 4 case
SAND = (RHO, NU, DELTA, W2, GAMMA)
SILT = (1.147, 0.9832, 0.00194, 1.638e-5, 3.25)
ANGLES = np.radians([10, 20, 30, 45, 60, 80])


@pytest.fixture(autouse=True)
def _no_float_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with np.errstate(over="raise", divide="raise", invalid="raise", under="ignore"):
            yield


def _args(theta, medium=SAND, f=F):
    rho, nu, delta, w2, g = medium
    return (theta, f, rho, nu, delta, w2, g, C_W)


def test_intermediates():
    """C_h² = 1.571e-3, q_c = 3.659e-2, a = 1.689, b = 1.413 (PHYSICS.md, 4 figures)."""
    p = kirchhoff_parameters(F, W2, GAMMA, C_W)
    assert float(p.alpha) == 0.625
    assert float(p.ch2) == pytest.approx(1.571e-3, abs=0.5e-6)
    assert float(p.qc) == pytest.approx(3.659e-2, abs=0.5e-5)
    assert float(p.a) == pytest.approx(1.689, abs=0.5e-3)
    assert float(p.b) == pytest.approx(1.413, abs=0.5e-3)


def test_kirchhoff_constants_against_direct_gamma_expressions():
    """a and b from independent evaluation for other exponents (2 < γ < 4)."""
    for g in (2.5, 3.0, 3.5, 3.9):
        al = g / 2 - 1
        a = (8 * al**2 * gamma(1 / (2 * al) + 0.5)
             / (math.sqrt(math.pi) * gamma(1 / al) * gamma(1 / (2 * al)))) ** (2 * al)
        b = a ** ((1 + al) / (2 * al)) * gamma(1 / al) / (2 * al)
        p = kirchhoff_parameters(F, W2, g, C_W)
        assert float(p.a) == pytest.approx(a, rel=1e-13)
        assert float(p.b) == pytest.approx(b, rel=1e-13)
    # α = ½ (γ = 3): a = 2Γ(3/2)/(Γ(½)Γ(2)Γ(1)) = 1 and b = Γ(2) = 1 exactly
    p = kirchhoff_parameters(F, W2, 3.0, C_W)
    assert float(p.a) == pytest.approx(1.0, rel=1e-13)
    assert float(p.b) == pytest.approx(1.0, rel=1e-13)


# PHYSICS.md section 4 (computed), medium sand, 20 kHz, σ2 = 0.002; 0.1 dB rounding.
TABLE = {
    "pr": [-38.8, -30.8, -27.8, -29.3, -25.8, -11.7],
    "bv": [-43.6, -35.1, -29.6, -24.8, -24.0, -23.5],
    "kr": [-35.3, -34.6, -33.5, -30.6, -25.8, -11.7],
}


def test_perturbation_table():
    s = power_to_db(sigma_perturbation(*_args(ANGLES)))
    assert np.max(np.abs(s - TABLE["pr"])) <= 0.05 + 1e-9


def test_volume_table():
    s = power_to_db(sigma_volume(ANGLES, RHO, NU, DELTA, 0.002))
    assert np.max(np.abs(s - TABLE["bv"])) <= 0.05 + 1e-9


def test_kirchhoff_table_and_tail():
    s = power_to_db(sigma_kirchhoff(*_args(ANGLES)))
    assert np.max(np.abs(s - TABLE["kr"])) <= 0.05 + 1e-9
    tail = float(power_to_db(sigma_kirchhoff(*_args(np.radians(5.0)))))
    assert tail == pytest.approx(-35.0, abs=0.5)


def test_volume_term_equals_attenuation_form():
    """σ_bv = σ_v |1−R²|² sin²θ / (4 k |P|² Im P) with σ_v = σ2 α[dB/m]: the same physics
    written with the sediment attenuation, which fixes the 5δ/(ν ln10) constant."""
    th = np.radians(np.linspace(1, 90, 40))
    k = 2 * np.pi * F / C_W
    sv = 0.002 * sediment_attenuation_db_per_m(F, NU * C_W, DELTA)
    p = vertical_wavenumber_ratio(th, NU, DELTA)
    r = reflection_coefficient(th, RHO, NU, DELTA)
    ref = sv * np.abs(1 - r**2) ** 2 * np.sin(th) ** 2 / (4 * k * np.abs(p) ** 2 * p.imag)
    np.testing.assert_allclose(sigma_volume(th, RHO, NU, DELTA, 0.002), ref, rtol=1e-12)


def test_kirchhoff_and_perturbation_share_their_asymptote():
    """Away from normal, σ_kr → b q_c |R(90°)|²/(8π cos^γ θ) and σ_pr → the same with
    sin⁴θ|Y|² → |R(90°)|²: they agree within 1 dB over 60–80° (the blend's overlap)."""
    th = np.radians(np.linspace(60, 80, 11))
    d = power_to_db(sigma_kirchhoff(*_args(th))) - power_to_db(sigma_perturbation(*_args(th)))
    assert np.max(np.abs(d)) < 1.0
    d = (power_to_db(sigma_kirchhoff(*_args(th, SILT)))
         - power_to_db(sigma_perturbation(*_args(th, SILT))))
    assert np.max(np.abs(d)) < 1.0


def _composite_reference(theta, medium, f):
    """Independent evaluation of the documented composite form with scipy.quad."""
    rho, nu, delta, w2, g = medium
    k = 2 * np.pi * f / C_W
    kc = (8 * np.pi * w2 * k**2 / (g - 2)) ** (1 / (g - 2))
    s = math.sqrt(np.pi * w2 * kc ** (4 - g) / (4 - g))

    def small(thl):
        thl = np.pi / 2 - abs(np.pi / 2 - thl)
        if 2 * k * math.cos(thl) < kc or thl <= 0:
            return 0.0
        return float(sigma_perturbation(thl, f, rho, nu, delta, w2, g, C_W))

    def integrand(sp):
        return small(theta + math.atan(sp)) * math.exp(-0.5 * (sp / s) ** 2) / (
            math.sqrt(2 * math.pi) * s)

    thk = math.acos(kc / (2 * k))
    breaks = [math.tan(thk - theta)]
    if np.pi - thk - theta < np.pi / 2:
        breaks.append(math.tan(np.pi - thk - theta))
    lo = max(-math.tan(theta), -8 * s)
    pts = [b for b in breaks if lo < b < 8 * s]
    val, _ = quad(integrand, lo, 8 * s, points=pts or None, limit=400, epsabs=0, epsrel=1e-10)
    v = math.tan(theta) / (math.sqrt(2) * s)
    lam = 0.5 * (math.exp(-v * v) / (math.sqrt(math.pi) * v) - erfc(v))
    return val / (1 + lam)


@pytest.mark.parametrize("medium", [SAND, SILT])
@pytest.mark.parametrize("deg", [3.0, 10.0, 30.0, 60.0, 80.0, 89.0])
def test_composite_quadrature_matches_reference(medium, deg):
    th = math.radians(deg)
    got = float(sigma_composite(*_args(th, medium, 27.5e3)))
    ref = _composite_reference(th, medium, 27.5e3)
    assert got == pytest.approx(ref, rel=2e-3)      # 0.01 dB


def test_composite_is_slope_averaged_perturbation_at_moderate_angles():
    """Small large-scale slopes (≈ 3–4° rms for sand) change σ_pr by well under 1 dB
    at 20–45°, and shadowing removes everything at grazing incidence."""
    th = np.radians([20.0, 30.0, 45.0])
    d = power_to_db(sigma_composite(*_args(th))) - power_to_db(sigma_perturbation(*_args(th)))
    assert np.max(np.abs(d)) < 0.6
    assert float(sigma_composite(*_args(0.0))) == 0.0


def test_composite_split_and_slope():
    k = 2 * np.pi * F / C_W
    kc = float(composite_cutoff_wavenumber(F, W2, GAMMA, C_W))
    hs2 = 2 * np.pi * W2 * kc ** (2 - GAMMA) / (GAMMA - 2)
    assert 2 * k * math.sqrt(hs2) == pytest.approx(1.0, rel=1e-12)   # small-scale 2 k h = 1
    s2 = float(large_scale_slope_variance(W2, GAMMA, kc))
    ref, _ = quad(lambda K: np.pi * K**3 * W2 * K ** -GAMMA, 0, kc)     # ½∫∫ K² W d²K
    assert s2 == pytest.approx(ref, rel=1e-8)
    assert 2.0 < math.degrees(math.atan(math.sqrt(s2))) < 5.0


def test_shadowing_limits():
    s = 0.06
    assert float(shadowing_factor(0.0, s)) == 0.0
    assert float(shadowing_factor(np.pi / 2, s)) == 1.0
    assert float(shadowing_factor(0.3, 0.0)) == 1.0
    th = np.linspace(0, np.pi / 2, 200)
    sh = shadowing_factor(th, s)
    assert np.all(np.diff(sh) >= 0) and np.all((sh >= 0) & (sh <= 1))
    # low-angle limit: Λ ≈ 1/(2√π v) − ½ + O(v), so S ≈ 2√π v / (1 + √π v)
    v = math.tan(1e-4) / (math.sqrt(2) * s)
    sv = 2 * math.sqrt(math.pi) * v / (1 + math.sqrt(math.pi) * v)
    assert float(shadowing_factor(1e-4, s)) == pytest.approx(sv, rel=1e-5)


def test_blend_follows_composite_low_and_kirchhoff_high():
    low = np.radians([5.0, 10.0])
    br = sigma_interface(*_args(low))
    cr = sigma_composite(*_args(low))
    kr = sigma_kirchhoff(*_args(low))
    np.testing.assert_allclose(br, cr, rtol=1e-6)
    # not the σ_kr tail (−35.5, −35.3 dB): 9 dB below it at 5°, 2.4 dB at 10°
    assert np.all(power_to_db(br) < power_to_db(kr) - np.array([6.0, 1.5]))
    assert np.all(power_to_db(br) < np.array([-40.0, -37.0]))
    high = np.radians([80.0, 85.0, 89.0, 90.0])
    np.testing.assert_allclose(sigma_interface(*_args(high)), sigma_kirchhoff(*_args(high)),
                               rtol=1e-6)


def test_blend_is_smooth_through_its_centre():
    th = np.radians(np.linspace(55, 75, 401))
    for medium in (SAND, SILT):
        for f in (20e3, 35e3):
            br = power_to_db(sigma_interface(*_args(th, medium, f)))
            assert np.max(np.abs(np.diff(br))) < 0.1                 # 0.05° steps
            kr = power_to_db(sigma_kirchhoff(*_args(th, medium, f)))
            cr = power_to_db(sigma_composite(*_args(th, medium, f)))
            lo = np.minimum(kr, cr) - 1e-9
            hi = np.maximum(kr, cr) + 1e-9
            assert np.all((br >= lo) & (br <= hi))
    w = blend_weight(np.array([0.0, BLEND_CENTRE, np.pi / 2]))
    assert w[0] < 1e-30 and w[1] == pytest.approx(0.5) and w[2] > 1 - 1e-9


def test_zero_roughness():
    th = np.radians([0.0, 10.0, 45.0, 90.0])
    zero = (RHO, NU, DELTA, 0.0, GAMMA)
    for fn in (sigma_perturbation, sigma_kirchhoff, sigma_composite, sigma_interface):
        np.testing.assert_array_equal(fn(*_args(th, zero)), 0.0)


def test_exact_limits_finite():
    th = np.array([0.0, np.pi / 2])
    for medium in (SAND, SILT, (1.5, 1.0, 0.0, W2, GAMMA), (2.0, 1.3, 5.0, W2, GAMMA)):
        for fn in (sigma_perturbation, sigma_kirchhoff, sigma_composite, sigma_interface):
            v = fn(*_args(th, medium))
            assert np.all(np.isfinite(v)) and np.all(v >= 0)
        v = sigma_volume(th, *medium[:3], 0.001)
        assert np.all(np.isfinite(v)) and v[0] == 0.0
    assert float(sigma_perturbation(*_args(0.0))) == 0.0


def test_volume_lossless_limit_and_high_attenuation():
    th = np.radians(np.linspace(0, 90, 91))
    for rho, nu in ((RHO, NU), (1.147, 0.9832)):
        v0 = sigma_volume(th, rho, nu, 0.0, 0.002)
        v1 = sigma_volume(th, rho, nu, 1e-9, 0.002)
        assert np.all(np.isfinite(v0))
        # (below θc the lossy value is O(δ) → 0)
        np.testing.assert_allclose(v0, v1, rtol=1e-6, atol=1e-6 * v1.max())
    # below the critical angle a lossless fast sediment returns nothing from its volume
    assert np.all(sigma_volume(np.radians(np.linspace(0, 31), ), RHO, NU, 0.0, 0.002) == 0)
    big = sigma_volume(th, RHO, NU, 50.0, 0.002)
    assert np.all(np.isfinite(big)) and np.all(big >= 0)


def test_sigma2_from_volume_strength_matches_the_seed():
    """Seed: −20 dB/m in medium sand ↔ σ2 ≈ 0.001; −28.6 dB/m in very fine silt ↔ ≈ 0.001."""
    s2 = float(sigma2_from_volume_strength(-20.0, 20e3, 1767.0, DELTA))
    assert s2 == pytest.approx(1e-3, rel=0.01)
    s2 = float(sigma2_from_volume_strength(-28.6, 20e3, 1476.0, 0.00194))
    assert s2 == pytest.approx(1e-3, rel=0.05)
    back = volume_strength_from_sigma2(s2, 20e3, 1476.0, 0.00194)
    assert float(back) == pytest.approx(-28.6, abs=1e-10)


def test_total_and_sediment_wrapper():
    sand = Sediment("sand", 1845.0, 1767.0, DELTA, W2, GAMMA, 0.01, sigma2_value=0.002)
    th = np.radians(np.linspace(0, 90, 31))
    comp = bottom_backscatter(th, F, sand, 1000.0, C_W)
    rho, nu = 1.845, 1767.0 / C_W
    args = (th, F, rho, nu, DELTA, W2, GAMMA, C_W)
    np.testing.assert_allclose(comp.kirchhoff, sigma_kirchhoff(*args), rtol=1e-13)
    np.testing.assert_allclose(comp.interface, sigma_interface(*args), rtol=1e-13)
    np.testing.assert_allclose(comp.volume, sigma_volume(th, rho, nu, DELTA, 0.002), rtol=1e-13)
    np.testing.assert_allclose(comp.total, comp.interface + comp.volume, rtol=1e-15)
    np.testing.assert_allclose(sigma_total(th, F, rho, nu, DELTA, W2, GAMMA, 0.002, C_W),
                               comp.total, rtol=1e-13)


def test_broadcast_over_angle_and_frequency():
    th = np.radians(np.linspace(1, 90, 12))
    f = np.array([[20e3], [27.5e3], [35e3]])
    out = sigma_interface(th, f, RHO, NU, DELTA, W2, GAMMA, C_W)
    assert out.shape == (3, 12)
    for i in range(3):
        np.testing.assert_allclose(out[i], sigma_interface(th, float(f[i, 0]), RHO, NU, DELTA,
                                                           W2, GAMMA, C_W), rtol=1e-13)
    # roughness scales as k^(4−γ) away from normal: σ_pr ∝ f^0.75 at fixed angle
    pr = sigma_perturbation(np.radians(30.0), f[:, 0], RHO, NU, DELTA, W2, GAMMA, C_W)
    np.testing.assert_allclose(pr / pr[0], (f[:, 0] / 20e3) ** 0.75, rtol=1e-12)


def test_rejects_bad_spectrum():
    with pytest.raises(ValueError):
        sigma_kirchhoff(*_args(0.3, (RHO, NU, DELTA, W2, 4.0)))
    with pytest.raises(ValueError):
        sigma_perturbation(*_args(0.3, (RHO, NU, DELTA, -1e-4, GAMMA)))
