"""Transducer directivity and the dB helpers."""

import math

import numpy as np
import pytest
from scipy.special import j1

from svss_daq.decibels import (amplitude_to_db, db_to_amplitude, db_to_power,
                                           power_to_db)
from sim_device.acoustics.directivity import (cone_gate, piston_directivity,
                                              piston_first_null, piston_radius_for_half_angle,
                                              piston_x_at_gain)

C = 1500.0


def test_piston_on_axis_and_formula():
    a, f = 0.02, 27.5e3
    assert float(piston_directivity(0.0, f, a, C)) == 1.0
    th = np.radians(np.linspace(0.5, 90, 50))
    x = 2 * np.pi * f / C * a * np.sin(th)
    np.testing.assert_allclose(piston_directivity(th, f, a, C), 2 * j1(x) / x, rtol=1e-14)
    # continuous through the small-x branch
    tiny = np.array([1e-8, 1e-7, 1e-6, 2e-6, 1e-5])
    np.testing.assert_allclose(piston_directivity(tiny, f, a, C), 1 - (2 * np.pi * f / C * a
                                                                      * np.sin(tiny)) ** 2 / 8,
                               rtol=1e-12)


def test_first_null_at_3_8317():
    a, f = 0.05, 35e3
    k = 2 * np.pi * f / C
    th0 = float(piston_first_null(f, a, C))
    assert k * a * math.sin(th0) == pytest.approx(3.8317, abs=1e-4)
    assert abs(float(piston_directivity(th0, f, a, C))) < 1e-12
    assert float(piston_directivity(th0 - 1e-3, f, a, C)) > 0 > float(
        piston_directivity(th0 + 1e-3, f, a, C))                       # sign change
    assert np.isnan(piston_first_null(f, 0.001, C))                    # ka < 3.83: no null


@pytest.mark.parametrize("half_angle_deg,f", [(25.0, 27.5e3), (50.0, 27.5e3), (25.0, 20e3),
                                              (10.0, 35e3)])
def test_radius_for_half_angle_gives_minus_3_db(half_angle_deg, f):
    th = math.radians(half_angle_deg)
    a = float(piston_radius_for_half_angle(th, f, C))
    g = float(piston_directivity(th, f, a, C))
    assert float(amplitude_to_db(g)) == pytest.approx(-3.0, abs=1e-9)
    # monotone main lobe: inside is louder, outside quieter
    assert piston_directivity(0.9 * th, f, a, C) > g > piston_directivity(1.1 * th, f, a, C)


def test_half_power_point_constant():
    assert piston_x_at_gain() == pytest.approx(1.6163, abs=1e-4)       # |2J1(x)/x| = 1/√2
    assert piston_x_at_gain(10 ** (-3 / 20)) == pytest.approx(1.6129, abs=1e-3)
    a = float(piston_radius_for_half_angle(math.radians(20.0), 30e3, C, level_db=-6.0))
    assert float(amplitude_to_db(piston_directivity(math.radians(20.0), 30e3, a, C))) == \
        pytest.approx(-6.0, abs=1e-9)
    with pytest.raises(ValueError):
        piston_radius_for_half_angle(0.0, 30e3, C)


def test_cone_gate():
    h = math.radians(25.0)
    w = math.radians(4.0)
    th = np.radians(np.linspace(0, 60, 601))
    g = cone_gate(th, h, w)
    assert np.all(g[th <= h - w / 2] == 1.0) and np.all(g[th >= h + w / 2] == 0.0)
    assert float(cone_gate(h, h, w)) == pytest.approx(0.5)
    assert np.all(np.diff(g) <= 0) and np.all((g >= 0) & (g <= 1))
    assert np.max(np.abs(np.diff(g))) < 0.05                            # no jump at 0.1° steps
    hard = cone_gate(th, h)
    np.testing.assert_array_equal(hard, (th <= h).astype(float))
    np.testing.assert_array_equal(cone_gate(-th, h, w), g)              # symmetric
    with pytest.raises(ValueError):
        cone_gate(th, h, -1.0)


def test_decibel_helpers():
    v = np.array([1e-3, 0.5, 1.0, 10.0])
    np.testing.assert_allclose(db_to_power(power_to_db(v)), v, rtol=1e-14)
    np.testing.assert_allclose(db_to_amplitude(amplitude_to_db(v)), v, rtol=1e-14)
    assert float(power_to_db(0.01)) == pytest.approx(-20.0)
    assert float(amplitude_to_db(-0.1 + 0j)) == pytest.approx(-20.0)
    assert float(power_to_db(0.0)) == -np.inf and float(amplitude_to_db(0.0)) == -np.inf
