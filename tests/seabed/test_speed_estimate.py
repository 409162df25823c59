"""The sediment speed from the echoes, end to end: a run of the seed's medium sand
(1767 m/s) with buried points, simulated with the full 80-channel array 5.8 km from the
survey origin, recorded to a raw run and processed by ``svss process``'s
:func:`~svss_proc.run_worker.process_raw` with a configuration that says 1500 m/s; and
a sediment with nothing buried in it (interface and volume scattering only), where the
configured speed must be kept, saying why."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sim_device.environment_source import EnvironmentSource
from svss_daq.config import (HardwareConfig, ProcessingConfig, config_path, load,
                             load_with_text, loads)
from svss_daq.rawfile import RawRunWriter
from svss_proc.run_worker import process_raw
from svss_proc.seabed.speed import estimate_speed
from svss_proc.tiles import read_tile_header
from svss.summary import format_summary, summarise

SAND = 1767.0
SCENE = """
[scene]
name = "seabed-test"
description = "buried points in medium sand"
seed = 4646
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
n_pings = {n}
[noise]
electronic_rms_counts = 20.0
[[seabed.layers]]
sediment = "medium_sand"
[scattering]
interface = {scat}
volume = {scat}
specular = true
interface_model = "apl_uw"
interface_density_per_m2 = 1000.0
volume_density_per_m3 = 4000.0
volume_max_depth_m = 1.2
cell_m = 0.25
precision = "float64"
scatterers_per_resolution_cell = 2.0
volume_below_noise_db = 0.0
"""
POINTS = [(4.6, 0.2, 0.5), (5.4, -0.25, 0.8)]   # fully in the aperture


def _scene(n: int, scat: bool, points):
    from sim_device.scene import SceneConfig, check_scene
    text = SCENE.format(n=n, scat=str(scat).lower())
    for a, y, z in points:
        text += (f"[[points]]\nalong_m = {a}\ncross_m = {y}\ndepth_m = {z}\n"
                 "target_strength_db = -20.0\n")
    return check_scene(loads(SceneConfig, text, "test scene"), "test scene")


@pytest.fixture(scope="module")
def hw():
    return load_with_text(HardwareConfig, config_path("hardware.toml"))


@pytest.fixture(scope="module")
def sand_run(hw, tmp_path_factory):
    run = tmp_path_factory.mktemp("seabed") / "sand.h5"
    with RawRunWriter(run, hw) as rec:
        for p in EnvironmentSource(hw, _scene(80, False, POINTS)):
            rec.append(p)
    return run


@pytest.mark.slow
def test_process_images_buried_points_at_their_depth_with_the_estimated_speed(
        tmp_path, sand_run):
    run = sand_run
    processing = load_with_text(ProcessingConfig, config_path("processing-demo.toml"))
    assert processing.value.seabed is None            # the shipped [seabed] settings
    out = tmp_path / "tiles"
    files = process_raw(run, out, processing, sediment_speed="estimate")
    seabed = json.loads((out / "manifest.json").read_text())["seabed"]
    assert seabed["status"] == "estimated" and seabed["configured_m_s"] == \
        processing.value.imaging.sediment_sound_speed_m_s
    assert abs(seabed["sediment_sound_speed_m_s"] / SAND - 1) < 0.02, seabed
    assert 0 < seabed["sigma_m_s"] < 0.05 * SAND and seabed["disagrees"]
    assert len(seabed["responses"]) >= 1 and not seabed["layers"]
    tiles = [p for p in files if p.suffix == ".h5" and p.name.startswith("tile_")]
    depths = []
    for t in tiles:
        head = read_tile_header(t)
        assert head["seabed"]["status"] == "estimated"
        assert head["seabed"]["sediment_sound_speed_m_s"] == pytest.approx(
            seabed["sediment_sound_speed_m_s"])
        depths += [float(d["depth_m"]) for d in head["detections"]]
        assert "estimated from" in format_summary(summarise(t))
    for _, _, z in POINTS:          # each point detected at its depth (the tile voxel)
        assert min(abs(d - z) for d in depths) <= 0.02 + 0.02 * z, (z, depths)


@pytest.mark.slow
def test_nothing_buried_keeps_the_configured_speed_and_says_why(hw):
    src = EnvironmentSource(hw, _scene(40, True, []))
    pings = [src.ping(i) for i in range(src.n_pings)]
    proc = load(ProcessingConfig, config_path("processing.toml"))
    est = estimate_speed(pings, hw, proc)
    assert est.status == "unconstrained" and est.speed_m_s == 1500.0
    assert "isolated" in est.reason and not est.disagrees
    assert "not constrained" in est.description and "1500" in est.description
    assert est.summary()["sigma_m_s"] is None
    assert np.isfinite(est.configured_m_s)


@pytest.mark.slow
def test_batch_plans_a_run_with_its_estimate_and_images_with_it(sand_run):
    """svss batch's plan carries the run's estimate to every tile task, which images
    with it (:func:`~svss_proc.seabed.speed.applied`), and says nothing of a speed where
    asked for the configured one."""
    from svss_proc.batch.plan import plan_run
    from svss_proc.seabed.speed import applied
    processing = load_with_text(ProcessingConfig, config_path("processing-demo.toml"))
    plan = plan_run("sand", "sand", [sand_run], processing, sediment_speed="estimate")
    assert plan.seabed["status"] == "estimated"
    assert abs(plan.seabed["sediment_sound_speed_m_s"] / SAND - 1) < 0.02
    assert plan.tiles and all(t.seabed == plan.seabed for t in plan.tiles)
    used = applied(processing.value, plan.tiles[0].seabed)
    assert used.imaging.sediment_sound_speed_m_s == plan.seabed["sediment_sound_speed_m_s"]
    assert used.imaging.delays == "table"         # the demo's straight rays refract now
    plain = plan_run("sand", "sand", [sand_run], processing, sediment_speed="configured")
    assert plain.seabed["status"] == "configured"
    assert applied(processing.value, plain.tiles[0].seabed) == processing.value
