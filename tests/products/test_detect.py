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
    # 2 ** -(10 ** (T / 10)) (docs/detections.md)
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


def test_later_echoes_under_a_contact_merge_into_it():
    """An elastic object's response extends below it (ringing, internal paths): weaker
    contacts under a stronger one, within later_echo_m, are that object; a weaker one
    above it, or beside it beyond the horizontal reach, stays a contact."""
    a, c, z = AXES[0][100], AXES[1][20], AXES[2][8]
    blobs = [((a, c, z), 32.0),                       # the object
             ((a + 0.02, c - 0.12, z + 0.5), 27.0),   # its later echoes below it
             ((a - 0.04, c + 0.14, z + 0.5), 26.0),
             ((a, c, z - 0.12), 25.0),                # its top, above: a contact
             ((a + 1.0, c, z + 0.5), 26.0)]           # beside it: a contact
    level, mag, bg = _blobs(blobs)
    det = detect(level, mag, bg, AXES, 14.0, 2, (0.05,) * 3, 50,
                 later_echo_m=(0.35, 0.35, 1.5))
    got = sorted((round(float(r["along_m"]), 2), round(float(r["depth_m"]), 2)) for r in det)
    want = sorted((round(float(p[0]), 2), round(float(p[2]), 2))
                  for i, (p, _) in enumerate(blobs) if i in (0, 3, 4))
    assert len(got) == len(want)
    np.testing.assert_allclose(np.array(got), np.array(want), atol=VOXEL)
    # the object's extent covers its later echoes
    top = det[np.argmin(np.abs(det["along_m"] - a) + np.abs(det["depth_m"] - z))]
    assert top["extent_depth_m"] >= 0.5
    # without it every echo is a contact
    assert len(detect(level, mag, bg, AXES, 14.0, 2, (0.05,) * 3, 50)) == 5
    # a bright patch of the interface claims no buried object under it
    shallow = [((a, c, AXES[2][2]), 34.0), ((a, c, AXES[2][2] + 0.5), 27.0)]
    level, mag, bg = _blobs(shallow)
    assert len(detect(level, mag, bg, AXES, 14.0, 2, (0.05,) * 3, 50,
                      later_echo_m=(0.35, 0.35, 1.5))) == 2


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


def test_sidelobes_compared_by_peak_magnitude_not_excess():
    """A strong target raises its own background (its sidelobes fill the median
    window), so a sidelobe further out can have the larger excess: the magnitudes
    decide. Here the weak contact has 10 dB more excess but a 40 dB weaker peak."""
    a, c, z = AXES[0][60], AXES[1][20], AXES[2][20]
    level = np.full(SHAPE, 0.0, dtype=np.float32)
    mag = np.full(SHAPE, 1.0, dtype=np.float32)
    bg = np.ones(SHAPE, dtype=np.float32)
    for (ia, excess, peak) in ((60, 30.0, 1e4), (85, 40.0, 1e2)):
        level[ia - 1:ia + 2, 19:22, 19:22] = excess
        mag[ia - 1:ia + 2, 19:22, 19:22] = peak
        level[ia, 20, 20] += 1.0                                  # the peak voxel
        mag[ia, 20, 20] *= 1.1
    det = _detect(level, mag, bg, sidelobe_db=30.0, sidelobe_m=1.0)
    np.testing.assert_allclose(det["along_m"], [a], atol=0.5 * VOXEL)
    assert det["cross_m"][0] == pytest.approx(c, abs=0.5 * VOXEL)
    assert det["depth_m"][0] == pytest.approx(z, abs=0.5 * VOXEL)
    assert len(_detect(level, mag, bg, sidelobe_db=50.0, sidelobe_m=1.0)) == 2


def test_sidelobe_region_is_the_projector_footprint():
    """Seen by one ping's cone together: (2 h + z1 + z2) tan(half-angle) apart at most."""
    from svss_proc.products.detect import Footprint, is_sidelobe
    fp = Footprint(2.0, np.tan(np.radians(25.0)))
    reach = (4.0 + 0.3 + 0.5) * np.tan(np.radians(25.0))            # 2.24 m
    strong = (0.0, 0.0, 0.3)
    for d, want in ((reach - 0.01, True), (reach + 0.01, False)):
        weak = (d * 0.8, d * 0.6, 0.5)
        assert is_sidelobe(weak, 150.0, strong, 190.0, 30.0, 0.0, fp) is want
        assert not is_sidelobe(weak, 170.0, strong, 190.0, 30.0, 0.0, fp)   # 20 dB only
    assert not is_sidelobe((1.5, 0.0, 0.3), 150.0, strong, 190.0, 30.0, 1.0)  # no footprint


def test_voxels_below_the_coverage_fraction_never_detect():
    a, c = AXES[0][60], AXES[1][20]
    level, mag, bg = _blobs([((a, c, AXES[2][10]), 30.0), ((a, c, AXES[2][30]), 30.0)])
    detectable = np.ones(SHAPE, dtype=bool)
    detectable[:, :, 25:] = False
    det = detect(level, mag, bg, AXES, 14.0, 2, (0.2,) * 3, 50, detectable=detectable)
    np.testing.assert_allclose(det["depth_m"], [AXES[2][10]], atol=0.5 * VOXEL)


def test_background_follows_the_coverage(cfg):
    """Speckle whose level follows the coverage (noise summed over N channel samples
    grows as sqrt(N)): with whitening, the normalised level's median is 0 dB on both
    sides of a coverage step and nothing is detected at the step; without it the
    median window straddles the step and the well-covered side stands out."""
    from dataclasses import replace
    rng = np.random.default_rng(5)
    channels = np.full(SHAPE, 2000, dtype=np.uint16)
    channels[:100] = 125                                      # 1/16 the looks: -12 dB
    img = (speckle(SHAPE, rng) * np.sqrt(channels.astype(np.float32))).astype(np.complex64)
    pings = (channels // 80).astype(np.uint16)
    pings[:100] = 25                                          # at least half of 25: all
    p = compute_products(img, AXES, VOXEL, cfg, coverage=(pings, channels))
    for part in (slice(0, 95), slice(105, None)):
        assert np.median(p.level[part]) == pytest.approx(0.0, abs=0.3)
    assert len(p.detections) == 0
    off = replace(cfg, background=replace(cfg.background, coverage_whitening=False))
    q = compute_products(img, AXES, VOXEL, off, coverage=(pings, channels))
    assert np.median(q.level[100:110]) > 5.0                  # the step, unwhitened


def test_a_target_buried_under_a_bright_interface_is_not_its_sidelobe():
    """No ping sees the interface (nadir 2 m, cone edge 2.2 m) and a point 1 m into sand
    (at least 2 + 0.85 m water-equivalent) at one range, so the buried point stays a
    contact however much brighter the interface is; a point at the interface's depth
    within the footprint is still its sidelobe."""
    from svss_proc.products.detect import Footprint, is_sidelobe
    fp = Footprint(2.0, np.tan(np.radians(25.0)), 1500.0 / 1767.0, 0.19)
    bright = (10.0, 0.1, 0.01)
    assert not fp.may_share_range(1.0, 0.01)
    assert not is_sidelobe((10.3, 0.0, 1.0), 150.0, bright, 190.0, 15.0, 1.0, fp)
    assert is_sidelobe((10.9, 0.5, 0.05), 150.0, bright, 190.0, 15.0, 1.0, fp)
    # ranges that overlap: 0.2 m deeper is within the cone-edge range of the shallower
    assert fp.may_share_range(0.2, 0.0)
    # without the range test (no footprint) the 1 m Euclidean rule would drop it
    assert is_sidelobe((10.3, 0.0, 0.95), 150.0, bright, 190.0, 15.0, 1.0)


def test_regions_from_their_voxels_equal_scipys_measurements():
    """A region's voxel count, bounding box, largest finite level and its voxel, taken
    from the labelled voxels only (``_regions``), equal scipy.ndimage's measurements over
    the whole volume; a peak shared by several voxels is the first in C order."""
    from scipy import ndimage

    from svss_proc.products.detect import _regions
    rng = np.random.default_rng(12)
    level = rng.normal(0.0, 5.0, (60, 30, 20)).astype(np.float32)
    mask = level >= 6.0
    labels, n = ndimage.label(mask, structure=np.ones((3, 3, 3), dtype=bool))
    assert n > 50
    # non-finite levels inside regions, and one region whose peak is shared
    inside = np.flatnonzero(labels)
    level.ravel()[inside[::7]] = np.inf
    level.ravel()[inside[3::11]] = np.nan
    r = _regions(labels, level)
    index = np.arange(1, n + 1)
    finite = np.where(np.isfinite(level), level, -np.inf)
    np.testing.assert_array_equal(r.labels, index)
    np.testing.assert_array_equal(r.counts, np.bincount(labels.ravel())[1:])
    np.testing.assert_array_equal(r.peak_value, ndimage.maximum(finite, labels, index))
    boxes = ndimage.find_objects(labels)
    np.testing.assert_array_equal(r.lo.T, [[s.start for s in b] for b in boxes])
    np.testing.assert_array_equal(r.hi.T, [[s.stop for s in b] for b in boxes])
    big = int(np.argmax(r.counts))
    vox = np.argwhere(labels == big + 1)
    level[tuple(vox[-1])] = level[tuple(vox[0])] = 99.0       # a tie: first in C order
    r = _regions(labels, level)
    np.testing.assert_array_equal(r.peak[:, big], vox[0])
    unique = [k for k in range(n) if np.sum(finite[labels == k + 1] == r.peak_value[k]) == 1
              and k != big]
    positions = ndimage.maximum_position(np.where(np.isfinite(level), level, -np.inf),
                                         labels, index[unique])
    np.testing.assert_array_equal(r.peak[:, unique].T, positions)
