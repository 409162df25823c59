"""Attenuation in the sediment and in the water, and the sound speed of water.

Sediment (APL-UW TR 9407, PHYSICS.md section 1): the sediment wavenumber is
k_s = (k/ν)(1 + iδ), so the amplitude attenuation is Im k_s = k δ/ν = 2π f δ / c_sed
nepers per metre, linear in frequency for a constant loss parameter δ, i.e.
α[dB/m] = 20 k δ / (ν ln 10).

Water absorption: Francois & Garrison (1982, JASA 72, 896-907 and 1879-1890), the
three-term (boric acid, magnesium sulphate, pure water) relaxation formula; and the
simpler Ainslie & McColm (1998, JASA 103, 1671-1672) fit to the same data. Salinity 0
gives fresh water (only the pure-water term is left).

Water sound speed: Mackenzie (1981, JASA 70, 807-812; nine-term equation, sea water) and
Coppens (1981, JASA 69, 862-863; valid down to salinity 0, so usable for fresh water).

All functions are numpy-vectorised and broadcast over their arguments. Units: frequency
Hz, temperature °C, salinity ppt (PSU), depth m, speeds m/s, attenuation per metre.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "NEPER_TO_DB",
    "sediment_attenuation_np_per_m",
    "sediment_attenuation_db_per_m",
    "loss_parameter_from_attenuation",
    "db_per_m_to_np_per_m",
    "np_per_m_to_db_per_m",
    "francois_garrison_absorption",
    "ainslie_mccolm_absorption",
    "mackenzie_sound_speed",
    "coppens_sound_speed",
]

#: dB per neper for an amplitude quantity: 20/ln 10 ≈ 8.686.
NEPER_TO_DB = 20.0 / math.log(10.0)


def _f(x: ArrayLike) -> np.ndarray:
    return np.asarray(x, dtype=float)


# --------------------------------------------------------------------------- sediment
def sediment_attenuation_np_per_m(frequency: ArrayLike, sediment_sound_speed: ArrayLike,
                                  loss_parameter: ArrayLike) -> np.ndarray:
    """Amplitude attenuation of a sediment with loss parameter δ, Np/m.

    α = Im k_s = 2π f δ / c_sed  (= k δ/ν with k = 2πf/c_w, ν = c_sed/c_w).
    frequency Hz; sediment_sound_speed m/s; loss_parameter δ (dimensionless, ≥ 0).
    """
    return 2.0 * np.pi * _f(frequency) * _f(loss_parameter) / _f(sediment_sound_speed)


def sediment_attenuation_db_per_m(frequency: ArrayLike, sediment_sound_speed: ArrayLike,
                                  loss_parameter: ArrayLike) -> np.ndarray:
    """Sediment attenuation α(f) in dB/m: 20 k δ / (ν ln 10) (PHYSICS.md section 1)."""
    return NEPER_TO_DB * sediment_attenuation_np_per_m(frequency, sediment_sound_speed,
                                                        loss_parameter)


def loss_parameter_from_attenuation(attenuation_db_per_m: ArrayLike, frequency: ArrayLike,
                                    sediment_sound_speed: ArrayLike) -> np.ndarray:
    """Loss parameter δ that gives a quoted attenuation (dB/m) at a frequency (Hz).

    Inverse of :func:`sediment_attenuation_db_per_m`: δ = α ln10 c_sed / (20·2π f).
    """
    return (_f(attenuation_db_per_m) / NEPER_TO_DB * _f(sediment_sound_speed)
            / (2.0 * np.pi * _f(frequency)))


def db_per_m_to_np_per_m(alpha_db: ArrayLike) -> np.ndarray:
    """Amplitude attenuation dB/m → Np/m."""
    return _f(alpha_db) / NEPER_TO_DB


def np_per_m_to_db_per_m(alpha_np: ArrayLike) -> np.ndarray:
    """Amplitude attenuation Np/m → dB/m."""
    return _f(alpha_np) * NEPER_TO_DB


# ------------------------------------------------------------------ water absorption
def francois_garrison_absorption(frequency: ArrayLike, temperature: ArrayLike = 10.0,
                                 salinity: ArrayLike = 35.0, depth: ArrayLike = 0.0,
                                 ph: ArrayLike = 8.0) -> np.ndarray:
    """Sea/fresh-water absorption after Francois & Garrison (1982), dB/m.

    α = A1 P1 f1 f²/(f1²+f²) + A2 P2 f2 f²/(f2²+f²) + A3 P3 f²  (dB/km, f in kHz), with
    the boric-acid (A1, f1), magnesium-sulphate (A2, P2, f2) and pure-water (A3, P3)
    coefficients of FG 1982 Part II, c = 1412 + 3.21 T + 1.19 S + 0.0167 D and
    T_K = 273 + T. Temperature is taken as given (the IPTS-68/ITS-90 difference,
    a factor 1.00024, is ignored). Fitted for 0.2 kHz–1 MHz, −2…22 °C (MgSO4 band to
    5 %), 30–35 ppt, depth < 3.5 km; salinity 0 leaves the pure-water term (fresh water).

    frequency Hz; temperature °C; salinity ppt; depth m; ph (NBS scale). Returns dB/m.
    """
    f = _f(frequency) / 1e3
    t = _f(temperature)
    s = _f(salinity)
    d = _f(depth)
    ph = _f(ph)
    tk = 273.0 + t
    c = 1412.0 + 3.21 * t + 1.19 * s + 0.0167 * d
    f2sq = f * f
    # boric acid
    a1 = 8.86 / c * 10.0 ** (0.78 * ph - 5.0)
    f1 = 2.8 * np.sqrt(s / 35.0) * 10.0 ** (4.0 - 1245.0 / tk)
    boric = a1 * f1 * f2sq / (f1 * f1 + f2sq)
    # magnesium sulphate
    a2 = 21.44 * s / c * (1.0 + 0.025 * t)
    p2 = 1.0 - 1.37e-4 * d + 6.2e-9 * d * d
    fm = 8.17 * 10.0 ** (8.0 - 1990.0 / tk) / (1.0 + 0.0018 * (s - 35.0))
    mgso4 = a2 * p2 * fm * f2sq / (fm * fm + f2sq)
    # pure water
    a3 = np.where(t <= 20.0,
                  4.937e-4 - 2.59e-5 * t + 9.11e-7 * t**2 - 1.50e-8 * t**3,
                  3.964e-4 - 1.146e-5 * t + 1.45e-7 * t**2 - 6.5e-10 * t**3)
    p3 = 1.0 - 3.83e-5 * d + 4.9e-10 * d * d
    water = a3 * p3 * f2sq
    return (boric + mgso4 + water) / 1e3


def ainslie_mccolm_absorption(frequency: ArrayLike, temperature: ArrayLike = 10.0,
                              salinity: ArrayLike = 35.0, depth: ArrayLike = 0.0,
                              ph: ArrayLike = 8.0) -> np.ndarray:
    """Sea/fresh-water absorption after Ainslie & McColm (1998), dB/m.

    α = 0.106 f1 f²/(f1²+f²) e^{(pH−8)/0.56}
        + 0.52 (1 + T/43)(S/35) f2 f²/(f2²+f²) e^{−z/6}
        + 0.00049 f² e^{−(T/27 + z/17)}            (dB/km; f, f1, f2 in kHz; z in km)
    f1 = 0.78 √(S/35) e^{T/26},  f2 = 42 e^{T/17}.
    Same inputs and units as :func:`francois_garrison_absorption`. Returns dB/m.
    """
    f = _f(frequency) / 1e3
    t = _f(temperature)
    s = _f(salinity)
    z = _f(depth) / 1e3
    ph = _f(ph)
    f2sq = f * f
    f1 = 0.78 * np.sqrt(s / 35.0) * np.exp(t / 26.0)
    fm = 42.0 * np.exp(t / 17.0)
    boric = 0.106 * f1 * f2sq / (f1 * f1 + f2sq) * np.exp((ph - 8.0) / 0.56)
    mgso4 = 0.52 * (1.0 + t / 43.0) * (s / 35.0) * fm * f2sq / (fm * fm + f2sq) \
        * np.exp(-z / 6.0)
    water = 0.00049 * f2sq * np.exp(-(t / 27.0 + z / 17.0))
    return (boric + mgso4 + water) / 1e3


# --------------------------------------------------------------- water sound speed
def mackenzie_sound_speed(temperature: ArrayLike, salinity: ArrayLike = 35.0,
                          depth: ArrayLike = 0.0) -> np.ndarray:
    """Sound speed in sea water, Mackenzie (1981) nine-term equation, m/s.

    Valid −2…30 °C, 25…40 ppt, 0…8000 m (standard error 0.07 m/s). Published check
    value: 1550.744 m/s at 25 °C, 35 ppt, 1000 m. temperature °C; salinity ppt; depth m.
    """
    t = _f(temperature)
    s = _f(salinity)
    d = _f(depth)
    return (1448.96 + 4.591 * t - 5.304e-2 * t**2 + 2.374e-4 * t**3
            + 1.340 * (s - 35.0) + 1.630e-2 * d + 1.675e-7 * d**2
            - 1.025e-2 * t * (s - 35.0) - 7.139e-13 * t * d**3)


def coppens_sound_speed(temperature: ArrayLike, salinity: ArrayLike = 35.0,
                        depth: ArrayLike = 0.0) -> np.ndarray:
    """Sound speed in sea or fresh water, Coppens (1981), m/s.

    With t = T/10 and D in km:
    c0 = 1449.05 + 45.7 t − 5.21 t² + 0.23 t³ + (1.333 − 0.126 t + 0.009 t²)(S − 35),
    c = c0 + (16.23 + 0.253 t) D + (0.213 − 0.1 t) D² + [0.016 + 0.0002 (S−35)](S−35) t D.
    Valid 0…35 °C, 0…45 ppt, 0…4000 m; at S = 0 it follows the pure-water speed
    (1402.4 m/s at 0 °C, 1482.3 m/s at 20 °C) to about 0.1 m/s.
    temperature °C; salinity ppt; depth m.
    """
    t = _f(temperature) / 10.0
    s = _f(salinity)
    dk = _f(depth) / 1e3
    c0 = (1449.05 + 45.7 * t - 5.21 * t**2 + 0.23 * t**3
          + (1.333 - 0.126 * t + 0.009 * t**2) * (s - 35.0))
    return (c0 + (16.23 + 0.253 * t) * dk + (0.213 - 0.1 * t) * dk**2
            + (0.016 + 0.0002 * (s - 35.0)) * (s - 35.0) * t * dk)
