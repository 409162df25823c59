"""The interface's slope from a run's own navigation and echoes, and buried points imaged
over it: medium sand sloping 3 deg along the track and 5 deg across it, simulated with
the full 80-channel array 5.8 km from the survey origin (the simulator refracts at the
tilted plane itself: tests/sim/test_sloping_bed.py), the interface scattering; a point
0.6 m below the bed 0.6 m to starboard, where the plane lies 5 cm deeper than under the
track."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sim_device.environment_source import EnvironmentSource
from svss_daq.config import (HardwareConfig, ProcessingConfig, config_path, load,
                             load_with_text, loads)
from svss_proc.imaging.imager import PingAccumulator, TileImager
from svss_proc.imaging.sampler import PointSampler
from svss_proc.seabed.slope import estimate_slope, with_slope
from svss_proc.seabed.speed import SpeedEstimate, applied, with_speed

SAND = 1767.0
SLOPE = (3.0, 5.0)
POINT = (4.8, 0.6, 0.6)
SCENE = """
[scene]
name = "slope-test"
description = "a buried point in sloping medium sand"
seed = 4647
[medium]
density_kg_m3 = 1000.0
sound_speed_m_s = 1500.0
[track]
start_time_utc = "2026-11-22T12:00:00Z"
start_ne_m = [5000.0, 3000.0]
heading_deg = 30.0
speed_m_s = 1.0
altitude_m = 2.5
body_down_m = 0.0
n_pings = 70
[noise]
electronic_rms_counts = 20.0
[seabed]
slope_deg = {slope}
[[seabed.layers]]
sediment = "medium_sand"
[scattering]
interface = true
volume = false
specular = true
interface_model = "apl_uw"
interface_density_per_m2 = 1000.0
volume_density_per_m3 = 4000.0
volume_max_depth_m = 1.2
cell_m = 0.25
precision = "float64"
scatterers_per_resolution_cell = 2.0
[[points]]
along_m = {a}
cross_m = {c}
depth_m = {d}
target_strength_db = -20.0
"""


def _pings(hw, slope):
    from sim_device.scene import SceneConfig, check_scene
    text = SCENE.format(slope=list(slope), a=POINT[0], c=POINT[1], d=POINT[2])
    src = EnvironmentSource(hw, check_scene(loads(SceneConfig, text, "test scene"),
                                            "test scene"))
    return [src.ping(i) for i in range(src.n_pings)]


@pytest.fixture(scope="module")
def hw():
    return load_with_text(HardwareConfig, config_path("hardware.toml"))


@pytest.fixture(scope="module")
def sloping(hw):
    return _pings(hw, SLOPE)


@pytest.fixture(scope="module")
def proc():
    return load(ProcessingConfig, config_path("processing.toml"))


@pytest.mark.slow
def test_slope_along_from_the_navigation_and_across_from_the_echo(hw, sloping, proc):
    est = estimate_slope(sloping, hw, proc)
    assert est.slope_deg[0] == pytest.approx(SLOPE[0], abs=0.05)     # true navigation
    assert est.slope_deg[1] == pytest.approx(SLOPE[1], abs=0.25)     # the echo's
    assert all(s is not None and 0 < s < 0.3 for s in est.sigma_deg)
    assert est.source[0].startswith("navigation") and est.source[1].startswith("interface")
    summary = est.summary()
    used = applied(proc, SpeedEstimate("unconstrained", 1500.0, 1500.0, "test",
                                       slope=summary).summary())
    assert used.imaging.interface_slope_deg == pytest.approx(est.slope_deg, abs=1e-3)
    assert used.imaging.sediment_sound_speed_m_s == proc.imaging.sediment_sound_speed_m_s


@pytest.mark.slow
def test_a_level_bed_gives_no_slope(hw, proc):
    est = estimate_slope(_pings(hw, (0.0, 0.0)), hw, proc)
    assert abs(est.slope_deg[0]) < 0.05 and abs(est.slope_deg[1]) < 0.3


def _depth_of_peak(hw, proc, pings):
    """The point's peak depth below the bed above it, as the tiles image it: a 2 cm
    column about it, then a parabola through the peak."""
    line = TileImager(hw, proc)
    line.add(pings[0])
    s = PointSampler(PingAccumulator(hw, proc), proc, line.line)
    near = [p for p in pings if abs(s.reach(p)[0] - POINT[0]) <= s.reach(p)[1]]
    ax = np.arange(-0.06, 0.061, 0.02)
    z = np.arange(0.4, 0.95, 0.01)          # below the interface's own echo
    col = np.abs(s.grid(near, POINT[0] + ax, POINT[1] + ax, z))
    i, j, k = np.unravel_index(int(np.argmax(col)), col.shape)
    if not 0 < k < z.size - 1:
        return float(z[k])
    y = np.log(col[i, j, k - 1:k + 2])
    return float(z[k] + 0.01 * 0.5 * (y[0] - y[2]) / (y[0] - 2 * y[1] + y[2]))


@pytest.mark.slow
def test_a_point_under_the_slope_at_its_depth_only_over_the_plane(hw, sloping, proc):
    sand = with_speed(dataclasses.replace(proc, products=None), SAND)
    over_plane = _depth_of_peak(hw, with_slope(sand, SLOPE), sloping)
    level = _depth_of_peak(hw, sand, sloping)
    assert over_plane == pytest.approx(POINT[2], abs=0.015)
    assert abs(level - POINT[2]) > 0.03              # level at the nadir bed: 5 cm off
    assert math.isfinite(level)
