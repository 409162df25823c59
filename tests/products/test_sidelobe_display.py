"""What the display products show of a strong target's sidelobes (svss_proc.products.chain,
``_shown``; detect.sidelobe_zone): a voxel the detection would drop as an imaging sidelobe
of a contact is shown at most at the detection threshold. A target's sidelobes end
sharply where no ping's footprint holds both it and them, where the median background
falls to the noise: in the demo that edge stood 70 dB over its background in the tile
MIPs and the mosaic, 28 dB over the weakest target, while the detection dropped it.
Here: speckle, a point 80 dB over it and, 1.6 m away at its depth, a thin arc 30 dB
below it (one voxel thick along-track, so the median does not see it)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from svss_daq.config import ProcessingConfig, config_path, load
from svss_proc.products.chain import compute_products
from svss_proc.products.detect import Footprint, sidelobe_zone

from . import VOXEL, plant, rayleigh_median, speckle

SHAPE = (300, 40, 30)
AXES = tuple(0.5 * VOXEL + np.arange(n) * VOXEL for n in SHAPE)
FOOT = Footprint(height_m=2.0, tan_half_angle=np.tan(np.radians(25.0)))
TARGET = (100, 20, 10)
ARC = 180                                          # 1.6 m along from the target


def _image():
    rng = np.random.default_rng(12)
    img = speckle(SHAPE, rng)
    med = rayleigh_median(1.0)
    plant(img, AXES, tuple(AXES[k][TARGET[k]] for k in range(3)), med * 10 ** (80 / 20))
    img[ARC, :, TARGET[2]] += med * 10 ** (50 / 20)
    return img


@pytest.fixture(scope="module")
def cfg():
    return load(ProcessingConfig, config_path("processing.toml")).products


def test_the_zone_is_what_is_sidelobe_would_drop():
    mag_db = np.full(SHAPE, 100.0)
    mag_db[ARC, :, :] = 150.0                     # 30 dB under a 180 dB source
    src = np.array([[AXES[0][TARGET[0]], AXES[1][TARGET[1]], AXES[2][TARGET[2]]]])
    zone = sidelobe_zone(mag_db, AXES, src, np.array([180.0]), 15.0, 1.0, FOOT)
    from svss_proc.products.detect import is_sidelobe
    rng = np.random.default_rng(1)
    for idx in zip(*(rng.integers(0, n, 400) for n in SHAPE)):
        pos = [AXES[k][idx[k]] for k in range(3)]
        assert zone[idx] == is_sidelobe(pos, mag_db[idx], src[0], 180.0, 15.0, 1.0, FOOT)
    # without a footprint: the sidelobe radius alone
    near = sidelobe_zone(mag_db, AXES, src, np.array([180.0]), 15.0, 1.0, None)
    assert near[TARGET[0] + 40, TARGET[1], TARGET[2]] and not near[ARC, 0, TARGET[2]]


def test_a_sidelobe_edge_is_not_shown_brighter_than_the_threshold(cfg):
    p = compute_products(_image(), AXES, VOXEL, cfg, footprint=FOOT)
    assert len(p.detections) == 1                  # the arc was a sidelobe there already
    assert np.median(p.level[ARC, :, TARGET[2]]) > 40.0    # the premise: 50 dB up
    # shown at most at the threshold (plus the depth gain at its depth) ...
    shown = p.mips["mip_depth"][ARC - 2:ARC + 3]
    assert np.max(shown) <= cfg.detection.threshold_db + p.gain_db[TARGET[2]] + 1e-4
    # ... while the target is shown as it is
    assert np.max(p.mips["mip_depth"]) > 60.0
    # with only the 1 m sidelobe radius (no footprint) the arc is no sidelobe: shown
    plain = compute_products(_image(), AXES, VOXEL, cfg)
    assert np.max(plain.mips["mip_depth"][ARC - 2:ARC + 3]) > 40.0


def test_a_partly_imaged_edge_is_shown_as_partial(cfg):
    """Voxels imaged by fewer than ``min_coverage_fraction`` of the full pings at their
    depth (a run's end) may not detect; a bright response there is shown at most at the
    threshold, and kept as it is in the level volume."""
    img = _image()
    img[:, :, :] = speckle(SHAPE, np.random.default_rng(3))
    edge = (slice(270, 300), slice(None), slice(None))
    plant(img, AXES, (AXES[0][285], AXES[1][20], AXES[2][12]),
          rayleigh_median(1.0) * 10 ** (45 / 20))
    pings = np.full(SHAPE, 20, dtype=np.uint16)
    pings[edge] = 3                                # the last pings' reach
    channels = pings * 80
    p = compute_products(img, AXES, VOXEL, cfg, coverage=(pings, channels))
    assert len(p.detections) == 0
    assert np.max(p.level[edge]) > 35.0            # the level is as it was
    assert np.max(p.mips["mip_depth"][270:300]) <= cfg.detection.threshold_db \
        + np.max(p.gain_db) + 1e-4
