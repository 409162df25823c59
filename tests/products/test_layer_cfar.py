"""A detection threshold per depth layer from the layer's own clutter
(svss_proc.products.layer_cfar): the Weibull tail fit against samples of known tails,
speckle keeping the configured threshold (its tail is the exponential one, k = 1), and a
tile whose interface layer is a sheet of sparse bright facets (K-distributed clutter):
one threshold for all layers makes contacts all along that sheet (the seed's sand line:
9 on the interface, 86 on a bright sheet at the tile's bottom), the layer's own
threshold none, while targets in speckle and in the sheet itself are still found. The
guard against a strong target's own sidelobes is exercised on real imagery by
tests/products/test_run_products.py (the demo's six points in water: fitted without it,
their layers' thresholds rose to 40-90 dB and five of six were missed)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from svss_daq.config import ProcessingConfig, config_path, load
from svss_proc.products.chain import compute_products
from svss_proc.products.layer_cfar import layer_tails, weibull_tail

from . import VOXEL, plant, rayleigh_median, speckle


@pytest.mark.parametrize("k, lam", [(1.0, 1.0 / math.log(2.0)), (0.5, 0.4), (0.3, 0.05)])
def test_the_tail_fit_recovers_a_weibull_tail(k, lam):
    rng = np.random.default_rng(4)
    x = lam * rng.weibull(k, 2_000_000)
    got_lam, got_k = weibull_tail(x)
    assert got_k == pytest.approx(k, rel=0.03)
    assert got_lam == pytest.approx(lam, rel=0.06)


def test_speckle_layers_keep_the_configured_threshold():
    """Median-normalised speckle: intensity exceeds X with probability 2^-X, so the
    tail's level at pfa is 10 log10(log2(1/pfa)) dB: 14.8 dB for 8e-10, below 17."""
    rng = np.random.default_rng(5)
    a = np.abs(speckle((600, 40, 12), rng))
    level = 20 * np.log10(a / np.median(a))
    pfa = 1e-4 * VOXEL ** 3
    free = layer_tails(level, None, pfa, -100.0, VOXEL)
    want = 10 * math.log10(math.log2(1.0 / pfa))
    np.testing.assert_allclose(free.threshold_db, want, atol=0.7)
    np.testing.assert_allclose(free.k, 1.0, atol=0.08)
    assert np.all(layer_tails(level, None, pfa, 17.0, VOXEL).threshold_db == 17.0)


SHAPE = (750, 40, 30)                      # a 15 m tile, 0.8 m across, 0.6 m deep
AXES = tuple(0.5 * VOXEL + np.arange(n) * VOXEL for n in SHAPE)
SHEET = slice(0, 3)                        # the interface's own layer: 3 planes


def _scene(seed: int) -> np.ndarray:
    """Speckle; in SHEET, K-distributed clutter (speckle times the square root of a
    gamma texture of shape 1 per voxel, 10 dB over the speckle on average: its levels
    over the median background reach 25.7 dB, as the seed's sand line's sheets reach
    25.8); a point 24 dB over the speckle at 0.4 m, and a strong one in the sheet."""
    rng = np.random.default_rng(seed)
    img = speckle(SHAPE, rng)
    texture = rng.gamma(1.0, 1.0, (SHAPE[0], SHAPE[1], SHEET.stop))
    img[:, :, SHEET] *= (np.sqrt(10.0 * texture)).astype(np.float32)
    med = rayleigh_median(1.0)
    plant(img, AXES, (AXES[0][200], AXES[1][20], AXES[2][20]), med * 10 ** (24 / 20))
    plant(img, AXES, (AXES[0][520], AXES[1][12], AXES[2][1]), med * 10 ** (60 / 20))
    return img


def _contacts(cfg, img):
    det = compute_products(img, AXES, VOXEL, cfg).detections
    return np.stack([det["along_m"], det["cross_m"], det["depth_m"]], -1), det


def test_a_sheet_of_facets_makes_no_contacts_with_its_own_threshold():
    shipped = load(ProcessingConfig, config_path("processing.toml")).products
    assert shipped.detection.layer_false_alarms_per_m3 is not None
    one = dataclasses.replace(shipped, detection=dataclasses.replace(
        shipped.detection, layer_false_alarms_per_m3=None))
    img = _scene(6)
    targets = np.array([[AXES[0][200], AXES[1][20], AXES[2][20]],
                        [AXES[0][520], AXES[1][12], AXES[2][1]]])
    # one threshold for every layer: the sheet's facets cross it all along the tile
    pos, _ = _contacts(one, img)
    in_sheet = pos[:, 2] <= AXES[2][SHEET.stop - 1] + 1e-9
    far = np.min(np.linalg.norm(pos[:, None, :] - targets[None], axis=-1), axis=1) > 0.3
    assert (in_sheet & far).sum() >= 5, pos
    # its own: the two targets, nothing else
    pos, det = _contacts(shipped, img)
    assert len(pos) == 2, pos
    assert np.all(np.min(np.linalg.norm(pos[:, None, :] - targets[None], axis=-1),
                         axis=0) < 0.05)
    deep, shallow = det[np.argsort(-det["depth_m"])]
    assert deep["threshold_db"] == pytest.approx(shipped.detection.threshold_db)
    assert shallow["threshold_db"] > shipped.detection.threshold_db + 3.0
    # the strong one stands far above its layer's clutter, the deep one far above speckle
    assert 0.0 <= shallow["false_alarms"] < 1e-6 and 0.0 <= deep["false_alarms"] < 1e-6
