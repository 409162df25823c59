"""svss_daq.decibels: the floored amplitude level the quicklooks use (the round trips
and zero handling are checked in tests/acoustics/test_directivity.py)."""

from __future__ import annotations

import numpy as np

from svss_daq.decibels import amplitude_to_db, amplitude_to_db_floored


def test_floored_level_is_the_level_limited_below():
    v = np.array([0.0, 1e-20, 1e-3, -0.1 + 0j, 1.0, 10.0])
    out = amplitude_to_db_floored(v, -100.0)
    np.testing.assert_array_equal(out, [-100.0, -100.0, -60.0, -20.0, 0.0, 20.0])
    above = np.abs(v) >= 1e-5
    np.testing.assert_array_equal(out[above], amplitude_to_db(v[above]))
    assert np.all(np.isfinite(out))
