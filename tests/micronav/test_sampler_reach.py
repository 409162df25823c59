"""The autofocus's sampler (svss_proc.micronav.autofocus._Sampler, also bench_focus's)
images as the tiles do, with and without ``[imaging] beam_gating``: without it each
ping reaches as far along-track as its echo window's range (the tiles' schedule), not
the projector's beam to the tile's bottom."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from sim_device.environment_source import EnvironmentSource
from sim_device.scene import load_scene
from svss_daq.config import (HardwareConfig, ProcessingConfig, config_path, load_with_text,
                             loaded_from_text)
from svss_proc.imaging.imager import TileImager
from svss_proc.micronav.autofocus import _Sampler

from .test_live_stage import processing_text


@pytest.fixture(scope="module")
def pings():
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    scene = load_scene(config_path("scenes/demo.toml"))
    return hw, list(itertools.islice(iter(EnvironmentSource(hw, scene)), 10))


@pytest.mark.parametrize("gating", [True, False])
def test_the_sampler_images_as_the_tiles(pings, gating):
    hw, ps = pings
    text = processing_text(False, 1.0, 0.0, 1.0)
    assert text.count("beam_gating = true") == 1
    text = text.replace("beam_gating = true", f"beam_gating = {str(gating).lower()}")
    proc = loaded_from_text(ProcessingConfig, text, f"gating {gating}").value
    imager = TileImager(hw, proc)
    tiles = []
    for p in ps:
        tiles += imager.add(p)
    tiles += imager.finish()
    assert tiles
    sampler = _Sampler(imager.accumulator, proc, imager.line)
    scale = max(float(np.abs(t.image).max()) for t in tiles)
    assert scale > 0
    for t in tiles:
        g = t.grid
        got = sampler.grid(ps, g.along, g.cross, g.depth)
        np.testing.assert_allclose(got, t.image, rtol=0, atol=1e-5 * scale)
