"""Each contact's features in the products (issue 51): the tile's detections, the tile
file (and an older tile without them), the run's contacts (CSV, GeoJSON, GeoPackage) and
the quicklook, from a tile of speckle with a ringing point planted in it."""

from __future__ import annotations

import csv
import json

import h5py
import matplotlib.image
import numpy as np
import pytest

from svss_daq.config import ConfigError, ProcessingConfig, loaded_from_text
from svss_daq.frames import TrackLine
from svss_proc.imaging.grid import tile_grid
from svss_proc.products.chain import compute_products, save_tile
from svss_proc.products.contact_features import FEATURE_FILL, NO_TAIL, SHORT_FIT
from svss_proc.products.run_products import (CONTACTS_CSV, CONTACTS_GEOJSON, CONTACTS_GPKG,
                                             write_run_products)
from svss_proc.tiles import read_tile

from . import VOXEL, make_tile, plant, rayleigh_median, speckle

FEATURES = """
[products.features]
enabled = true
footprint_min_m = [0.06, 0.06]
footprint_max_m = [0.30, 0.30]
peak_window_m = 0.06
tail_window_m = 0.3
background_within_db = 3.0
below_run_m = 0.06
reference_boxes = 4
reference_gap_m = 0.2
min_fit_points = 4
profile_m = 0.6
aspect_window_m = 0.6
"""
ORIGIN = (41.5240, -70.6710, 0.0)
DECAY = 40.0                     # dB per metre of the planted tail


@pytest.fixture(scope="module")
def processing(demo_processing):
    return loaded_from_text(ProcessingConfig, demo_processing.text + FEATURES, "features")


@pytest.fixture(scope="module")
def ringing_tile(demo_processing):
    """A demo-sized tile of speckle: a ringing point (40 dB, a tail 25 dB over the
    background's mean below it, falling 40 dB/m) and a plain point (40 dB, no tail)."""
    grid = tile_grid(demo_processing.value.tile, 0)
    axes = (grid.along, grid.cross, grid.depth)
    rng = np.random.default_rng(51)
    img = speckle(grid.shape, rng)
    ring, plain = (grid.along[50], grid.cross[30], grid.depth[10]), \
        (grid.along[110], grid.cross[20], grid.depth[12])
    for t in (ring, plain):
        plant(img, axes, t, rayleigh_median(1.0) * 10 ** (40 / 20))
    d = grid.depth - ring[2]
    amp = np.where(d > 0.06, np.sqrt(2.0 * 10 ** ((25.0 - DECAY * (d - 0.06)) / 10)), 0.0)
    ph = np.exp(2j * np.pi * rng.random((3, 3, grid.depth.size)))
    img[49:52, 29:32, :] += (amp[None, None, :] * ph).astype(np.complex64)
    tile = make_tile(grid, TrackLine((0.0, 0.0), 0.0, 2.5), img, pings=range(0, 30))
    return tile, ring, plain


def test_the_features_config_is_checked_naming_file_and_key(demo_processing):
    bad = FEATURES.replace("footprint_max_m = [0.30, 0.30]", "footprint_max_m = [0.30]")
    with pytest.raises(ConfigError, match=r"bad\.toml.*products\.features\.footprint_max_m"):
        loaded_from_text(ProcessingConfig, demo_processing.text + bad, "bad.toml")
    bad = FEATURES.replace("footprint_min_m = [0.06, 0.06]", "footprint_min_m = [0.6, 0.06]")
    with pytest.raises(ConfigError, match=r"products\.features\.footprint_min_m"):
        loaded_from_text(ProcessingConfig, demo_processing.text + bad, "bad.toml")
    bad = FEATURES.replace("below_run_m = 0.06\n", "")
    with pytest.raises(ConfigError, match=r"products\.features\.below_run_m"):
        loaded_from_text(ProcessingConfig, demo_processing.text + bad, "bad.toml")
    # omitted: no features measured
    assert demo_processing.value.products.features is None


def test_the_chain_measures_each_contacts_tail(ringing_tile, processing):
    tile, ring, plain = ringing_tile
    g = tile.grid
    p = compute_products(tile.image, (g.along, g.cross, g.depth), VOXEL,
                         processing.value.products)
    det = p.detections
    pos = np.stack([det["along_m"], det["cross_m"], det["depth_m"]], axis=1)
    i = int(np.argmin(np.linalg.norm(pos - ring, axis=1)))
    j = int(np.argmin(np.linalg.norm(pos - plain, axis=1)))
    assert np.linalg.norm(pos[i] - ring) < 0.05 and np.linalg.norm(pos[j] - plain) < 0.05
    # the ringing point: its decay within 3 standard errors (the 3-D median background
    # of the chain, not the speckle's known level)
    d, e = det["tail_decay_db_per_m"][i], det["tail_decay_err_db_per_m"][i]
    assert abs(d - DECAY) < 3 * e, (d, e)
    assert det["late_to_specular_db"][i] > det["late_to_specular_db"][j] + 15
    # the plain point: no tail (its main lobe, 40 dB over the background, may outlast
    # the 6 cm peak window by a voxel or two: too short to fit)
    assert det["feature_flags"][j] & (NO_TAIL | SHORT_FIT)
    assert np.isnan(det["tail_decay_db_per_m"][j]) and det["tail_extent_m"][j] < 0.12
    assert p.tail_profiles.shape == (len(det), int(round(0.6 / VOXEL)) + 1)
    assert p.tail_profiles[i, 5] > 10.0 and abs(p.tail_profile_step_m - VOXEL) < 1e-9


def test_an_empty_tile_has_no_features(demo_processing, processing, hardware, tmp_path):
    grid = tile_grid(demo_processing.value.tile, 0)
    img = speckle(grid.shape, np.random.default_rng(3))
    tile = make_tile(grid, TrackLine((0.0, 0.0), 0.0, 2.5), img, pings=range(0, 30))
    h5, png = save_tile(tile, tmp_path, hardware, processing)
    t = read_tile(h5)
    assert len(t["detections"]) == 0 and t["tail_profile_db"].shape[0] == 0
    assert png.stat().st_size > 0


def test_tile_file_run_contacts_and_quicklook_carry_the_features(
        ringing_tile, processing, hardware, tmp_path):
    tile, ring, _ = ringing_tile
    h5, png = save_tile(tile, tmp_path, hardware, processing)
    t = read_tile(h5)
    det = t["detections"]
    assert np.isfinite(det["tail_decay_db_per_m"]).sum() >= 1
    assert t["tail_profile_db"].shape[0] == len(det)
    img = matplotlib.image.imread(png)
    assert img.ndim == 3 and img.shape[0] > 400
    files = write_run_products(tmp_path, tmp_path / "run", origin=ORIGIN)
    names = {f.name for f in files}
    assert {CONTACTS_CSV, CONTACTS_GEOJSON, CONTACTS_GPKG} <= names
    with open(tmp_path / "run" / CONTACTS_CSV) as f:
        rows = list(csv.DictReader(f))
    k = int(np.argmax([float(r["tail_decay_db_per_m"] or "nan") > 0 for r in rows]))
    ringing = rows[k]
    assert abs(float(ringing["tail_decay_db_per_m"]) - DECAY) < \
        3 * float(ringing["tail_decay_err_db_per_m"])
    assert ringing["feature_flags"] == "0" and ringing["feature_notes"] == ""
    # the aspect: measured (save_tile gives the band's wavenumber). The planted blob is
    # in phase, a Gaussian of 1.2 voxels along-track: its power spectrum in k_x is a
    # Gaussian of deviation 1 / (sigma sqrt 2), centred; widened by the Hann window's
    k = 2 * np.pi * hardware.value.waveform.center_hz / 1500.0
    sig = np.degrees(np.arcsin(1.0 / (1.2 * VOXEL * np.sqrt(2.0)) / (2.0 * k)))
    win = np.degrees(2 * np.pi / (np.sqrt(3.0) * 31 * VOXEL) / (2.0 * k))
    assert abs(float(ringing["aspect_centre_deg"])) < 0.5
    assert float(ringing["aspect_width_deg"]) == pytest.approx(np.hypot(sig, win), abs=0.5)
    assert any("no tail" in r["feature_notes"] or "too short" in r["feature_notes"]
               for r in rows)
    gj = json.loads((tmp_path / "run" / CONTACTS_GEOJSON).read_text())
    props = [f["properties"] for f in gj["features"] if f["properties"]["kind"] == "contact"]
    assert all("late_to_specular_db" in p and "feature_flags" in p for p in props)
    import pyogrio.raw
    _, _, _, data = pyogrio.raw.read(str(tmp_path / "run" / CONTACTS_GPKG),
                                     layer="contacts")
    meta = pyogrio.read_info(str(tmp_path / "run" / CONTACTS_GPKG), layer="contacts")
    cols = list(meta["fields"])
    decay = data[cols.index("tail_decay_db_per_m")]
    assert np.nanmax(decay) == pytest.approx(float(ringing["tail_decay_db_per_m"]), abs=0.01)
    assert any(("no tail" in n or "too short" in n) for n in data[cols.index("feature_notes")])


def test_a_tile_written_before_the_features_reads_with_their_fill_values(
        ringing_tile, processing, hardware, tmp_path):
    tile, _, _ = ringing_tile
    h5, _ = save_tile(tile, tmp_path, hardware, processing)
    with h5py.File(h5, "r+") as f:
        for name in [*FEATURE_FILL, "tail_profile_db"]:
            del f["detections"][name]
    t = read_tile(h5)
    assert len(t["detections"]) >= 2 and "tail_profile_db" not in t
    assert np.all(t["detections"]["feature_flags"] == -1)
    assert np.all(np.isnan(t["detections"]["tail_decay_db_per_m"]))
    with open(write_run_products(tmp_path, tmp_path / "run")[0]) as f:
        rows = list(csv.DictReader(f))
    assert rows and all(r["tail_decay_db_per_m"] == "" and r["feature_flags"] == "-1"
                        for r in rows)
