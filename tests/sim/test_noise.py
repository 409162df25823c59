"""Receiver noise: Knudsen ambient noise by sea state inside the receivers' band, channel
independence, electronic noise, and per-ping seeding."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.signal import welch

from sim_device.acoustics import ambient_noise_spectrum_level
from sim_device.acoustics.ambient_noise import band_noise_power
from sim_device.environment_source import EnvironmentSource
from sim_device.receiver_noise import band_power, knudsen_noise
from sim_device.scene import load_scene
from svss_daq.config import config_path
from svss_daq.scaling import counts_per_upa

FS = 125e3


def test_knudsen_spectrum_inside_the_band():
    rng = np.random.default_rng(5)
    x = knudsen_noise(rng, 64, 4000, FS, 3.0, (10e3, 60e3))
    f, pxx = welch(x, FS, nperseg=256, axis=-1)
    pxx = pxx.mean(axis=0)
    for fq in (15e3, 20e3, 27.5e3, 35e3, 50e3):
        k = np.argmin(np.abs(f - fq))
        level = 10 * np.log10(pxx[k])
        assert level == pytest.approx(float(ambient_noise_spectrum_level(f[k], 3.0)), abs=0.5)
    # nothing outside the band (beyond the estimator's leakage)
    inside = 10 * np.log10(pxx[np.argmin(np.abs(f - 20e3))])
    for fq in (3e3, 62e3):
        assert 10 * np.log10(pxx[np.argmin(np.abs(f - fq))]) < inside - 25
    # the variance is the band's Knudsen power
    assert x.var() == pytest.approx(float(band_noise_power(10e3, 60e3, 3.0)), rel=0.03)


def test_sea_state_extremes_and_channel_independence():
    rng = np.random.default_rng(6)
    v0 = knudsen_noise(rng, 32, 3000, FS, 0.0, (10e3, 60e3)).var()
    v4 = knudsen_noise(rng, 32, 3000, FS, 4.0, (10e3, 60e3)).var()
    assert 10 * np.log10(v4 / v0) == pytest.approx(66.5 - 44.5, abs=0.3)
    x = knudsen_noise(rng, 16, 20000, FS, 3.0, (10e3, 60e3))
    r = np.corrcoef(x)
    off = r[~np.eye(16, dtype=bool)]
    assert np.max(np.abs(off)) < 5 / math.sqrt(20000 / 4)


def test_band_power_adds_the_electronic_share():
    p = band_power(3.0, (10e3, 60e3), 20e3, 35e3, 100.0, FS)
    expect = float(band_noise_power(20e3, 35e3, 3.0)) + 100.0 ** 2 * 15e3 / 62.5e3
    assert p == pytest.approx(expect, rel=1e-12)
    assert band_power(None, None, 20e3, 35e3, 0.0, FS) == 0.0


@pytest.fixture(scope="module")
def quiet_scene():
    sc = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
    return dataclasses.replace(sc, scattering=dataclasses.replace(
        sc.scattering, interface=False, volume=False, specular=False), targets=())


def test_ping_noise_levels_and_seeding(hardware, quiet_scene):
    dig = hardware.value.digitiser
    src = EnvironmentSource(hardware, quiet_scene)
    a, b = src.noise(4), src.noise(5)
    np.testing.assert_array_equal(a, EnvironmentSource(hardware, quiet_scene).noise(4))
    assert not np.allclose(a, b)
    expect = (float(band_noise_power(10e3, 60e3, 3.0))
              + (quiet_scene.noise.electronic_rms_counts / counts_per_upa(dig)) ** 2)
    assert a.var() == pytest.approx(expect, rel=0.05)
    # electronic noise alone, in counts
    sc = dataclasses.replace(quiet_scene, noise=dataclasses.replace(quiet_scene.noise,
                                                                    sea_state=None))
    ping = EnvironmentSource(hardware, sc).ping(2)
    assert ping.samples.std() == pytest.approx(sc.noise.electronic_rms_counts, rel=0.02)
