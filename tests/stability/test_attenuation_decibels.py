"""Attenuation, water absorption, sound speed and decibel conversions at their
extremes: zero and huge losses, frequencies 1 Hz to 10 MHz, levels to +-3000 dB,
subnormal and zero powers, against mpmath or closed forms."""

from __future__ import annotations

import math

import mpmath as mp
import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from sim_device.acoustics.attenuation import (
    ainslie_mccolm_absorption,
    coppens_sound_speed,
    francois_garrison_absorption,
    loss_parameter_from_attenuation,
    mackenzie_sound_speed,
    sediment_attenuation_db_per_m,
    sediment_attenuation_np_per_m,
)
from svss_daq.decibels import (
    amplitude_to_db,
    amplitude_to_db_floored,
    db_to_amplitude,
    db_to_power,
    power_to_db,
)

from ._sweep import sweep

mp.mp.dps = 40

freqs = st.floats(1.0, 1e7)
deltas = st.one_of(st.just(0.0), st.floats(1e-12, 1e-3), st.floats(1e-3, 1e3))


@sweep(60)
@given(freqs, st.floats(300.0, 5000.0), deltas)
def test_sediment_attenuation_zero_to_huge_loss(f, c, delta):
    a = float(sediment_attenuation_np_per_m(f, c, delta))
    db = float(sediment_attenuation_db_per_m(f, c, delta))
    ref = 2 * mp.pi * f * delta / c
    assert math.isfinite(a) and a >= 0.0 and math.isfinite(db)
    assert abs(a - float(ref)) <= 1e-14 * float(ref) + 1e-300
    assert abs(db - float(ref * 20 / mp.log(10))) <= 1e-13 * abs(db) + 1e-300
    if delta == 0.0:
        assert a == 0.0 and db == 0.0
    else:                                                # round trip through dB/m
        back = float(loss_parameter_from_attenuation(db, f, c))
        assert abs(back / delta - 1.0) <= 1e-13


@sweep(60)
@given(freqs, st.floats(-2.0, 30.0), st.floats(0.0, 40.0), st.floats(0.0, 6000.0),
       st.floats(7.0, 8.5))
def test_water_absorption_finite_positive_and_tends_to_zero_at_low_frequency(f, t, s, d, ph):
    for model in (francois_garrison_absorption, ainslie_mccolm_absorption):
        a = float(model(f, t, s, d, ph))
        assert math.isfinite(a) and a >= 0.0
        # every term goes to zero as f^2 (below its relaxation frequency)
        assert 0.0 <= float(model(1e-3, t, s, d, ph)) <= 1e-9        # dB/m at 1 mHz
        # and it never decreases with frequency (relaxation terms and f^2 water term)
        assert float(model(f * 1.01, t, s, d, ph)) >= a * (1 - 1e-12)
    # fresh water leaves the pure-water f^2 term alone: ~f^2 at every frequency
    fw = francois_garrison_absorption(np.array([f, 2 * f]), t, 0.0, d, ph)
    assert fw[1] / fw[0] == np.float64(4.0) or abs(fw[1] / fw[0] - 4.0) <= 1e-9


def test_sound_speeds_at_their_published_check_values_and_range_ends():
    assert float(mackenzie_sound_speed(25.0, 35.0, 1000.0)) == np.float64(1550.744) or \
        abs(float(mackenzie_sound_speed(25.0, 35.0, 1000.0)) - 1550.744) < 1e-3
    assert abs(float(coppens_sound_speed(0.0, 0.0, 0.0)) - 1402.4) < 0.3   # pure water
    t, s, d = np.meshgrid([-2.0, 35.0], [0.0, 45.0], [0.0, 8000.0])
    for fn in (mackenzie_sound_speed, coppens_sound_speed):
        c = fn(t, s, d)
        assert np.all(np.isfinite(c)) and np.all((c > 1300) & (c < 1800))


levels = st.one_of(st.floats(-3000.0, 3000.0), st.sampled_from([0.0, -3000.0, 3000.0]))
positives = st.one_of(st.floats(5e-324, 1e308), st.sampled_from([5e-324, 1e-300, 1e300,
                                                                 1.7e308]))


@sweep(100)
@given(positives)
def test_decibels_of_tiny_and_huge_values_match_mpmath(v):
    assert abs(float(power_to_db(v)) - float(10 * mp.log10(v))) <= 1e-12 * (1 + abs(
        float(power_to_db(v))))
    assert abs(float(amplitude_to_db(v)) - float(20 * mp.log10(v))) <= 1e-12 * (1 + abs(
        float(amplitude_to_db(v))))
    assert abs(float(amplitude_to_db(complex(0.0, -v))) - float(amplitude_to_db(v))) <= 1e-12
    # the round trip is exact to rounding wherever the result is a normal number
    if v > 1e-290:
        assert abs(float(db_to_power(power_to_db(v))) / v - 1) <= 1e-12
        assert abs(float(db_to_amplitude(amplitude_to_db(v))) / v - 1) <= 1e-12


@sweep(60)
@given(levels)
def test_decibel_inverses_are_finite_or_clean_infinities(level):
    with np.errstate(over="raise"):
        try:
            p = float(db_to_power(level))
        except FloatingPointError:
            assert level > 3080.0                      # beyond 1.8e308 only
            return
    assert p >= 0.0
    if -3070.0 < level < 3080.0:
        assert p > 0.0 and abs(float(power_to_db(p)) - level) <= 1e-11 * (1 + abs(level))
    a = float(db_to_amplitude(level))
    assert math.isfinite(a) and a >= 0.0


def test_zero_and_floor():
    with np.errstate(all="raise"):                     # no warning for zero
        assert power_to_db(0.0) == -np.inf and amplitude_to_db(0j) == -np.inf
        assert float(amplitude_to_db_floored(0.0, -120.0)) == -120.0
    assert np.all(np.isfinite(amplitude_to_db_floored(np.array([0.0, 5e-324, 1.0]), -400.0)))
