"""A shell and a rock buried alike (config/scenes/shell_slab_silt.toml: a TNT-filled
steel shell and a granite slab, centres 0.2 m deep in silt over clay) simulated, imaged
and processed with the shipped configuration: both are contacts, and their features
tell them apart as the elastic physics says (the shell rings: more late energy than
specular; the slab's flat face answers near its normal only, the shell over the whole
aperture). docs/contact_features.md, "Measured on simulated shells and slabs".

Extended (minutes: 80 pings with seabed reverberation and a ringing shell); the default
run checks each feature against synthetic images (test_contact_features.py)."""

from __future__ import annotations

import csv
import itertools
import math

import numpy as np
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
        src = EnvironmentSource(hardware, scene)
        for p in itertools.islice(iter(src), scene.track.n_pings):
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
    # resonance lines from the pings (svss process; [products.spectra]): the shell's late
    # response stands over the silt's and its line lies at a peak of the simulator's
    # own modal series for this shell in this silt (21.2, 25.0, 27.85, 29.1, 32.8 kHz),
    # within two of its standard errors (0.3 kHz at least)
    with open(out / "contacts.csv") as fh:
        rows = list(csv.DictReader(fh))
    near = min(rows, key=lambda r: math.hypot(float(r["along_m"]) - SHELL_ALONG_M,
                                              float(r["cross_m"])))
    assert float(near["late_over_background_db"]) >= 3.0 and int(near["resonance_pings"]) >= 10
    f_line, f_err = float(near["resonance_hz"]), float(near["resonance_err_hz"])
    peaks = shell_peaks(src)
    assert min(abs(f_line - p) for p in peaks) < max(2 * f_err, 300.0), (f_line, peaks)


SHELL_ALONG_M = 5.5


def shell_peaks(src) -> list[float]:
    """The local maxima of the shell's monostatic form function |f(pi)| in the band
    20-35 kHz, from the simulator's modal series (its host: the silt it lies in)."""
    from sim_device.targets.shells import shell_backscatter
    [shell] = [t for t in src.targets if t.cfg.kind == "shell"]
    f = np.arange(19000.0, 36000.0, 25.0)
    a = np.abs(shell_backscatter(f, shell.radius, shell.thickness, shell.host,
                                 shell.material, shell.fill))
    k = np.flatnonzero((a[1:-1] > a[:-2]) & (a[1:-1] >= a[2:])) + 1
    return [float(x) for x in f[k] if 20000.0 <= x <= 35000.0]
