"""The sediment-speed scan's pure parts: travel time against depth through layers, the
peak of a focus curve, the combination of responses, and a layer boundary in an image's
level against depth, against values computed by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from svss_proc.seabed.focus import (combine, curve_peak, depth_at_time, focus_measure,
                                    point_sigma, vertical_time)
from svss_proc.seabed.layers import boundary_in_profile, profile_peak

TOPS = np.array([0.0, 0.5])
SPEEDS = np.array([1476.0, 1767.0])


def test_vertical_time_through_layers_and_back():
    assert vertical_time(0.3, TOPS, SPEEDS) == pytest.approx(0.3 / 1476)
    assert vertical_time(1.2, TOPS, SPEEDS) == pytest.approx(0.5 / 1476 + 0.7 / 1767)
    assert vertical_time(-0.2, TOPS, SPEEDS) == 0.0      # above the interface
    for z in (0.0, 0.1, 0.5, 0.5000001, 0.9, 3.0):
        assert depth_at_time(vertical_time(z, TOPS, SPEEDS), TOPS, SPEEDS) == \
            pytest.approx(z, abs=1e-12)
    # one vertical time, another profile: the depth a response moves to
    t = vertical_time(1.0, np.array([0.0]), np.array([1500.0]))
    assert depth_at_time(t, np.array([0.0]), np.array([1767.0])) == pytest.approx(1.178)


def test_curve_peak_finds_a_parabola_vertex_and_refuses_an_edge():
    s = np.arange(1400.0, 2101.0, 50.0)
    v = np.exp(-((s - 1767.0) / 120.0) ** 2)             # log is an exact parabola
    c, a = curve_peak(s, v)
    assert c == pytest.approx(1767.0, abs=1e-6)
    assert a == pytest.approx(-1 / 120.0 ** 2, rel=1e-9)
    c, a = curve_peak(s, np.exp(s / 100))                 # rising to the scan's end
    assert c == 2100.0 and a == 0.0
    assert point_sigma(0.0, 30.0, 3.0) == math.inf
    # 30 dB contrast: 4 e = 0.126 in log focus; curvature -1/120^2: sqrt(0.126) x 120
    assert point_sigma(-1 / 120.0 ** 2, 30.0, 3.0) == pytest.approx(
        120 * math.sqrt(4 * 10 ** -1.5))
    assert point_sigma(-1.0, 60.0, 3.0) == 3.0            # never below the floor


def test_combine_weights_by_uncertainty_and_flags_disagreement():
    c, s, chi2 = combine(np.array([1760.0, 1780.0]), np.array([10.0, 20.0]))
    assert c == pytest.approx((1760 / 100 + 1780 / 400) / (1 / 100 + 1 / 400))
    assert s >= 1 / math.sqrt(1 / 100 + 1 / 400)
    assert chi2 < 1
    _, _, chi2 = combine(np.array([1476.0, 1767.0]), np.array([10.0, 10.0]))
    assert chi2 > 100                                     # two layers' speeds
    c, s, _ = combine(np.array([1700.0, np.nan]), np.array([math.inf, 5.0]))
    assert math.isnan(c) and s == math.inf                # nothing usable


def test_focus_measure_prefers_a_concentrated_response_of_equal_energy():
    focused = np.zeros((5, 5, 5), complex)
    focused[2, 2, 2] = 1.0
    spread = np.full((5, 5, 5), 1 / math.sqrt(125), complex)
    assert np.sum(abs(spread) ** 2) == pytest.approx(1.0)
    assert focus_measure(focused) == pytest.approx(1.0)
    assert focus_measure(spread) == pytest.approx(1 / 125)


def _profile(boundary=None, ghost=None, interface_db=20.0):
    """Median level (dB) against depth (4 cm): an interface, a volume decaying at
    attenuation, at ``boundary`` the boundary's echo and a step up to a lower layer that
    attenuates faster, and a bump at ``ghost`` (depth, dB)."""
    z = np.arange(0.02, 2.0, 0.04)
    lv = 183.0 - 3.0 * z
    lv[0] += interface_db
    if boundary is not None:
        lv += np.where(z >= boundary, 4.0 - 20.0 * np.clip(z - boundary, 0, None), 0.0)
        lv += 4.0 * np.exp(-((z - boundary) / 0.04) ** 2)
    if ghost is not None:
        lv += ghost[1] * np.exp(-((z - ghost[0]) / 0.04) ** 2)
    return z, lv


def test_boundary_found_at_a_step_in_the_volume_level():
    z, lv = _profile(boundary=0.62)
    got = boundary_in_profile(z, lv, 0.25, 0.6, 4.0)
    assert got is not None and abs(got[0] - 0.62) <= 0.04 and got[1] >= 4.0


def test_no_boundary_in_a_homogeneous_sediment_or_above_min_depth():
    z, lv = _profile()
    assert boundary_in_profile(z, lv, 0.25, 0.6, 4.0) is None
    z, lv = _profile(boundary=0.14)                       # within min_depth: not a layer
    assert boundary_in_profile(z, lv, 0.25, 0.6, 4.0) is None


def test_the_interface_surface_echo_is_not_a_boundary_unless_brighter_than_the_interface():
    z, lv = _profile(ghost=(0.61, 6.0))
    assert boundary_in_profile(z, lv, 0.25, 0.6, 4.0) is not None      # a bump alone
    assert boundary_in_profile(z, lv, 0.25, 0.6, 4.0, exclude=(0.61, 0.1)) is None
    # a boundary there, brighter than a weak interface's echo, is still one
    z, lv = _profile(boundary=0.58, interface_db=2.0)
    got = boundary_in_profile(z, lv, 0.25, 0.6, 4.0, exclude=(0.61, 0.1))
    assert got is not None and abs(got[0] - 0.58) <= 0.04


def test_profile_peak_refines_and_refuses_the_ends():
    z = np.arange(0.3, 0.8, 0.01)
    assert profile_peak(z, -((z - 0.5053) / 0.05) ** 2) == pytest.approx(0.5053, abs=1e-9)
    assert profile_peak(z, z) is None
