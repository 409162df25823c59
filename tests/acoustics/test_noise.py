"""Knudsen ambient noise (Urick's tabulation, PHYSICS.md section 7)."""

import math

import numpy as np
import pytest
from scipy.integrate import quad

from sim_device.acoustics.ambient_noise import (ambient_noise_spectrum_level, band_noise_level,
                                        band_noise_power, band_noise_rms_pressure,
                                        knudsen_level_1khz, thermal_noise_spectrum_level,
                                        white_noise_rms_per_sample)


def test_sea_state_3_values():
    """64.5 dB at 1 kHz, −17 dB/decade: 47.5, 42.4, 39.4, 37.3 dB at 10–40 kHz."""
    nl = ambient_noise_spectrum_level(np.array([10e3, 20e3, 30e3, 40e3]), 3)
    assert np.all(np.abs(nl - [47.5, 42.4, 39.4, 37.3]) <= 0.05 + 1e-9)


def test_anchors_and_slope():
    for ss, level in zip(range(5), [44.5, 55.0, 61.5, 64.5, 66.5]):
        assert float(ambient_noise_spectrum_level(1e3, ss)) == pytest.approx(level, abs=1e-12)
    f = np.geomspace(1e3, 1e5, 9)
    nl = ambient_noise_spectrum_level(f, 2)
    np.testing.assert_allclose(np.diff(nl) / np.diff(np.log10(f)), -17.0, rtol=1e-12)


def test_fractional_sea_state_is_linear_in_db():
    assert float(knudsen_level_1khz(2.5)) == pytest.approx((61.5 + 64.5) / 2)
    assert float(knudsen_level_1khz(0.25)) == pytest.approx(44.5 + 0.25 * 10.5)
    ss = np.linspace(0, 4, 41)
    assert np.all(np.diff(knudsen_level_1khz(ss)) > 0)
    for bad in (-0.1, 4.5, float("nan")):
        with pytest.raises(ValueError):
            knudsen_level_1khz(bad)


def test_band_power_against_quadrature():
    for ss in (0, 3, 3.7):
        for thermal in (False, True):
            num, _ = quad(lambda f: 10 ** (float(ambient_noise_spectrum_level(
                f, ss, include_thermal=thermal)) / 10), 20e3, 35e3, epsrel=1e-12)
            assert float(band_noise_power(20e3, 35e3, ss, thermal)) == pytest.approx(num,
                                                                                  rel=1e-10)
    lvl = float(band_noise_level(20e3, 35e3, 3))
    assert lvl == pytest.approx(10 * math.log10(float(band_noise_power(20e3, 35e3, 3))))
    # a narrow band is spectrum level + 10 log10(bandwidth)
    assert float(band_noise_level(27.4e3, 27.6e3, 3)) == pytest.approx(
        float(ambient_noise_spectrum_level(27.5e3, 3)) + 10 * math.log10(200.0), abs=1e-3)
    assert float(band_noise_rms_pressure(20e3, 35e3, 3)) == pytest.approx(
        math.sqrt(float(band_noise_power(20e3, 35e3, 3))) * 1e-6)


def test_thermal_noise():
    assert float(thermal_noise_spectrum_level(1e3)) == -15.0
    assert float(thermal_noise_spectrum_level(100e3)) == pytest.approx(25.0)
    # it matters at sea state 0 above ~30 kHz, not at sea state 3 at 27.5 kHz
    assert float(ambient_noise_spectrum_level(100e3, 0, include_thermal=True)) > 25.0
    d = ambient_noise_spectrum_level(27.5e3, 3, True) - ambient_noise_spectrum_level(27.5e3, 3)
    assert 0 < float(d) < 0.2


def test_white_noise_per_sample_gives_the_band_power():
    """Draw white Gaussian samples at the digitiser rate with the returned rms, keep only
    20–35 kHz: the kept power equals the Knudsen band power (to the sampling error)."""
    fs, f1, f2, ss = 125e3, 20e3, 35e3, 3
    sigma = float(white_noise_rms_per_sample(f1, f2, fs, ss))
    band = float(band_noise_rms_pressure(f1, f2, ss))
    assert sigma == pytest.approx(band * math.sqrt(fs / 2 / (f2 - f1)), rel=1e-12)
    rng = np.random.default_rng(1234)
    n = 1 << 18
    x = rng.normal(0.0, sigma, n)
    spec = np.fft.rfft(x)
    freqs = np.fft.rfftfreq(n, 1 / fs)
    keep = (freqs >= f1) & (freqs <= f2)
    power_in_band = 2 * np.sum(np.abs(spec[keep]) ** 2) / n**2
    assert power_in_band == pytest.approx(band**2, rel=0.02)
    with pytest.raises(ValueError):
        white_noise_rms_per_sample(20e3, 70e3, fs, ss)
