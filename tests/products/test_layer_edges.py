"""The upper edge of a brighter layer below the interface (background.below_edge_from_m,
svss_proc.products.background.greater_of_below): a sheet 20 dB over the speckle whose top
rises locally by a few centimetres (as the seed's sand line's deep sheet did at 1.85 m,
where its last false alarm sat). The centred median lags such a rise and the bumps'
voxels stand out by about 20 dB: contacts along the sheet with the centred median alone,
none with the greater of it and the window beneath, while a point in the speckle above
keeps its level and its contact."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from svss_daq.config import ProcessingConfig, config_path, load
from svss_proc.products.background import greater_of_below
from svss_proc.products.chain import compute_products

from . import VOXEL, plant, rayleigh_median, speckle

SHAPE = (500, 50, 100)                  # 10 m along, 1 m across, 2 m deep at 2 cm
AXES = tuple(0.5 * VOXEL + np.arange(n) * VOXEL for n in SHAPE)
SHEET_TOP_M = 1.9                        # the sheet's top where it is level
BUMPS = [(1.5, 0.3), (4.2, 0.7), (6.9, 0.2), (8.8, 0.5)]   # (along, cross) of its rises
POINT = (AXES[0][150], AXES[1][25], AXES[2][60])             # 1.21 m deep


def _scene(seed: int) -> np.ndarray:
    """Speckle over a sheet 20 dB brighter below SHEET_TOP_M, whose top rises by up to
    7 cm in four Gaussian bumps 0.25 m wide; a point 25 dB over the speckle."""
    rng = np.random.default_rng(seed)
    img = speckle(SHAPE, rng)
    a, c = np.meshgrid(AXES[0], AXES[1], indexing="ij")
    top = np.full(a.shape, SHEET_TOP_M)
    for ba, bc in BUMPS:
        top -= 0.07 * np.exp(-0.5 * ((a - ba) ** 2 + (c - bc) ** 2) / 0.25 ** 2)
    below = AXES[2][None, None, :] >= top[:, :, None]
    img[below] *= np.float32(10.0)
    plant(img, AXES, POINT, rayleigh_median(1.0) * 10 ** (25 / 20))
    return img


@pytest.fixture(scope="module")
def shipped():
    cfg = load(ProcessingConfig, config_path("processing.toml")).products
    assert cfg.background.below_edge_from_m is not None
    return cfg


def test_the_window_beneath_takes_a_layers_edge_and_leaves_a_point(shipped):
    off = dataclasses.replace(shipped, background=dataclasses.replace(
        shipped.background, below_edge_from_m=None))
    img = _scene(11)
    near = lambda det, p, r: np.hypot(det["along_m"] - p[0], det["cross_m"] - p[1]) < r
    # the centred median alone: contacts on the sheet's risen edge, at the bumps
    plain = compute_products(img, AXES, VOXEL, off)
    on_sheet = plain.detections[plain.detections["depth_m"] > 1.7]
    assert len(on_sheet) >= 2, plain.detections
    assert all(any(near(d, b, 0.6) for b in BUMPS) for d in on_sheet)
    # the greater of it and the window beneath: only the point
    got = compute_products(img, AXES, VOXEL, shipped)
    det = got.detections
    assert len(det) == 1, det
    assert near(det[0], POINT, 0.05) and abs(det[0]["depth_m"] - POINT[2]) < 0.05
    # the point's level is unchanged, to within the histogram median's bin
    ip = tuple(int(np.argmin(np.abs(ax - p))) for ax, p in zip(AXES, POINT))
    assert got.level[ip] == pytest.approx(plain.level[ip], abs=0.1)
    same = plain.detections[near(plain.detections, POINT, 0.05)]
    assert len(same) == 1 and det[0]["excess_db"] == pytest.approx(same[0]["excess_db"],
                                                                  abs=0.1)


def test_greater_of_below_by_hand():
    """Each voxel at or below ``from_m`` takes the greater of its own value and the one
    kernel_depth // 2 + 1 planes deeper (the last plane past the bottom); above it and
    where the deeper one is smaller, the value stays."""
    depth = np.array([0.0, 0.1, 0.2, 0.3, 0.4, 0.5])
    bg = np.array([[[5.0, 1.0, 1.0, 1.0, 3.0, 2.0]]])
    got = greater_of_below(bg, depth, 3, 0.1)        # shift 2
    np.testing.assert_array_equal(got[0, 0], [5.0, 1.0, 3.0, 2.0, 3.0, 2.0])
    assert greater_of_below(bg, depth, 3, None) is bg
    np.testing.assert_array_equal(greater_of_below(bg, depth, 3, 1.0), bg)
