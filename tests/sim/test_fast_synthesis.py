"""The fast accumulation (``[scattering] synthesis = "fast"``, the default) against the
reference kernel on the same scatterers, and the fidelity options of
:mod:`sim_device.fidelity`: per-path volume depth limits (honoured exactly by the
kernel; their levels follow the sonar equation) and densities per resolution cell."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sim_device.environment_source import EnvironmentSource
from sim_device.fidelity import densities, resolution_cell
from sim_device.scene import load_scene
from svss_daq.config import config_path

PING = 100


def sand(**scattering):
    """The seed's sand scene, thinned (explicit densities, 10x below the file's former
    ones) and cut at 1.2 m so that a ping is quick, no level cut-off; multipath to second
    order; no coherent returns, no targets."""
    sc = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
    opts = {"specular": False, "interface_density_per_m2": 100.0,
            "volume_density_per_m3": 400.0, "volume_max_depth_m": 1.2,
            "scatterers_per_resolution_cell": None, "volume_below_noise_db": None}
    opts.update(scattering)
    return dataclasses.replace(sc, scattering=dataclasses.replace(sc.scattering, **opts),
                               targets=())


def rel(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


@pytest.fixture(scope="module")
def sand_pair(hardware):
    fast = EnvironmentSource(hardware, sand())
    ref = EnvironmentSource(hardware, sand(synthesis="reference"))
    return fast, ref


def test_fast_path_agrees_with_the_reference_to_float32_rounding(sand_pair):
    fast, ref = sand_pair
    assert fast.synthesis == "fast" and ref.synthesis == "reference"
    a = fast.scattered(PING)
    ea = fast.last_stats["echoes"]
    b = ref.scattered(PING)
    assert fast.last_stats["in_view"] == ref.last_stats["in_view"] > 10000
    assert ea == ref.last_stats["echoes"] > 1_000_000        # the same echoes ...
    assert rel(a, b) < 1e-5                                  # ... summed in float32


@pytest.mark.extended      # the default precision's agreement runs by default (above)
@pytest.mark.parametrize("precision", ["exact", "float32"])
def test_fast_path_agrees_at_other_precisions(hardware, precision):
    """exact: every refracted leg goes through the fast path's scalar fall-back (Brent);
    float32: single-precision inputs."""
    opts = {"precision": precision, "volume_max_depth_m": 0.5,
            "interface_density_per_m2": 30.0, "volume_density_per_m3": 100.0}
    a = EnvironmentSource(hardware, sand(**opts))
    b = EnvironmentSource(hardware, sand(**opts, synthesis="reference"))
    pa, pb = a.scattered(PING), b.scattered(PING)
    assert a.last_stats["echoes"] == b.last_stats["echoes"] > 10000
    assert rel(pa, pb) < (1e-5 if precision == "exact" else 1e-4)


def test_fast_path_agrees_on_points_in_water(hardware):
    demo = load_scene(config_path("scenes/demo.toml"))
    ref = dataclasses.replace(demo, scattering=None)
    a = EnvironmentSource(hardware, ref)
    b = EnvironmentSource(hardware, ref)
    b.synthesis = "reference"
    pa, pb = a.scattered(40), b.scattered(40)
    assert a.last_stats["echoes"] == b.last_stats["echoes"] > 0
    assert rel(pa, pb) < 1e-5


def test_per_path_depth_limits_are_honoured(sand_pair, hardware):
    fast, _ = sand_pair
    # every path cut at 0.5 m == the scene cut at 0.5 m (the same seabed cells)
    cut = EnvironmentSource(hardware, sand(volume_max_depth_m=0.5, synthesis="reference"))
    fast.zmax = np.full(fast.allowed.shape, 0.5)
    try:
        a = fast.scattered(PING)
    finally:
        fast.zmax = np.full(fast.allowed.shape, np.inf)
    assert rel(a, cut.scattered(PING)) < 1e-5
    # multipath only from the interface (volume limit below it) == the direct path plus
    # the interface's multipath: check on the volume alone, where it is the direct path
    vol = EnvironmentSource(hardware, sand(interface=False))
    direct = EnvironmentSource(hardware, sand(interface=False))
    vol.zmax = np.where(np.eye(*vol.allowed.shape, dtype=bool) & (np.arange(
        vol.allowed.shape[0])[:, None] == 0), np.inf, -1.0)
    direct.allowed = np.zeros_like(direct.allowed)
    direct.allowed[0, 0] = True
    pv, pd = vol.scattered(PING), direct.scattered(PING)
    assert vol.last_stats["echoes"] == direct.last_stats["echoes"] > 0
    assert rel(pv, pd) < 1e-5


def test_volume_limits_follow_the_sonar_equation(hardware):
    """Each path keeps its volume down to the depth where its level meets the floor:
    multipath (weaker) stops shallower than the direct path, and 10 dB more margin
    goes 10 dB / (4 alpha 10 log10 e) deeper (sand: 27.6 dB/m two-way), the slowly
    varying spreading aside."""
    a = EnvironmentSource(hardware, sand(volume_below_noise_db=0.0, volume_max_depth_m=6.0))
    b = EnvironmentSource(hardware, sand(volume_below_noise_db=10.0, volume_max_depth_m=6.0))
    za, zb = a.zmax, b.zmax
    assert za[0, 0] > za[0, 1] > za[0, 2] > 0 and za[1, 0] == za[0, 1]
    assert za[1, 1] < za[0, 1]
    g = a.frame(0)
    nu = a.media.c[1] / a.media.c[0]
    db_e = 10 * math.log10(math.e)
    for ab, h_r in [((0, 0), 2.0), ((0, 1), 3.0), ((0, 2), 7.0)]:
        z = 0.5 * (za[ab] + zb[ab])
        h_t = -g.tx[2]
        # dB/m: attenuation both ways and the water-equivalent spreading 1/(h + nu z)^2
        # on each leg
        slope = 4 * a.media.alpha[1] * db_e + 2 * db_e * nu * (1 / (h_t + nu * z)
                                                               + 1 / (h_r + nu * z))
        assert zb[ab] - za[ab] == pytest.approx(10.0 / slope, abs=0.01), ab
    # the generated seabed stops at the deepest kept path
    assert a.seabed.z_cut == pytest.approx(za[a.allowed].max())
    s = a.scatterers(PING)
    assert s.z.max() <= za[0, 0] + 1e-12


def test_resolution_cell_and_densities(hardware):
    hw = hardware.value
    src = EnvironmentSource(hardware, sand(scatterers_per_resolution_cell=2.0))
    cell = src.resolution
    lam = 1500.0 / hw.waveform.center_hz
    h = 2.0                                                  # array above the interface
    assert cell.along == pytest.approx(lam * h / (8 * 0.091), rel=1e-3)
    assert cell.across == pytest.approx(lam * h / (12 * 0.091), rel=1e-3)
    assert cell.depth_sediment == pytest.approx(src.media.c[1] / (2 * 15000.0))
    di, dv = src.seabed.densities
    assert di * cell.area == pytest.approx(2.0) and dv * cell.volume == pytest.approx(2.0)
    assert densities(cell, 1.0) == pytest.approx((di / 2, dv / 2))
    c2 = resolution_cell(np.array([[0, 0, 0], [1, 2, 0.0]]), 0.5, 1e4, 3e4, 3.0, 1500, 1800)
    assert (c2.along, c2.across, c2.depth_water) == pytest.approx((0.1, 0.06, 0.075))
