"""The interface's relief about its plane, from the interface's own echo, and buried points
imaged over it (svss_proc.seabed.relief).

The run: medium sand whose interface undulates 10 cm over 4 m along the track and 4 cm
over 2.5 m across it, simulated with the full 80-channel array 5.8 km from the survey
origin, the simulator refracting exactly at the curved surface
(tests/sim/test_undulating_bed.py); a point 0.6 m below the bed on a flank of the
undulation, where the surface lies 8 cm below its level."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sim_device.environment_source import EnvironmentSource
from svss_daq.config import (ConfigError, HardwareConfig, ProcessingConfig, config_path,
                             load, load_with_text, loads)
from svss_proc.imaging.imager import PingAccumulator, TileImager
from svss_proc.imaging.sampler import PointSampler
from svss_proc.imaging.surface import InterfaceShape
from svss_proc.seabed.relief import (MIN_PICKS, estimate_relief, relief_nodes,
                                     with_relief)
from svss_proc.seabed.speed import SpeedEstimate, applied, with_speed

SAND = 1767.0
POINT = (4.6, 0.3, 0.6)
TERMS = ((0.10, 4.0, 0.0, 20.0), (0.04, 2.5, 90.0, 60.0))
SCENE = """
[scene]
name = "relief-test"
description = "a buried point under an undulating medium sand"
seed = 4648
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
{undulation}
[[seabed.layers]]
sediment = "medium_sand"
[scattering]
interface = true
volume = false
specular = false
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


def undulation_text(terms) -> str:
    return "\n".join(f"[[seabed.undulation]]\namplitude_m = {a}\nwavelength_m = {w}\n"
                     f"direction_deg = {d}\nphase_deg = {p}" for a, w, d, p in terms)


def true_height(along, cross):
    """The scene's surface written out (scene tile frame)."""
    return sum(a * np.cos(2 * np.pi / w * (along * np.cos(np.radians(d))
                                           + cross * np.sin(np.radians(d)))
                          + np.radians(p)) for a, w, d, p in TERMS)


def _source(hw, terms):
    from sim_device.scene import SceneConfig, check_scene
    text = SCENE.format(undulation=undulation_text(terms), a=POINT[0], c=POINT[1],
                        d=POINT[2])
    return EnvironmentSource(hw, check_scene(loads(SceneConfig, text, "test scene"),
                                             "test scene"))


@pytest.fixture(scope="module")
def hw():
    return load_with_text(HardwareConfig, config_path("hardware.toml"))


@pytest.fixture(scope="module")
def undulating(hw):
    src = _source(hw, TERMS)
    return src, [src.ping(i) for i in range(src.n_pings)]


@pytest.fixture(scope="module")
def proc():
    return load(ProcessingConfig, config_path("processing.toml"))


# ------------------------------------------------------------------ the nodes alone

def test_nodes_follow_the_picks_of_a_surface_and_a_level_bed_stays_a_plane():
    rng = np.random.default_rng(5)
    a = rng.uniform(0.0, 10.0, 40000)
    c = rng.uniform(-1.5, 1.5, 40000)
    noise = rng.normal(0.0, 0.012, a.size)           # speckle's scatter of single picks
    est = relief_nodes(a, c, true_height(a, c) + 0.3 + noise)
    assert est.nodes is not None
    na, nc = est.nodes.shape
    ga = est.origin[0] + est.step[0] * np.arange(na)
    gc = est.origin[1] + est.step[1] * np.arange(nc)
    truth = true_height(ga[:, None], gc[None, :])
    inside = (ga[:, None] > 0.2) & (ga[:, None] < 9.8) & (np.abs(gc[None, :]) < 1.3)
    err = (est.nodes - truth - 0.3)[inside]
    # the median over a node's cell (+-12.5 cm) of a surface curving 4 mm over it
    assert np.sqrt(np.mean(err ** 2)) < 0.004
    assert est.sigma_m == pytest.approx(0.012 / math.sqrt(a.size / (na * nc)), rel=0.35)
    level = relief_nodes(a, c, 0.3 + noise)
    assert level.nodes is None and "a plane" in level.source
    assert level.spread_m < 3 * level.sigma_m
    few = relief_nodes(a[:MIN_PICKS - 1], c[:MIN_PICKS - 1], noise[:MIN_PICKS - 1])
    assert few.nodes is None and few.source.startswith("kept")


def test_relief_goes_to_the_imaging_and_back_from_a_summary(proc):
    rng = np.random.default_rng(6)
    a, c = rng.uniform(0, 6, 20000), rng.uniform(-1, 1, 20000)
    est = relief_nodes(a, c, true_height(a, c) + rng.normal(0, 0.01, a.size))
    summary = SpeedEstimate("unconstrained", 1500.0, 1500.0, "test",
                            slope=est.summary()).summary()
    used = applied(proc, summary)
    shape = InterfaceShape.of(used.imaging)
    assert not shape.level
    ga = est.origin[0] + est.step[0] * np.arange(est.nodes.shape[0])
    gc = est.origin[1] + est.step[1] * np.arange(est.nodes.shape[1])
    # at the nodes the shape is the nodes (rounded to 0.1 mm in the summary)
    got = shape.depth(ga[:, None] + 0 * gc[None, :], gc[None, :] + 0 * ga[:, None])
    assert np.abs(got - est.nodes).max() < 6e-5
    # between them bilinear, beyond them the edge's value
    mid = shape.depth(ga[3] + 0.5 * est.step[0], gc[2])
    assert mid == pytest.approx(0.5 * (got[3, 2] + got[4, 2]), abs=1e-12)
    assert shape.depth(ga[0] - 5.0, gc[0] - 5.0) == pytest.approx(got[0, 0], abs=1e-12)
    assert with_relief(proc, {"interface_relief": False}) is proc


def test_ragged_relief_is_refused_naming_the_key():
    text = open(config_path("processing.toml")).read().replace(
        "[imaging]", "[imaging]\ninterface_relief_m = [[0.0, 0.01], [0.02]]", 1)
    with pytest.raises(ConfigError, match=r"imaging\.interface_relief_m"):
        loads(ProcessingConfig, text, "processing.toml")


# ------------------------------------------------------------- a simulated run

@pytest.mark.slow
def test_relief_from_the_echo_matches_the_surface(hw, undulating, proc):
    src, pings = undulating
    est = estimate_relief(pings, hw, proc)
    assert est.nodes is not None, est.source
    line = TileImager(hw, proc)
    line.add(pings[0])
    na, nc = est.nodes.shape
    ga = est.origin[0] + est.step[0] * np.arange(na)
    gc = est.origin[1] + est.step[1] * np.arange(nc)
    a, c = np.meshgrid(ga, gc, indexing="ij")
    ned = line.line.tile_to_ned(np.stack([a, c, 0 * a], axis=-1))
    scene = src.line.ned_to_tile(ned)
    truth = src.undulation.height(scene[..., 0], scene[..., 1])
    # nodes under the middle of the swath, whose columns the run's pings (the array 3 m
    # ahead of the body, at 3.0-9.9 m) cover with their whole apertures
    inside = (a > 4.5) & (a < 8.5) & (np.abs(c) <= 0.5)
    err = (est.nodes - truth)[inside]
    err -= err.mean()                         # the relief is known up to one constant
    assert np.sqrt(np.mean(err ** 2)) < 0.015
    assert np.std(truth[inside]) > 0.05        # a relief the test can tell


def _depth_of_peak(hw, proc, pings):
    line = TileImager(hw, proc)
    line.add(pings[0])
    s = PointSampler(PingAccumulator(hw, proc), proc, line.line)
    near = [p for p in pings if abs(s.reach(p)[0] - POINT[0]) <= s.reach(p)[1]]
    ax = np.arange(-0.06, 0.061, 0.02)
    z = np.arange(0.35, 0.95, 0.01)
    col = np.abs(s.grid(near, POINT[0] + ax, POINT[1] + ax, z))
    i, j, k = np.unravel_index(int(np.argmax(col)), col.shape)
    if not 0 < k < z.size - 1:
        return float(z[k])
    y = np.log(col[i, j, k - 1:k + 2])
    return float(z[k] + 0.01 * 0.5 * (y[0] - y[2]) / (y[0] - 2 * y[1] + y[2]))


@pytest.mark.slow
def test_a_point_under_the_relief_at_its_depth_only_over_the_relief(hw, undulating, proc):
    src, pings = undulating
    sand = with_speed(dataclasses.replace(proc, products=None), SAND)
    est = estimate_relief(pings, hw, sand)
    over = _depth_of_peak(hw, with_relief(sand, est.summary()), pings)
    level = _depth_of_peak(hw, sand, pings)
    assert over == pytest.approx(POINT[2], abs=0.015)
    assert abs(level - POINT[2]) > 0.03


def test_a_tile_records_the_interface_it_was_imaged_over(tmp_path, proc):
    import h5py

    from svss.summary import seabed_line
    from svss_proc.tiles import _read_seabed, _write_seabed
    rng = np.random.default_rng(7)
    a, c = rng.uniform(0, 6, 20000), rng.uniform(-1, 1, 20000)
    relief = relief_nodes(a, c, true_height(a, c) + rng.normal(0, 0.01, a.size))
    seabed = SpeedEstimate("unconstrained", 1500.0, 1500.0, "test",
                           slope={"interface_slope_deg": [3.0, 5.0],
                                  "interface_slope_sigma_deg": [0.01, 0.02],
                                  "interface_slope_from": ["navigation", "echo"],
                                  **relief.summary()}).summary()
    with h5py.File(tmp_path / "t.h5", "w") as f:
        _write_seabed(f.create_group("provenance"), seabed)
    with h5py.File(tmp_path / "t.h5", "r") as f:
        back = _read_seabed(f["provenance"])
    assert back["interface_slope_deg"] == [3.0, 5.0]
    assert back["interface_relief"] is True
    assert back["interface_relief_rms_m"] == pytest.approx(relief.spread_m, abs=1e-4)
    assert "interface_relief_m" not in back            # the nodes are the manifest's
    line = seabed_line(back)
    assert "interface sloping +3.00" in line and "interface relief" in line


def test_tiles_own_speeds_and_a_run_crossing_sediments(proc):
    from svss.summary import seabed_line
    from svss_proc.seabed.per_tile import tile_speeds

    def summary(speeds):
        responses = [{"along_m": a, "cross_m": 0.0, "depth_m": 0.6, "speed_m_s": c,
                      "sigma_m_s": 30.0, "contrast_db": 25.0, "layer": None}
                     for a, c in speeds]
        w = np.full(len(speeds), 1 / 30.0 ** 2)
        mean = float((w * [c for _, c in speeds]).sum() / w.sum())
        return {"status": "estimated", "sediment_sound_speed_m_s": mean, "layers": [],
                "responses": responses}
    length = proc.tile.length_m
    one = summary([(3.0, 1760.0), (9.0, 1775.0), (length + 2.0, 1770.0),
                   (length + 7.0, 1765.0)])
    tiles, disagree = tile_speeds(one, proc.tile)
    assert [t["tile"] for t in tiles] == [0, 1] and disagree is False
    assert tiles[0]["speed_m_s"] == pytest.approx(1767.5) and tiles[0]["responses"] == 2
    assert tiles[0]["sigma_m_s"] == pytest.approx(30.0 / math.sqrt(2), abs=0.05)
    # sand then silt: each tile's own responses agree, the tiles do not
    two = summary([(3.0, 1760.0), (9.0, 1775.0), (length + 2.0, 1480.0),
                   (length + 7.0, 1470.0)])
    tiles, disagree = tile_speeds(two, proc.tile)
    assert disagree is True
    assert tiles[1]["speed_m_s"] == pytest.approx(1475.0)
    line = seabed_line({**two, "sigma_m_s": 15.0, "tiles": tiles, "tiles_disagree": True})
    assert "per tile 0: 1768 +/- 21, 1: 1475 +/- 21 (they disagree" in line
    # one tile, or a layered estimate: nothing to compare
    assert tile_speeds(summary([(3.0, 1760.0)]), proc.tile)[1] is None
    assert tile_speeds({**two, "layers": [{"thickness_m": 0.5}]}, proc.tile) == ([], None)


def test_a_relief_the_navigation_does_not_see_is_not_kept():
    """The echo's picks over a field of proud objects are the objects: where the body's
    track crosses them, the navigation's bed stays level, and a plane is kept; a real
    relief agrees with the navigation's bed along the track and is kept."""
    rng = np.random.default_rng(8)
    a, c = rng.uniform(0, 8, 30000), rng.uniform(-1, 1, 30000)
    z = true_height(a, c) + rng.normal(0, 0.005, a.size)
    track = np.linspace(0.5, 7.5, 70)
    on_track = np.column_stack([track, np.zeros_like(track), true_height(track, 0 * track)])
    kept = relief_nodes(a, c, z, bed=on_track)
    assert kept.nodes is not None, kept.source
    level = np.column_stack([track, np.zeros_like(track), np.zeros_like(track)])
    refused = relief_nodes(a, c, z, bed=level)
    assert refused.nodes is None and "navigation's bed" in refused.source
