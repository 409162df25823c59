"""The Sayers-like test field (config/scenes/sayers_field.toml: shot puts, aluminium
cylinders and flat rocks, proud and buried, in silt over clay) simulated, imaged with
the shipped processing (its tiles reach 20 cm above the interface, so that the objects
resting on it are imaged whole) and scored: every target and clutter object detected
within a voxel plus its size of its true position, and no false alarm.

Extended (minutes: 260 pings with seabed reverberation); the default run checks the same
detection rule on the six points in water (test_run_products.py)."""

from __future__ import annotations

import numpy as np
import pytest

from svss.score import score_tiles
from svss_daq.config import ProcessingConfig, config_path, loaded_from_text

SCENE = config_path("scenes/sayers_field.toml")


def field_processing():
    """The shipped processing: its tiles reach 20 cm above the interface."""
    loaded = loaded_from_text(ProcessingConfig, open(config_path("processing.toml")).read(),
                              "processing.toml")
    assert loaded.value.tile.top_m <= -0.2
    return loaded


def object_size_m(fields: dict) -> float:
    """An object's largest dimension, m."""
    size = 2.0 * fields["radius_m"]
    return max(size, fields.get("length_m") or 0.0)


@pytest.mark.extended
def test_test_field_every_object_detected_no_false_alarm(tmp_path, hardware):
    import itertools

    from sim_device.environment_source import EnvironmentSource
    from sim_device.scene import load_scene
    from svss_daq.rawfile import RawRunWriter
    from svss_proc.run_worker import process_raw
    scene = load_scene(SCENE)
    raw = tmp_path / "field.h5"
    with RawRunWriter(raw, hardware, run_attrs={}) as rec:
        for p in itertools.islice(iter(EnvironmentSource(hardware, scene)),
                                  scene.track.n_pings):
            rec.append(p)
    proc = field_processing()
    out = tmp_path / "tiles"
    process_raw(raw, out, proc)
    voxel = proc.value.tile.voxel_m
    # the radius: no object is further than a voxel plus its size from its contact
    sizes = [object_size_m(t["fields"]) for t in _truth(scene)]
    r = score_tiles(out, SCENE, radius_m=voxel + max(sizes))
    s = r["summary"]
    assert s["outside"] == 0 and s["truth"] == 9
    assert s["false_alarms"] == 0, [d for d in r["detections"]
                                    if d.get("status") == "false alarm"]
    assert s["hits"] == 9
    for t in r["truth"]:
        assert t["distance_m"] <= voxel + object_size_m(t["fields"]), t


def _truth(scene):
    from svss.score import scene_truth
    return scene_truth(scene)


def test_object_sizes():
    from sim_device.scene import load_scene
    sizes = sorted(object_size_m(t["fields"]) for t in _truth(load_scene(SCENE)))
    assert sizes[0] == pytest.approx(0.102) and sizes[-1] == pytest.approx(0.61)
    assert np.all(np.asarray(sizes) > 0)
