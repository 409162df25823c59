"""Normalisation, level in dB, depth gain and dynamic range compression: no division
by zero, no log of zero, and the documented shape of the compression map."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from svss_daq.config import ProcessingConfig, config_path, load
from svss_proc.products.drc import (MIN_DB, background_floor, compress, depth_gain_db, expand,
                           level_db, normalise)
from svss_proc.products.chain import compute_products

from . import VOXEL, speckle

FLOOR, KNEE, CEIL = -10.0, 20.0, 40.0


def test_normalise_divides_by_the_background_and_never_by_zero():
    mag = np.array([2.0, 3.0, 0.0, 5.0, np.nan, 4.0], dtype=np.float32)
    bg = np.array([1.0, 2.0, 0.0, 0.0, 1.0, np.nan], dtype=np.float32)
    with np.errstate(all="raise"):
        r = normalise(mag, bg, floor_db=-20.0)
    floor = background_floor(bg, -20.0)
    # median of the positive finite background (1, 2, 1) is 1 -> floor 0.1
    assert floor == pytest.approx(0.1)
    np.testing.assert_allclose(r[[0, 1]], [2.0, 1.5], rtol=1e-6)
    assert r[2] == 0.0                                  # 0 / floor
    assert r[3] == pytest.approx(5.0 / floor, rel=1e-6)  # zero background -> floor
    assert np.isnan(r[4])                               # missing stays missing
    assert r[5] == pytest.approx(4.0 / floor, rel=1e-6)  # no background -> floor
    # a volume with no positive background at all
    with np.errstate(all="raise"):
        r = normalise(np.zeros(4), np.zeros(4), -20.0)
    assert np.all(r == 0)


def test_level_db_has_no_log_of_zero():
    with np.errstate(all="raise"):
        out = level_db(np.array([0.0, 1.0, 10.0, 0.5, np.nan, np.inf]))
    assert out[0] == MIN_DB
    np.testing.assert_allclose(out[1:4], [0.0, 20.0, 20 * np.log10(0.5)], atol=1e-5)
    assert np.isnan(out[4]) and out[5] == np.inf


def test_depth_gain():
    np.testing.assert_allclose(depth_gain_db([0.0, 0.5, 1.0, 2.0], 10.0, 0.5),
                               [0.0, 0.0, 5.0, 15.0])


def test_compression_is_linear_below_the_knee_then_bends_smoothly():
    L = np.linspace(FLOOR, KNEE, 31)
    np.testing.assert_allclose(compress(L, FLOOR, KNEE, CEIL), (L - FLOOR) / (CEIL - FLOOR),
                               atol=1e-6)
    # same slope on both sides of the knee (continuous derivative)
    h = 1e-3
    slope_below = (compress(KNEE, FLOOR, KNEE, CEIL) - compress(KNEE - h, FLOOR, KNEE, CEIL)) / h
    slope_above = (compress(KNEE + h, FLOOR, KNEE, CEIL) - compress(KNEE, FLOOR, KNEE, CEIL)) / h
    assert slope_above == pytest.approx(slope_below, rel=0.02)
    # strictly increasing above the floor, bounded, approaching 1
    sweep = np.linspace(FLOOR, 120.0, 2000)
    u = compress(sweep, FLOOR, KNEE, CEIL)
    assert np.all(np.diff(u.astype(np.float64)) >= 0) and u[0] == 0.0
    assert np.all(u < 1.0 + 1e-7) and u[-1] > 0.99
    # above the knee the documented map y = knee + s (1 - exp(-(L - knee) / s)), s = 20 dB:
    # 20 dB above the knee show as 12.6 dB, 60 dB above as 19.0 dB
    for above, shown in ((20.0, 20 * (1 - np.exp(-1))), (60.0, 20 * (1 - np.exp(-3)))):
        assert compress(KNEE + above, FLOOR, KNEE, CEIL) == pytest.approx(
            (KNEE + shown - FLOOR) / (CEIL - FLOOR), abs=1e-6)


def test_compression_of_missing_and_extreme_values():
    with np.errstate(all="raise"):
        u = compress(np.array([np.nan, -np.inf, MIN_DB, np.inf, 1e30]), FLOOR, KNEE, CEIL)
    np.testing.assert_array_equal(u, [0.0, 0.0, 0.0, 1.0, 1.0])
    with pytest.raises(ValueError):
        compress(np.zeros(3), 10.0, 5.0, 40.0)


def test_expand_inverts_compress():
    L = np.array([FLOOR, -3.0, 0.0, 12.0, KNEE, 25.0, 33.0, 50.0])
    np.testing.assert_allclose(expand(compress(L, FLOOR, KNEE, CEIL), FLOOR, KNEE, CEIL), L,
                               atol=2e-3)


def test_products_of_a_volume_with_zeros_nan_and_a_constant_block():
    cfg = load(ProcessingConfig, config_path("processing-demo.toml")).products
    rng = np.random.default_rng(8)
    image = speckle((220, 40, 30), rng)
    image[:30] = 0                  # not imaged
    image[60:140, :, :] = 2.0       # a constant block longer than the 61-voxel kernel
    image[150:155, 5:9, :] = np.nan  # missing
    axes = tuple(np.arange(n) * VOXEL for n in image.shape)
    with np.errstate(all="raise"):
        p = compute_products(image, axes, VOXEL, cfg)
    assert np.all(np.isfinite(p.drc)) and p.drc.min() >= 0 and p.drc.max() <= 1
    assert np.all(p.level[:30] == MIN_DB)                # zeros: floor level, not -inf
    assert np.all(np.isnan(p.level[150:155, 5:9, :]))     # missing stays missing
    assert np.all(p.drc[150:155, 5:9, :] == 0)
    # the middle of the constant block is its own background: 0 dB (to within the
    # histogram approximation's bound)
    bound = cfg.background.histogram_bin_db / 2 if cfg.background.method == "histogram" else 0
    np.testing.assert_allclose(p.level[95:105], 0.0, atol=bound + 1e-4)
    # projections ignore missing voxels; only lines with nothing but missing are NaN
    missing = np.zeros(p.mips["mip_depth"].shape, dtype=bool)
    missing[150:155, 5:9] = True
    np.testing.assert_array_equal(np.isnan(p.mips["mip_depth"]), missing)
    assert np.isfinite(p.mips["mip_cross"]).all() and np.isfinite(p.mips["mip_along"]).all()
    assert len(p.detections) == 0


def test_depth_gain_is_for_display_only():
    cfg = load(ProcessingConfig, config_path("processing-demo.toml")).products
    gained = dataclasses.replace(cfg, depth_gain=dataclasses.replace(
        cfg.depth_gain, db_per_m=10.0, start_m=0.2))
    rng = np.random.default_rng(9)
    image = speckle((150, 30, 50), rng)
    axes = tuple(0.5 * VOXEL + np.arange(n) * VOXEL for n in image.shape)
    image[75, 15, 40] += 300.0
    plain, g = compute_products(image, axes, VOXEL, cfg), compute_products(image, axes,
                                                                           VOXEL, gained)
    expected_gain = 10.0 * np.maximum(axes[2] - 0.2, 0.0)
    np.testing.assert_allclose(g.gain_db, expected_gain, atol=1e-5)
    np.testing.assert_allclose(g.mips["mip_cross"] - plain.mips["mip_cross"],
                               np.broadcast_to(expected_gain, g.mips["mip_cross"].shape),
                               atol=1e-4)
    np.testing.assert_array_equal(g.level, plain.level)
    for name in plain.detections.dtype.names:      # NaN: features not measured
        np.testing.assert_array_equal(g.detections[name], plain.detections[name])
    assert np.all(g.drc >= plain.drc)
