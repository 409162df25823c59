"""Kirchhoff flat-disc (flat rock) model."""

import numpy as np
import pytest

from sim_device.targets import (disc_backscatter, disc_scattering_amplitude,
                                disc_target_strength, kirchhoff_disc_directivity,
                                load_materials)

MAT = load_materials()
WATER = MAT.fluid("water_nominal")
GRANITE = MAT.material("granite")


def test_normal_incidence_level():
    a, f = 0.1, 27.5e3
    k = 2 * np.pi * f / 1500.0
    r = (2650 * 4960 - 1.5e6) / (2650 * 4960 + 1.5e6)
    fb = disc_backscatter(f, a, WATER, GRANITE.lossless())
    assert fb == pytest.approx(-1j * r * k * a * a / 2)
    # rigid plate: TS = 20 log10(A/λ), the classic flat-plate value
    assert disc_target_strength(f, a, WATER) == pytest.approx(
        20 * np.log10(np.pi * a * a / (1500.0 / f)))


def test_tilt_pattern_null_edge_on_and_symmetry():
    a, f = 0.1, 30e3
    k = 2 * np.pi * f / 1500.0
    null = np.arcsin(3.831705970 / (2 * k * a))
    tilt = np.array([0.0, null, -null, np.pi / 2, 2.0, -np.pi / 2])
    fb = disc_backscatter(f, a, WATER, GRANITE, tilt=tilt)
    assert np.all(np.isfinite(fb))
    assert abs(fb[1]) < 1e-8 * abs(fb[0]) and abs(fb[2]) < 1e-8 * abs(fb[0])
    assert abs(fb[3]) < 1e-15 and fb[4] == 0 and abs(fb[5]) < 1e-15
    small = disc_backscatter(f, a, WATER, GRANITE, tilt=[0.05, -0.05])
    assert small[0] == pytest.approx(small[1])
    assert kirchhoff_disc_directivity(0.0) == 1.0
    assert kirchhoff_disc_directivity(1e-7) == pytest.approx(1.0)


def test_bistatic_disc_reduces_to_monostatic_and_specular():
    rng = np.random.default_rng(1)
    a, f = 0.08, 25e3
    normal = np.array([0.0, 0.0, -1.0])               # z down: normal points up to the water
    tilts = rng.uniform(0, 1.2, 20)
    az = rng.uniform(0, 2 * np.pi, 20)
    to_sonar = np.stack([np.sin(tilts) * np.cos(az), np.sin(tilts) * np.sin(az),
                         -np.cos(tilts)], axis=-1)
    bi = disc_scattering_amplitude(f, a, WATER, -to_sonar, to_sonar, normal, GRANITE)
    mono = disc_backscatter(f, a, WATER, GRANITE, tilt=tilts)
    np.testing.assert_allclose(bi, mono, rtol=1e-12)
    # specular direction: full aperture, |f| = |R| k a² cos γ / 2
    ki = np.array([np.sin(0.4), 0.0, np.cos(0.4)])
    ks = np.array([np.sin(0.4), 0.0, -np.cos(0.4)])
    spec = disc_scattering_amplitude(f, a, WATER, ki, ks, normal, GRANITE)
    k = 2 * np.pi * f / 1500.0
    r = GRANITE.normal_incidence_reflection(WATER)
    assert abs(spec) == pytest.approx(abs(r) * k * a * a * np.cos(0.4) / 2)
    # receiver behind the disc: not lit
    assert disc_scattering_amplitude(f, a, WATER, ki, -ks, normal, GRANITE) == 0
