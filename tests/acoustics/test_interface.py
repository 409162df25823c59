"""Rayleigh reflection, transmission, Snell and Eckart: tables, theory and extremes."""

import math
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad

from sim_device.acoustics.interface import (band_limited_rms_roughness,
                                            coherent_reflection_coefficient, critical_angle,
                                            eckart_factor, reflection_coefficient,
                                            snell_grazing_angle, transmission_coefficient,
                                            transmitted_angle, vertical_wavenumber_ratio)

mpmath = pytest.importorskip("mpmath")

SAND = (1.845, 1.1782, 0.01624)   # TR 9407 rows (PHYSICS.md section 1)
SILT = (1.147, 0.9832, 0.00194)
DEG = np.radians


@pytest.fixture(autouse=True)
def _no_float_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with np.errstate(over="raise", divide="raise", invalid="raise", under="ignore"):
            yield


@pytest.mark.parametrize("medium,table", [
    (SAND, [0.9585, 0.9371, 0.8757, 0.4705, 0.3699]),
    (SILT, [0.1228, 0.0077, 0.0364, 0.0519, 0.0600]),
])
def test_reflection_magnitude_tables(medium, table):
    """PHYSICS.md section 2 (computed), 4 decimals."""
    r = np.abs(reflection_coefficient(DEG([10, 20, 30, 45, 90]), *medium))
    assert np.all(np.abs(r - table) <= 0.5e-4 + 1e-12)


def test_silt_has_near_zero_reflection_near_20_degrees():
    th = DEG(np.linspace(15, 25, 1001))
    r = np.abs(reflection_coefficient(th, *SILT))
    assert 18.5 < np.degrees(th[np.argmin(r)]) < 21.0 and r.min() < 0.01


def test_critical_angle():
    assert math.degrees(float(critical_angle(1.1782))) == pytest.approx(31.92, abs=0.005)
    assert np.isnan(critical_angle(0.9832))          # slow sediment: none
    np.testing.assert_allclose(critical_angle(np.array([1.5, 2.0])),
                               np.arccos([1 / 1.5, 0.5]))


def _r_mp(theta, rho, nu, delta):
    """Reference R with 50-digit arithmetic (mpmath), same branch Im P >= 0."""
    mpmath.mp.dps = 50
    th = mpmath.mpf(theta)
    kap = (1 + 1j * mpmath.mpf(delta)) / mpmath.mpf(nu)
    p = mpmath.sqrt(kap**2 - mpmath.cos(th) ** 2)
    if mpmath.im(p) < 0:
        p = -p
    a = mpmath.mpf(rho) * mpmath.sin(th)
    return complex((a - p) / (a + p))


@pytest.mark.parametrize("medium", [SAND, SILT, (1.845, 1.1782, 0.0), (2.0, 1.3, 0.5)])
def test_reflection_matches_high_precision_reference(medium):
    thc = math.acos(1 / medium[1]) if medium[1] > 1 else 0.3
    th = np.concatenate([DEG(np.linspace(0, 90, 37)),
                         thc + np.array([-1e-6, -1e-9, 0.0, 1e-9, 1e-6])])
    th = np.clip(th, 0, np.pi / 2)
    r = reflection_coefficient(th, *medium)
    ref = np.array([_r_mp(float(t), *medium) for t in th])
    err = np.abs(r - ref)
    # Lossless and within 1e-6 rad of θc the problem itself is ill-conditioned
    # (dR/dθ → ∞): rounding of κ² − cos²θ (~1e-16) becomes ~1e-8 in P. Elsewhere, and for
    # any δ > 0, double precision is kept.
    near = (np.abs(th - thc) <= 1e-6) & (medium[2] == 0)
    assert np.max(err[~near]) < 1e-12
    assert np.max(err, initial=0.0) < 1e-7


def test_grazing_zero_and_normal_incidence():
    rho, nu, _ = SAND
    # lossless: |R(0)| = 1 exactly (R = -1), for fast and slow sediments
    for n in (nu, 0.9832):
        r0 = reflection_coefficient(0.0, rho, n, 0.0)
        assert r0 == pytest.approx(-1.0, abs=1e-15)
    # lossy: finite, |R| <= 1
    r0 = reflection_coefficient(0.0, *SAND)
    assert np.isfinite(r0) and abs(r0) <= 1.0
    # normal incidence, lossless: (rho nu - 1)/(rho nu + 1)
    r90 = reflection_coefficient(np.pi / 2, rho, nu, 0.0)
    assert complex(r90) == pytest.approx((rho * nu - 1) / (rho * nu + 1), abs=1e-15)
    # the one 0/0 point: lossless nu = 1 at grazing takes its limit (rho-1)/(rho+1)
    assert complex(reflection_coefficient(0.0, 1.5, 1.0, 0.0)) == pytest.approx(0.2)
    assert complex(reflection_coefficient(1e-3, 1.5, 1.0, 0.0)) == pytest.approx(0.2)


def test_lossless_total_reflection_below_critical_angle():
    rho, nu, _ = SAND
    thc = float(critical_angle(nu))
    th = np.linspace(0, thc, 200)
    np.testing.assert_allclose(np.abs(reflection_coefficient(th, rho, nu, 0.0)), 1.0,
                               atol=1e-14)
    assert np.all(np.abs(reflection_coefficient(th[1:], *SAND)) < 1.0)


def test_continuity_through_the_critical_angle():
    """R has an infinite slope at θc (P → 0) but no jump and no NaN."""
    rho, nu, delta = SAND
    thc = float(critical_angle(nu))
    for d in (0.0, delta):
        th = thc + np.linspace(-1e-3, 1e-3, 20001)
        r = reflection_coefficient(th, rho, nu, d)
        assert np.all(np.isfinite(r))
        assert np.max(np.abs(np.diff(r))) < 2e-3     # steps of 1e-7 rad: |ΔR| ~ √Δθ
        assert abs(complex(reflection_coefficient(thc, rho, nu, d))) <= 1.0


def test_energy_conservation_lossless_above_critical():
    """|R|² + (ρ_w c_w / ρ_s c_s)(sinθt / sinθ)|T|² = 1 (normal energy flux), with θt from
    Snell's law computed independently of P."""
    rho, nu, _ = SAND
    thc = float(critical_angle(nu))
    th = np.linspace(thc + 1e-6, np.pi / 2, 500)
    r = reflection_coefficient(th, rho, nu, 0.0)
    t = transmission_coefficient(th, rho, nu, 0.0)
    sin_t = np.sqrt(1 - (nu * np.cos(th)) ** 2)
    flux = np.abs(r) ** 2 + (1 / (rho * nu)) * (sin_t / np.sin(th)) * np.abs(t) ** 2
    np.testing.assert_allclose(flux, 1.0, atol=1e-12)
    np.testing.assert_allclose(t, 1 + r, atol=0)
    # slow sediment (no critical angle): conserved at every grazing angle > 0
    rho, nu, _ = SILT
    th = np.linspace(1e-4, np.pi / 2, 500)
    r = reflection_coefficient(th, rho, nu, 0.0)
    t = transmission_coefficient(th, rho, nu, 0.0)
    sin_t = np.sqrt(1 - (nu * np.cos(th)) ** 2)
    flux = np.abs(r) ** 2 + (1 / (rho * nu)) * (sin_t / np.sin(th)) * np.abs(t) ** 2
    np.testing.assert_allclose(flux, 1.0, atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(theta=st.floats(0, np.pi / 2), rho=st.floats(0.3, 5), nu=st.floats(0.3, 4),
       delta=st.floats(0, 20))
def test_reflection_bounded_and_finite(theta, rho, nu, delta):
    r = complex(reflection_coefficient(theta, rho, nu, delta))
    assert math.isfinite(r.real) and math.isfinite(r.imag)
    assert abs(r) <= 1.0 + 1e-12
    p = complex(vertical_wavenumber_ratio(theta, nu, delta))
    assert p.imag >= 0.0


def test_very_high_attenuation_is_finite():
    th = np.linspace(0, np.pi / 2, 91)
    for delta in (1.0, 1e3, 1e8):
        r = reflection_coefficient(th, 1.8, 1.2, delta)
        assert np.all(np.isfinite(r)) and np.all(np.abs(r) <= 1.0)


def test_rejects_bad_angles_and_media():
    with pytest.raises(ValueError):
        reflection_coefficient(-0.1, *SAND)
    with pytest.raises(ValueError):
        reflection_coefficient(2.0, *SAND)
    with pytest.raises(ValueError):
        reflection_coefficient(0.3, 1.8, 1.2, -0.01)
    # rounding just outside [0, π/2] is accepted
    assert np.isfinite(reflection_coefficient(np.pi / 2 + 1e-12, *SAND))


def test_transmitted_angle_is_snell():
    rho, nu, _ = SAND
    thc = float(critical_angle(nu))
    th = np.linspace(thc + 1e-3, np.pi / 2, 50)
    tt = transmitted_angle(th, nu, 0.0)
    np.testing.assert_allclose(tt.real, np.arccos(nu * np.cos(th)), atol=1e-12)
    np.testing.assert_allclose(tt.imag, 0.0, atol=1e-12)
    # below θc: evanescent, a purely imaginary angle with cos θt = ν cos θ
    th = np.linspace(0, thc - 1e-3, 50)
    tt = transmitted_angle(th, nu, 0.0)
    np.testing.assert_allclose(tt.real, 0.0, atol=1e-12)
    np.testing.assert_allclose(np.cos(tt), nu * np.cos(th), rtol=1e-12)
    # lossy: cos θt = cos θ / κ exactly
    tt = transmitted_angle(th, nu, 0.05)
    np.testing.assert_allclose(np.cos(tt), np.cos(th) * nu / (1 + 0.05j), rtol=1e-12)


def test_snell_both_directions():
    c_w, c_s = 1500.0, 1767.0
    th_s = np.linspace(0, np.pi / 2, 20)            # from a buried point upward
    th_w = snell_grazing_angle(th_s, c_s, c_w)
    assert np.all(np.abs(th_w.imag) < 1e-12)        # always reaches the water (fast sediment)
    assert np.all(th_w.real >= float(critical_angle(c_s / c_w)) - 1e-12)
    back = snell_grazing_angle(th_w.real, c_w, c_s)
    np.testing.assert_allclose(back.real, th_s, atol=1e-7)
    evan = snell_grazing_angle(0.1, c_w, c_s)       # below θc: imaginary angle
    assert abs(evan.real) < 1e-12 and evan.imag > 0
    assert complex(np.cos(evan)) == pytest.approx(math.cos(0.1) * c_s / c_w)


def test_eckart():
    rho, nu, delta = SAND
    th = DEG(np.array([0, 10, 30, 60, 90]))
    f, h, c = 27.5e3, 0.01, 1500.0
    r = reflection_coefficient(th, rho, nu, delta)
    np.testing.assert_array_equal(coherent_reflection_coefficient(th, f, rho, nu, delta, 0.0, c),
                                  r)
    k = 2 * np.pi * f / c
    expected = r * np.exp(-2 * k**2 * h**2 * np.sin(th) ** 2)
    np.testing.assert_allclose(coherent_reflection_coefficient(th, f, rho, nu, delta, h, c),
                               expected, rtol=1e-14)
    # normal incidence at 27.5 kHz with 1 cm: 2(kh)² = 2.65 → about −23 dB of coherent loss
    loss_db = 20 * np.log10(float(eckart_factor(np.pi / 2, f, h, c)))
    assert loss_db == pytest.approx(-20 * 2 * (k * h) ** 2 / math.log(10), rel=1e-12)
    assert -23.1 < loss_db < -23.0
    assert float(eckart_factor(0.0, f, h, c)) == 1.0


def test_band_limited_roughness_against_quadrature():
    w2, g, kmin = 1.41e-4, 3.25, 2 * np.pi / 10.0    # features up to 10 m
    h = float(band_limited_rms_roughness(w2, g, kmin))
    num, _ = quad(lambda K: 2 * np.pi * K * w2 * K ** -g, kmin, np.inf)
    assert h == pytest.approx(math.sqrt(num), rel=1e-8)
    assert h == pytest.approx(math.sqrt(2 * np.pi * w2 * kmin ** (2 - g) / (g - 2)), rel=1e-14)
    h2 = float(band_limited_rms_roughness(w2, g, kmin, 100.0))
    num2, _ = quad(lambda K: 2 * np.pi * K * w2 * K ** -g, kmin, 100.0)
    assert h2 == pytest.approx(math.sqrt(num2), rel=1e-8)
    # γ = 2 (logarithmic) with a finite band
    h3 = float(band_limited_rms_roughness(1e-4, 2.0, 1.0, 10.0))
    assert h3 == pytest.approx(math.sqrt(2 * np.pi * 1e-4 * math.log(10.0)), rel=1e-12)
    with pytest.raises(ValueError):
        band_limited_rms_roughness(1e-4, 2.0, 1.0)        # diverges
    assert float(band_limited_rms_roughness(0.0, 3.25, kmin)) == 0.0
