"""Detections: planted targets in speckle are found at their positions with their levels;
speckle alone gives the false-alarm rate the documentation states; merging and sidelobe
suppression. Scoring against ground truth is the ``svss`` tool's (test_score.py)."""

from __future__ import annotations

import numpy as np
import pytest

from svss_daq.config import ProcessingConfig, config_path, load
from svss_proc.products.detect import detect
from svss_proc.products.drc import level_db, normalise
from svss_proc.products.background import median_exact
from svss_proc.products.chain import compute_products

from . import VOXEL, plant, rayleigh_median, speckle

SHAPE = (200, 40, 40)
AXES = tuple(0.5 * VOXEL + np.arange(n) * VOXEL for n in SHAPE)
TREND_DB_PER_M = -20.0  # speckle level falls with depth; normalisation must undo it


def sigma_at(depth_m):
    return 10.0 ** (TREND_DB_PER_M * np.asarray(depth_m) / 20.0)


def speckle_volume(seed: int) -> np.ndarray:
    img = speckle(SHAPE, np.random.default_rng(seed))
    return (img * sigma_at(AXES[2])[None, None, :]).astype(np.complex64)


@pytest.fixture(scope="module")
def cfg():
    return load(ProcessingConfig, config_path("processing.toml")).products


# (along, cross, depth) m and excess over the local speckle median, dB
TARGETS = [
    ((AXES[0][50], AXES[1][20], AXES[2][10]), 32.0),               # on a voxel centre
    ((AXES[0][120] + 0.006, AXES[1][10] - 0.005, AXES[2][25] + 0.004), 26.0),  # between
    ((AXES[0][170], AXES[1][30], AXES[2][35]), 28.0),              # deep: 14 dB weaker
]


def test_planted_targets_found_at_their_positions_and_levels(cfg):
    img = speckle_volume(11)
    expected_peak = []
    for pos, excess in TARGETS:
        local_median = rayleigh_median(sigma_at(pos[2]))
        amp = local_median * 10 ** (excess / 20)
        plant(img, AXES, pos, amp)
        # the blob's value at the nearest voxel centre
        near = [ax[np.argmin(np.abs(ax - p))] for ax, p in zip(AXES, pos)]
        expected_peak.append(amp * np.exp(-0.5 * sum(((n - p) / (1.2 * VOXEL)) ** 2
                                                     for n, p in zip(near, pos))))
    det = compute_products(img, AXES, VOXEL, cfg).detections
    assert len(det) == len(TARGETS), det
    for (pos, excess), peak in zip(TARGETS, expected_peak):
        d = det[np.argmin([np.linalg.norm(np.array(pos) - [r["along_m"], r["cross_m"],
                                                            r["depth_m"]]) for r in det])]
        err = np.abs(np.array([d["along_m"], d["cross_m"], d["depth_m"]]) - pos)
        assert np.all(err <= 0.5 * VOXEL), (pos, d)
        sigma = sigma_at(pos[2])
        # the speckle adds a complex value of a few sigma to the planted peak
        tol_db = 20 * np.log10(1 + 4 * sigma / peak)
        assert d["peak_db"] == pytest.approx(20 * np.log10(peak), abs=tol_db)
        bg_db = 20 * np.log10(rayleigh_median(sigma))
        assert d["background_db"] == pytest.approx(bg_db, abs=0.5)
        assert d["excess_db"] == pytest.approx(20 * np.log10(peak) - bg_db, abs=tol_db + 0.5)
        # extent: the blob above the 14 dB threshold, r = w sqrt(2 ln(amplitude ratio))
        r = 1.2 * np.sqrt(2 * np.log(10 ** ((d["excess_db"] - cfg.detection.threshold_db)
                                            / 20)))
        for k in ("extent_along_m", "extent_cross_m", "extent_depth_m"):
            assert 2 * (r - 1) * VOXEL <= d[k] <= (2 * (r + 1) + 1) * VOXEL, (k, d[k], r)
    assert list(det["excess_db"]) == sorted(det["excess_db"], reverse=True)


def test_speckle_false_alarms_follow_the_documented_rate(cfg):
    img = speckle_volume(12)
    img[:20] = 0  # an unimaged strip: its edge must not detect
    mag = np.abs(img)
    bg = median_exact(mag, (61, 11, 5), ignore_zeros=True)
    level = level_db(normalise(mag, bg, -60.0))
    data = level[20:]
    # a voxel of median-normalised Rayleigh speckle reaches T dB with probability
    # 2 ** -(10 ** (T / 10)) (docs/products.md)
    for t_db, tol in ((6.0, 0.1), (10.0, 0.25)):
        p = 2.0 ** -(10 ** (t_db / 10))
        assert np.mean(data >= t_db) == pytest.approx(p, rel=tol)
    expected = data.size * 2.0 ** -(10 ** (cfg.detection.threshold_db / 10))
    assert expected < 0.1
    det = compute_products(img, AXES, VOXEL, cfg).detections
    assert len(det) <= 1


def _blobs(spec, seed=13):
    img = speckle(SHAPE, np.random.default_rng(seed))
    for pos, excess in spec:
        plant(img, AXES, pos, rayleigh_median(1.0) * 10 ** (excess / 20))
    mag = np.abs(img)
    bg = median_exact(mag, (61, 11, 5))
    return level_db(normalise(mag, bg, -60.0)), mag, bg


def _detect(level, mag, bg, merge=0.2, sidelobe_db=np.inf, sidelobe_m=0.0):
    return detect(level, mag, bg, AXES, 14.0, 2, (merge,) * 3, 50, sidelobe_db, sidelobe_m)


def test_close_peaks_merge_into_the_stronger():
    a, c, z = AXES[0][100], AXES[1][20], AXES[2][20]
    # two separate regions above the threshold, 0.16 m apart
    level, mag, bg = _blobs([((a, c, z), 30.0), ((a + 0.16, c, z), 27.0)])
    det = _detect(level, mag, bg)
    assert len(det) == 1
    assert det[0]["along_m"] == pytest.approx(a, abs=0.5 * VOXEL)
    assert det[0]["extent_along_m"] >= 0.16          # covers both peaks
    det = _detect(level, mag, bg, merge=0.05)
    assert len(det) == 2


def test_weak_contacts_near_a_strong_one_are_its_sidelobes():
    a, c, z = AXES[0][60], AXES[1][20], AXES[2][20]
    level, mag, bg = _blobs([((a, c, z), 40.0), ((a + 0.5, c, z), 22.0),
                             ((a + 1.6, c, z), 22.0)])
    assert len(_detect(level, mag, bg)) == 3
    det = _detect(level, mag, bg, sidelobe_db=15.0, sidelobe_m=1.0)
    # the 18 dB weaker contact 0.5 m away goes; the one 1.6 m away stays
    np.testing.assert_allclose(det["along_m"], [a, a + 1.6], atol=0.5 * VOXEL)
    det = _detect(level, mag, bg, sidelobe_db=20.0, sidelobe_m=1.0)
    assert len(det) == 3


def test_no_detections_in_an_empty_or_missing_volume():
    z = np.zeros(SHAPE, dtype=np.float32)
    assert len(_detect(z, z, z)) == 0
    n = np.full(SHAPE, np.nan, dtype=np.float32)
    assert len(_detect(n, n, n)) == 0
