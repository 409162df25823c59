"""Ambient noise: Knudsen spectra by sea state (as tabulated by Urick), PHYSICS.md section 7.

Spectrum level NL(f) = NL_1k(SS) − 17 log10(f / 1 kHz)  dB re 1 µPa²/Hz, with
NL_1k = 44.5, 55, 61.5, 64.5, 66.5 dB for sea states 0, 1, 2, 3, 4. Fractional sea states
are interpolated linearly in dB between these anchors (a convenience of this module, not
Knudsen's); sea states outside 0…4 are rejected. The Knudsen curves describe wind/wave
noise from about 0.5 to 25–50 kHz; above that molecular thermal noise,
NL_th = −15 + 20 log10(f/1 kHz) dB re 1 µPa²/Hz (Mellen 1952), may be added with
``include_thermal=True``.

Band quantities integrate the spectral density exactly (power law). The per-sample rms of
a white sequence is for a simulator that draws independent Gaussian samples at the
digitiser rate: white noise at rate fs with one-sided density N has variance N·fs/2.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from svss_daq.decibels import power_to_db

__all__ = [
    "KNUDSEN_LEVEL_1KHZ",
    "KNUDSEN_SLOPE_DB_PER_DECADE",
    "knudsen_level_1khz",
    "ambient_noise_spectrum_level",
    "thermal_noise_spectrum_level",
    "band_noise_power",
    "band_noise_level",
    "band_noise_rms_pressure",
    "white_noise_rms_per_sample",
]

#: Knudsen spectrum level at 1 kHz, dB re 1 µPa²/Hz, for sea states 0…4 (Urick).
KNUDSEN_LEVEL_1KHZ = {0: 44.5, 1: 55.0, 2: 61.5, 3: 64.5, 4: 66.5}
#: Knudsen spectral slope, dB per decade of frequency.
KNUDSEN_SLOPE_DB_PER_DECADE = -17.0
_F0 = 1000.0  # Hz
_MICROPASCAL = 1e-6  # Pa
_SS = np.array(sorted(KNUDSEN_LEVEL_1KHZ), dtype=float)
_NL = np.array([KNUDSEN_LEVEL_1KHZ[int(s)] for s in _SS])


def knudsen_level_1khz(sea_state: ArrayLike) -> np.ndarray:
    """Spectrum level at 1 kHz (dB re 1 µPa²/Hz) for a sea state 0…4 (fractional: linear in dB)."""
    ss = np.asarray(sea_state, dtype=float)
    if np.any(~np.isfinite(ss)) or np.any(ss < _SS[0]) or np.any(ss > _SS[-1]):
        raise ValueError(f"sea state must lie in [{_SS[0]:g}, {_SS[-1]:g}]; got {sea_state!r}")
    return np.interp(ss, _SS, _NL)


def thermal_noise_spectrum_level(frequency: ArrayLike) -> np.ndarray:
    """Thermal noise spectrum level −15 + 20 log10(f/1 kHz), dB re 1 µPa²/Hz (frequency Hz)."""
    f = np.asarray(frequency, dtype=float)
    return -15.0 + 20.0 * np.log10(f / _F0)


def _check_f(frequency):
    f = np.asarray(frequency, dtype=float)
    if np.any(~(f > 0)):
        raise ValueError("frequency must be > 0 Hz")
    return f


def ambient_noise_spectrum_level(frequency: ArrayLike, sea_state: ArrayLike,
                                 include_thermal: bool = False) -> np.ndarray:
    """Knudsen ambient noise spectrum level NL(f), dB re 1 µPa²/Hz.

    frequency Hz (> 0); sea_state 0…4; include_thermal adds the thermal floor (powers add).
    """
    f = _check_f(frequency)
    nl = knudsen_level_1khz(sea_state) + KNUDSEN_SLOPE_DB_PER_DECADE * np.log10(f / _F0)
    if include_thermal:
        nl = 10.0 * np.log10(10.0 ** (nl / 10.0)
                             + 10.0 ** (thermal_noise_spectrum_level(f) / 10.0))
    return nl


def band_noise_power(f_low: ArrayLike, f_high: ArrayLike, sea_state: ArrayLike,
                     include_thermal: bool = False) -> np.ndarray:
    """Mean-square ambient pressure in the band [f_low, f_high] Hz, µPa².

    ∫ N(f) df with N = N0 (f/f0)^(−1.7) (+ thermal N_t (f/f0)²), done in closed form.
    """
    f1 = _check_f(f_low)
    f2 = _check_f(f_high)
    if np.any(~(f2 > f1)):
        raise ValueError("need f_high > f_low")
    n0 = 10.0 ** (knudsen_level_1khz(sea_state) / 10.0)
    m = KNUDSEN_SLOPE_DB_PER_DECADE / 10.0           # exponent of f: −1.7
    power = n0 * _F0 / (m + 1.0) * ((f2 / _F0) ** (m + 1.0) - (f1 / _F0) ** (m + 1.0))
    if include_thermal:
        nt = 10.0 ** (-15.0 / 10.0)
        power = power + nt * _F0 / 3.0 * ((f2 / _F0) ** 3 - (f1 / _F0) ** 3)
    return power


def band_noise_level(f_low: ArrayLike, f_high: ArrayLike, sea_state: ArrayLike,
                     include_thermal: bool = False) -> np.ndarray:
    """Band noise level 10 log10(band power), dB re 1 µPa² (band in Hz)."""
    return power_to_db(band_noise_power(f_low, f_high, sea_state, include_thermal))


def band_noise_rms_pressure(f_low: ArrayLike, f_high: ArrayLike, sea_state: ArrayLike,
                            include_thermal: bool = False) -> np.ndarray:
    """RMS ambient pressure (Pa) of noise confined to [f_low, f_high] Hz."""
    return np.sqrt(band_noise_power(f_low, f_high, sea_state, include_thermal)) * _MICROPASCAL


def white_noise_rms_per_sample(f_low: ArrayLike, f_high: ArrayLike, sample_rate: ArrayLike,
                               sea_state: ArrayLike, include_thermal: bool = False) -> np.ndarray:
    """Per-sample rms pressure (Pa) of white noise whose band [f_low, f_high] matches Knudsen.

    The noise is taken white at the band-average density N̄ = P_band/(f_high − f_low); drawn
    as independent samples at sample_rate fs (Hz) its variance is N̄·fs/2, and any filter
    that keeps exactly [f_low, f_high] leaves the Knudsen band power P_band. Requires
    f_high ≤ fs/2.
    """
    fs = np.asarray(sample_rate, dtype=float)
    f1 = np.asarray(f_low, dtype=float)
    f2 = np.asarray(f_high, dtype=float)
    if np.any(f2 > fs / 2.0):
        raise ValueError("f_high must not exceed the Nyquist frequency sample_rate/2")
    density = band_noise_power(f1, f2, sea_state, include_thermal) / (f2 - f1)
    return np.sqrt(density * fs / 2.0) * _MICROPASCAL

