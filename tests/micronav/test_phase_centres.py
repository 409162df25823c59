"""Redundant phase centres of the real SVSS array (config/hardware.toml: 80 receivers on a
9.1 cm grid, six projectors 22.9 cm apart): the bistatic excess path against the exact
path, and the pairs of two pings against an independent count on the receiver grid."""

from __future__ import annotations

import math

import numpy as np
import pytest

from svss_daq.config import HardwareConfig, config_path, load
from svss_daq.geometry import array_geometry
from svss_proc.micronav.phase_centres import (bistatic_excess_m, overlap_table,
                                              pair_phase_centres, phase_centres)

WAVELENGTH = 1500.0 / 27.5e3            # at the waveform's centre frequency, m


@pytest.fixture(scope="module")
def hw():
    return load(HardwareConfig, config_path("hardware.toml"))


@pytest.fixture(scope="module")
def geo(hw):
    return array_geometry(hw)


def test_phase_centres_are_the_midpoints(geo):
    for k in range(geo.projectors.shape[0]):
        pc = phase_centres(geo, k)
        assert pc.shape == (80, 3)
        np.testing.assert_allclose(2 * pc - geo.receivers, np.tile(geo.projectors[k], (80, 1)),
                                   atol=1e-12)


@pytest.mark.parametrize("range_m", [1.5, 3.0, 10.0, 100.0])
def test_bistatic_excess_matches_the_exact_path_to_fourth_order(geo, range_m):
    """Every transmit-receive pair of the array, scatterers in every direction of the
    projector cone and beyond (up to 60 deg off nadir): the exact two-way path minus
    twice the range from the phase centre, against |s_perp|^2 / (4 R); the remainder
    is bounded by the next term, |s|^4 / (8 R^3)."""
    rng = np.random.default_rng(3)
    t = geo.projectors[rng.integers(0, 6, 400)]
    r = geo.receivers[rng.integers(0, 80, 400)]
    c = 0.5 * (t + r)
    th = rng.uniform(0.0, math.radians(60.0), 400)
    ph = rng.uniform(0.0, 2 * math.pi, 400)
    u = np.column_stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])
    p = c + range_m * u
    exact = (np.linalg.norm(p - t, axis=1) + np.linalg.norm(p - r, axis=1)
             - 2 * range_m)
    approx = bistatic_excess_m(r - t, u, range_m)
    s = np.linalg.norm(r - t, axis=1)
    assert (approx >= 0).all()
    assert np.all(np.abs(exact - approx) <= s ** 4 / (8 * range_m ** 3) + 1e-12)
    # the term matters: at 3 m it is centimetres, a wavelength's fraction
    if range_m == 3.0:
        assert approx.max() > WAVELENGTH / 2


def test_lag_two_pairs_at_the_matched_speed_lie_on_the_grid(geo, hw):
    """At 0.91 m/s and 10 pings/s, two pings apart (projector 0 then 2) the platform has
    moved 0.182 m: a receiver of the later ping four rows (4 x 9.1 cm = 2 x 0.182 m) aft
    and five columns (5 x 9.1 cm against the projectors' 2 x 22.9 cm) to port of one of
    the earlier ping gives a phase centre 1.5 mm across from it, none along. Counted
    independently on the receiver grid."""
    pitch = hw.receive_array.pitch_m
    d = np.array([2 * hw.sequencer.ping_interval_s * 0.91, 0.0, 0.0])
    pairs = pair_phase_centres(geo, 0, 2, d, WAVELENGTH / 4)
    dy = (geo.projectors[2, 1] - geo.projectors[0, 1]) / 2 - 5 * pitch / 2
    assert abs(dy - 0.0015) < 1e-4
    np.testing.assert_allclose(pairs.residual_m[:, 0], 0.0, atol=1e-9)
    np.testing.assert_allclose(np.abs(pairs.residual_m[:, 1]), abs(dy), atol=1e-9)
    # independently: receiver j of ping b pairs with the receiver of ping a four rows
    # forward and five columns to starboard, where one exists
    rx = geo.receivers
    expected = 0
    for j in range(80):
        want = rx[j] + np.array([4 * pitch, 5 * pitch, 0.0])
        expected += np.any(np.linalg.norm(rx - want, axis=1) < 1e-6)
    assert len(pairs) == expected > 10
    for i, j in zip(pairs.channel_a, pairs.channel_b):
        np.testing.assert_allclose(rx[i] - rx[j], [4 * pitch, 5 * pitch, 0.0], atol=1e-9)
    assert len(set(pairs.channel_a)) == len(pairs) == len(set(pairs.channel_b))
    np.testing.assert_allclose(pairs.separation_a, rx[pairs.channel_a] - geo.projectors[0])


def test_the_configured_sequence_at_one_metre_per_second_has_no_redundant_pair(geo, hw):
    """The finding docs/phase_centres.md builds on: consecutive projectors shift the
    phase centres by 11.45 cm, 2.5 grid spacings, and 1 m/s moves them 2.2 spacings per
    ping, so no pair of pings one to four apart shares a phase centre within lambda/4;
    the order 0, 2, 4, 5, 3, 1 gives 30 pairs for four of every six consecutive pings."""
    rows = overlap_table(geo, hw.sequencer.projector_order, 1.0,
                         hw.sequencer.ping_interval_s, (1, 2, 3, 4), WAVELENGTH / 4)
    assert len(rows) == 24 and all(r["pairs"] == 0 for r in rows)
    rows = overlap_table(geo, (0, 2, 4, 5, 3, 1), 1.0, hw.sequencer.ping_interval_s, (1,),
                         WAVELENGTH / 4)
    assert [r["pairs"] for r in rows] == [30, 30, 0, 30, 30, 0]
    assert all(r["max_residual_m"] <= WAVELENGTH / 4 for r in rows if r["pairs"])


def test_tolerance_must_be_positive(geo):
    with pytest.raises(ValueError, match="tolerance"):
        pair_phase_centres(geo, 0, 1, np.zeros(3), 0.0)
