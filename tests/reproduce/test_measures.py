"""The reproduction's measure functions on synthetic profiles and volumes with known
answers (svss.reproduce.measures)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import median_filter

from svss.reproduce import measures as m


def _profile(depth, peaks, floor_db=-60.0, width=0.03):
    """A dB profile: a floor plus Gaussian bumps (in intensity) of given (depth, dB)."""
    inten = np.full(depth.shape, 10 ** (floor_db / 10))
    for z, level in peaks:
        inten += 10 ** (level / 10) * np.exp(-0.5 * ((depth - z) / width) ** 2)
    return 10 * np.log10(inten)


def test_features_found_at_known_depths_first_and_second_order():
    depth = np.arange(-0.3, 3.5, 0.01) + 0.005
    db = _profile(depth, [(0.0, 0.0), (0.5893, -15.0), (1.18, -57.0), (2.9447, -30.0)])
    first, second, feats = m.multipath_features(depth, db)
    assert first.depth == pytest.approx(0.5893, abs=2e-3)
    assert second.depth == pytest.approx(2.9447, abs=2e-3)
    # the bump at 1.18 m stands 4.8 dB over the floor: a feature (>= 3 dB), but not
    # one of the two most prominent
    assert [round(f.depth, 1) for f in feats] == [0.6, 1.2, 2.9]
    assert m.multipath_features(depth, db, min_prominence_db=6.0)[2][1].depth == \
        pytest.approx(2.9447, abs=2e-3)
    # onset of a Gaussian bump well above the floor: 3 dB down on its shallow side,
    # z - sigma sqrt(2 ln 2^(3/10... )): exp(-x^2/2) = 10^(-0.3)
    x = np.sqrt(2 * 0.3 * np.log(10))
    assert first.onset == pytest.approx(0.5893 - 0.03 * x, abs=2e-3)
    assert second.onset == pytest.approx(2.9447 - 0.03 * x, abs=2e-3)


def test_prominence_against_a_direct_definition():
    db = np.array([0.0, -10.0, -4.0, -8.0, -6.0, -20.0, -2.0, -30.0])
    # peak at index 2 (-4): the higher base is the min on its way to a higher maximum:
    # left min -10 (up to index 0 at 0 dB), right min -20 (up to index 6 at -2 dB) ->
    # -4 - (-10) = 6; index 4 (-6): left -8 (up to -4), right -20 -> 2; index 6 (-2):
    # left -20 (up to 0 dB), right -30 (to the end) -> 18
    assert m.prominences(db, np.array([2, 4, 6])) == pytest.approx([6.0, 2.0, 18.0])


def test_refine_peak_is_exact_for_a_parabola():
    x = np.arange(0.0, 1.0, 0.02)
    y = -3.0 * (x - 0.4537) ** 2
    i = int(np.argmax(y))
    assert m.refine_peak(x, y, i) == pytest.approx(0.4537, abs=1e-9)


def test_no_second_feature_when_only_one():
    depth = np.arange(0.0, 3.0, 0.01)
    db = _profile(depth, [(0.0, 0.0), (0.6, -15.0)])
    first, second, _feats = m.multipath_features(depth, db)
    assert first.depth == pytest.approx(0.6, abs=2e-3) and second is None


def test_depth_profile_matches_a_direct_mean_and_leaves_out_the_target_columns():
    rng = np.random.default_rng(3)
    a = np.arange(50) * 0.02 + 9.0
    c = (np.arange(10) - 4.5) * 0.02
    d = np.arange(30) * 0.02
    img = (rng.normal(size=(50, 10, 30)) + 1j * rng.normal(size=(50, 10, 30))).astype(np.complex64)
    img[20:30] *= 100.0                     # a "target" in columns 9.40..9.58 m
    img[:, :, 5] = 0                        # one layer no ping reached
    out = m.depth_profile(img, (a, c, d), half_width=0.05, exclude_along=(9.49, 0.1))
    rows = np.abs(a - 9.49) > 0.1
    cols = np.abs(c) <= 0.05
    want = (np.abs(img[rows][:, cols].astype(np.complex128)) ** 2).mean(axis=(0, 1))
    assert np.isnan(out[5])
    keep = np.arange(30) != 5
    assert out[keep] == pytest.approx(want[keep], rel=1e-6)


def test_path_arithmetic():
    # PHYSICS.md section 8: 1 m / 1500 m/s * 1767 m/s / 2
    assert m.multipath_depth_expected(1.0, 1500.0, 1767.0) == pytest.approx(0.589)
    assert m.multipath_depth_expected(5.0, 1500.0, 1767.0) == pytest.approx(2.945)


def test_excess_of_a_point_over_a_uniform_background_is_its_level():
    shape = (81, 21, 31)
    axes = tuple((np.arange(n) - n // 2) * 0.02 for n in shape)
    img = np.ones(shape, dtype=np.complex64)
    img[40, 10, 15] = 10 ** (17.0 / 20)     # 17 dB over a background of 1
    e = m.target_excess(img, axes, 0.02, (0.01, 0.0, 0.0), radius=0.1)
    assert e.excess_db == pytest.approx(17.0, abs=0.03)     # histogram bins: <= 0.025 dB
    assert e.peak == pytest.approx((0.0, 0.0, 0.0))


def test_excess_uses_the_products_median_background():
    rng = np.random.default_rng(11)
    shape = (71, 15, 11)
    axes = tuple((np.arange(n) - n // 2) * 0.02 for n in shape)
    mag = np.abs(rng.normal(size=shape) + 1j * rng.normal(size=shape)).astype(np.float32)
    mag[35, 7, 5] = 40.0
    e = m.target_excess(mag, axes, 0.02, (0.0, 0.0, 0.0), radius=0.05, method="exact")
    # the products' kernel 1.2 x 0.2 x 0.1 m at 2 cm: 61 x 11 x 5 voxels, reflect
    bg = median_filter(mag, size=(61, 11, 5), mode="reflect")[35, 7, 5]
    assert e.excess_db == pytest.approx(20 * np.log10(40.0 / bg), abs=1e-4)
