"""A shell and a rock buried alike (config/scenes/shell_slab_silt.toml: a TNT-filled
steel shell and a granite slab, centres 0.2 m deep in silt over clay) simulated, imaged
and processed with the shipped configuration: both are contacts, and their features
tell them apart as the elastic physics says (the shell rings: more late energy than
specular; the slab's flat face answers near its normal only, the shell over the whole
aperture). docs/contact_features.md, "Measured on simulated shells and slabs".

Extended (minutes: 80 pings with seabed reverberation and a ringing shell); the default
run checks each feature against synthetic images (test_contact_features.py)."""

from __future__ import annotations

import itertools
import math

import pytest

from svss.score import score_tiles
from svss_daq.config import ProcessingConfig, config_path, loaded_from_text

SCENE = config_path("scenes/shell_slab_silt.toml")


@pytest.mark.extended
def test_a_buried_shell_and_slab_told_apart_by_their_features(tmp_path, hardware):
    from sim_device.environment_source import EnvironmentSource
    from sim_device.scene import load_scene
    from svss_daq.rawfile import RawRunWriter
    from svss_proc.run_worker import process_raw
    scene = load_scene(SCENE)
    raw = tmp_path / "run.h5"
    with RawRunWriter(raw, hardware, run_attrs={}) as rec:
        for p in itertools.islice(iter(EnvironmentSource(hardware, scene)),
                                  scene.track.n_pings):
            rec.append(p)
    proc = loaded_from_text(ProcessingConfig, open(config_path("processing.toml")).read(),
                            "processing.toml")
    out = tmp_path / "tiles"
    process_raw(raw, out, proc)
    r = score_tiles(out, SCENE)
    feats = {}
    for t in r["truth"]:
        assert t["status"] == "detected", t
        feats[t["fields"]["kind"]] = r["detections"][t["detection"]]
    shell, slab = feats["shell"], feats["disc"]
    # late-to-specular: the shell's ringing outweighs its specular echo, the slab's not
    gap = shell["late_to_specular_db"] - slab["late_to_specular_db"]
    err = math.hypot(shell["late_to_specular_err_db"], slab["late_to_specular_err_db"])
    assert gap > 3.0 and gap > 3 * err, (shell, slab)
    # aspect: the slab's face answers within a few degrees of its normal
    assert slab["aspect_width_deg"] < 5.0
    assert shell["aspect_width_deg"] > slab["aspect_width_deg"] + 3.0 + 3 * math.hypot(
        shell["aspect_width_err_deg"], slab["aspect_width_err_deg"])
    # both tails reach beyond the objects' peak windows and are measured
    for f in (shell, slab):
        assert f["feature_flags"] & 1 == 0 and f["tail_extent_m"] > 0.1
