"""Each contact called man-made, natural or undecided (issue 51; svss_proc.products.classify):
the logistic model against hand-computed values, undecided on missing or flagged
features, the configuration's errors naming file and key, and the class carried by the
tile file, the run's contacts (CSV, GeoJSON, GeoPackage) and the quicklook's list."""

from __future__ import annotations

import csv
import dataclasses
import json
import math

import h5py
import numpy as np
import pytest

from svss_daq.config import (ClassifyConfig, ConfigError, PingClassifyConfig, ProcessingConfig,
                             loaded_from_text)
from svss_daq.config_processing import CLASSIFY_FEATURES, PING_FEATURES
from svss_proc.products import detect
from svss_proc.products.chain import save_tile
from svss_proc.products.classify import (CLASS_FILL, FROM_IMAGE, FROM_PINGS, MANMADE,
                                         NATURAL, NOT_CLASSIFIED, UNDECIDED,
                                         call_with_pings, classify, logistic,
                                         probability, with_class)
from svss_proc.products.contact_features import FEATURE_NAMES, LATE_UPPER_BOUND, NO_ASPECT
from svss_proc.products.quicklook import _detection_lines
from svss_proc.products.run_products import (CONTACTS_CSV, CONTACTS_GEOJSON, CONTACTS_GPKG,
                                             write_run_products)
from svss_proc.tiles import read_tile

from .test_contact_features_products import FEATURES, ORIGIN, ringing_tile  # noqa: F401

CFG = ClassifyConfig(enabled=True, features=("aspect_width_deg", "late_to_specular_db"),
                     mean=(6.0, -3.0), scale=(3.0, 4.0), coefficients=(2.0, 1.0),
                     intercept=-0.5, manmade_above=0.6, natural_below=0.4,
                     undecided_flags=(NO_ASPECT,))

CLASSIFY = """
[products.classify]
enabled = true
features = ["aspect_width_deg"]
mean = [0.0]
scale = [1.0]
coefficients = [0.0]
intercept = 2.0
manmade_above = 0.6
natural_below = 0.4
undecided_flags = [32]
"""


def table(rows: list[tuple[float, float, int]]) -> np.ndarray:
    """Detections with (aspect_width_deg, late_to_specular_db, feature_flags)."""
    out = np.zeros(len(rows), dtype=detect.DTYPE)
    for r, (w, ls, flags) in zip(out, rows):
        r["aspect_width_deg"], r["late_to_specular_db"], r["feature_flags"] = w, ls, flags
    return out


def test_the_model_is_the_logistic_of_the_standardised_features():
    # hand-computed: z = ((9 - 6) / 3, (1 + 3) / 4) = (1, 1), t = -0.5 + 2 + 1 = 2.5,
    # p = 1 / (1 + e^-2.5) = 0.924142; at the means t = -0.5, p = 0.377541;
    # z = (-1, -1): t = -3.5, p = 0.029312
    p = probability(np.array([[9.0, 1.0], [6.0, -3.0], [3.0, -7.0]]), CFG)
    np.testing.assert_allclose(p, [0.924142, 0.377541, 0.029312], atol=2e-6)
    assert p[0] == pytest.approx(1 / (1 + math.exp(-2.5)), rel=1e-12)
    cls, pm = classify(table([(9.0, 1.0, 0), (6.0, -3.0, 0), (3.0, -7.0, 0),
                              (6.6, -3.0, LATE_UPPER_BOUND)]), CFG)
    # the fourth: t = -0.5 + 0.4 = -0.1, p = 0.475021: between the thresholds
    assert cls.tolist() == [MANMADE, NATURAL, NATURAL, UNDECIDED]
    assert cls.dtype == np.int8 and pm.dtype == np.float32
    assert float(pm[3]) == pytest.approx(0.475021, abs=1e-6)
    # a flag not among undecided_flags leaves the class as the probability says
    assert classify(table([(9.0, 1.0, LATE_UPPER_BOUND)]), CFG)[0][0] == MANMADE


def test_thresholds_and_extremes():
    assert logistic(np.array([-1000.0, 0.0, 1000.0])).tolist() == [0.0, 0.5, 1.0]
    cfg = dataclasses.replace(CFG, manmade_above=0.9, natural_below=0.1)
    cls, _ = classify(table([(9.0, 1.0, 0), (6.0, -3.0, 0), (3.0, -7.0, 0)]), cfg)
    assert cls.tolist() == [MANMADE, UNDECIDED, NATURAL]


def test_a_missing_or_flagged_feature_leaves_the_contact_undecided():
    cls, p = classify(table([(np.nan, 1.0, 0), (9.0, np.nan, 0), (9.0, 1.0, NO_ASPECT),
                             (9.0, 1.0, -1), (9.0, 1.0, 0)]), CFG)
    assert cls.tolist() == [UNDECIDED] * 4 + [MANMADE]
    assert np.all(np.isnan(p[:4])) and np.isfinite(p[4])
    # an empty table
    cls, p = classify(detect.empty(), CFG)
    assert cls.size == 0 and p.size == 0
    out = with_class(table([(9.0, 1.0, 0)]), CFG)
    assert out["class"][0] == MANMADE and out["p_manmade"][0] == pytest.approx(0.924142,
                                                                                abs=1e-6)


def test_the_features_a_model_may_use_are_contact_features():
    assert set(CLASSIFY_FEATURES) <= set(FEATURE_NAMES)
    # a detection table starts not classified
    assert detect.empty().dtype["class"] == np.int8
    assert CLASS_FILL["class"] == NOT_CLASSIFIED


@pytest.mark.parametrize("old,new,key", [
    ("mean = [0.0]", "mean = [0.0, 1.0]", r"products\.classify\.mean"),
    ("scale = [1.0]", "scale = [0.0]", r"products\.classify\.scale"),
    ('features = ["aspect_width_deg"]', 'features = ["aspect_width_deg", "colour"]',
     r"products\.classify\.features\[1\]"),
    ("natural_below = 0.4", "natural_below = 0.7", r"products\.classify\.natural_below"),
    ("coefficients = [0.0]\n", "", r"products\.classify\.coefficients"),
    ("intercept = 2.0", 'intercept = "high"', r"products\.classify\.intercept"),
])
def test_config_errors_name_the_file_and_key(demo_processing, old, new, key):
    assert old in CLASSIFY
    with pytest.raises(ConfigError, match=r"bad\.toml.*" + key):
        loaded_from_text(ProcessingConfig, demo_processing.text + FEATURES
                         + CLASSIFY.replace(old, new), "bad.toml")


def test_the_shipped_configuration_classifies():
    from svss_daq.config import config_path, load
    cfg = load(ProcessingConfig, config_path("processing.toml"))
    c = cfg.products.classify
    assert c is not None and c.enabled and cfg.products.features.enabled
    assert len(c.features) == len(c.coefficients) and c.natural_below <= c.manmade_above


def test_the_class_in_the_tile_file_run_contacts_and_quicklook(
        ringing_tile, demo_processing, hardware, tmp_path):  # noqa: F811
    processing = loaded_from_text(ProcessingConfig, demo_processing.text + FEATURES
                                  + CLASSIFY, "classify")
    tile, _, _ = ringing_tile
    h5, png = save_tile(tile, tmp_path, hardware, processing)
    det = read_tile(h5)["detections"]
    # the model: p = logistic(2) = 0.880797 wherever the aspect is measured
    measured = np.isfinite(det["aspect_width_deg"]) & (det["feature_flags"] >= 0) \
        & ((det["feature_flags"] & NO_ASPECT) == 0)
    assert measured.sum() >= 1
    assert np.all(det["class"][measured] == MANMADE)
    np.testing.assert_allclose(det["p_manmade"][measured], 0.880797, atol=1e-6)
    assert np.all(det["class"][~measured] == UNDECIDED)
    text = _detection_lines(det)
    assert "class" in text.splitlines()[0] and "man-made  0.88" in text
    write_run_products(tmp_path, tmp_path / "run", origin=ORIGIN)
    with open(tmp_path / "run" / CONTACTS_CSV) as f:
        rows = list(csv.DictReader(f))
    assert any(r["class"] == "man-made" and r["p_manmade"] == "0.881" for r in rows)
    assert all(r["class"] in ("man-made", "undecided") for r in rows)
    gj = json.loads((tmp_path / "run" / CONTACTS_GEOJSON).read_text())
    props = [f["properties"] for f in gj["features"] if f["properties"]["kind"] == "contact"]
    assert any(p["class"] == "man-made" and p["p_manmade"] == 0.881 for p in props)
    import pyogrio
    import pyogrio.raw
    _, _, _, data = pyogrio.raw.read(str(tmp_path / "run" / CONTACTS_GPKG), layer="contacts")
    cols = list(pyogrio.read_info(str(tmp_path / "run" / CONTACTS_GPKG),
                                  layer="contacts")["fields"])
    assert "man-made" in list(data[cols.index("class")])
    # a tile written before the classification: not classified, empty in the contacts
    with h5py.File(h5, "r+") as f:
        for name in CLASS_FILL:
            del f["detections"][name]
    det = read_tile(h5)["detections"]
    assert np.all(det["class"] == NOT_CLASSIFIED) and np.all(np.isnan(det["p_manmade"]))
    assert "class" not in _detection_lines(det).splitlines()[0]
    write_run_products(tmp_path, tmp_path / "run2")
    with open(tmp_path / "run2" / CONTACTS_CSV) as f:
        assert all(r["class"] == "" and r["p_manmade"] == "" for r in csv.DictReader(f))


PING_CFG = PingClassifyConfig(
    enabled=True, features=("aspect_width_deg", "late_to_specular_db",
                            "late_over_background_db"),
    mean=(6.0, -3.0, 1.0), scale=(3.0, 4.0, 2.0), coefficients=(2.0, 1.0, -1.0),
    intercept=-0.5, manmade_above=0.6, natural_below=0.4, undecided_flags=(NO_ASPECT,))


def _contact(aspect, late, lob, flags=0):
    return {"aspect_width_deg": aspect, "late_to_specular_db": late,
            "late_over_background_db": lob, "feature_flags": flags,
            "class": "man-made", "p_manmade": 0.9, "class_from": "image"}


def test_the_run_model_calls_again_where_the_pings_were_measured():
    # hand-computed: z = (1, 1, 1): t = -0.5 + 2 + 1 - 1 = 1.5, p = 0.817574;
    # z = (1, 1, 3): t = -0.5, p = 0.377541
    contacts = [_contact(9.0, 1.0, 3.0), _contact(9.0, 1.0, 7.0),
                _contact(9.0, 1.0, math.nan), _contact(9.0, 1.0, 3.0, NO_ASPECT),
                _contact(9.0, 1.0, "")]
    assert call_with_pings(contacts, PING_CFG) == 3
    assert [c["class"] for c in contacts] == ["man-made", "natural", "man-made",
                                              "undecided", "man-made"]
    assert contacts[0]["p_manmade"] == pytest.approx(0.818, abs=5e-4)
    assert contacts[1]["p_manmade"] == pytest.approx(0.378, abs=5e-4)
    assert math.isnan(contacts[3]["p_manmade"])
    assert [c["class_from"] for c in contacts] == [FROM_PINGS] * 2 + [FROM_IMAGE] \
        + [FROM_PINGS, FROM_IMAGE]
    # the image's call stands where the pings were not read
    assert contacts[2]["p_manmade"] == 0.9 and contacts[4]["p_manmade"] == 0.9
    # a model without a ping feature calls nothing again
    assert call_with_pings([_contact(9.0, 1.0, 3.0)], dataclasses.replace(
        PING_CFG, features=CFG.features, mean=CFG.mean, scale=CFG.scale,
        coefficients=CFG.coefficients)) == 0


CLASSIFY_PINGS = """
[products.classify_pings]
enabled = true
features = ["aspect_width_deg", "late_over_background_db"]
mean = [0.0, 0.0]
scale = [1.0, 1.0]
coefficients = [0.0, -1.0]
intercept = 2.0
manmade_above = 0.6
natural_below = 0.4
undecided_flags = [32]
"""


def test_only_the_run_model_may_use_the_pings_features(demo_processing):
    assert set(PING_FEATURES).isdisjoint(CLASSIFY_FEATURES)
    with pytest.raises(ConfigError, match=r"bad\.toml.*products\.classify\.features\[0\]"):
        loaded_from_text(ProcessingConfig, demo_processing.text + FEATURES + CLASSIFY.replace(
            '"aspect_width_deg"', '"late_over_background_db"'), "bad.toml")
    no_ping = CLASSIFY_PINGS.replace('"late_over_background_db"', '"late_to_specular_db"')
    with pytest.raises(ConfigError, match=r"bad\.toml.*products\.classify_pings\.features"
                       r".*none of the pings' features"):
        loaded_from_text(ProcessingConfig, demo_processing.text + FEATURES + CLASSIFY
                         + no_ping, "bad.toml")
    cfg = loaded_from_text(ProcessingConfig, demo_processing.text + FEATURES + CLASSIFY
                           + CLASSIFY_PINGS, "good.toml").value
    assert cfg.products.classify_pings.features[1] == "late_over_background_db"
    from svss_daq.config import config_path, load
    shipped = load(ProcessingConfig, config_path("processing.toml")).products
    assert shipped.classify_pings is not None and shipped.classify_pings.enabled
    assert set(shipped.classify_pings.features) & set(PING_FEATURES)


def test_the_run_calls_with_the_pings_in_every_contact_format(
        ringing_tile, demo_processing, hardware, tmp_path):  # noqa: F811
    """The run's contacts whose pings were read (the spectra step of svss process) are
    called by [products.classify_pings]: p = logistic(2 - 6.25) = 0.014064, natural,
    where the image's model said man-made (0.881); the others keep the image's call. A
    rewrite from the tiles alone calls them the same from the kept columns."""
    processing = loaded_from_text(ProcessingConfig, demo_processing.text + FEATURES
                                  + CLASSIFY + CLASSIFY_PINGS, "classify")
    tile, _, _ = ringing_tile
    save_tile(tile, tmp_path, hardware, processing)

    def measured(contacts, line):
        # the pings read for the first contact whose aspect was measured
        first = next(k for k, c in enumerate(contacts) if c["class"] == "man-made")
        return [{"resonance_hz": math.nan, "resonance_err_hz": math.nan,
                 "resonance_width_hz": math.nan, "resonance_width_err_hz": math.nan,
                 "late_over_background_db": 6.25 if k == first else math.nan,
                 "resonance_pings": 12 if k == first else 0}
                for k in range(len(contacts))]

    run = tmp_path / "run"
    write_run_products(tmp_path, run, origin=ORIGIN, spectra=measured)
    rows = list(csv.DictReader(open(run / CONTACTS_CSV)))
    pinged = [r for r in rows if r["class_from"] == FROM_PINGS]
    assert [(r["class"], r["p_manmade"]) for r in pinged] == [("natural", "0.014")]
    others = [r for r in rows if r is not pinged[0]]
    assert all(r["class_from"] == FROM_IMAGE for r in others)
    assert len(others) >= 1
    assert all(r["class"] in ("man-made", "undecided") for r in others)
    props = [f["properties"] for f in json.loads((run / CONTACTS_GEOJSON).read_text())
             ["features"] if f["properties"]["kind"] == "contact"]
    assert [p["class_from"] for p in props] == [r["class_from"] for r in rows]
    import pyogrio.raw
    _, _, _, data = pyogrio.raw.read(str(run / CONTACTS_GPKG), layer="contacts")
    cols = list(pyogrio.read_info(str(run / CONTACTS_GPKG), layer="contacts")["fields"])
    assert list(data[cols.index("class_from")]) == [r["class_from"] for r in rows]
    write_run_products(tmp_path, run, origin=ORIGIN)          # svss products
    again = list(csv.DictReader(open(run / CONTACTS_CSV)))
    assert [(r["class"], r["p_manmade"], r["class_from"]) for r in again] == \
        [(r["class"], r["p_manmade"], r["class_from"]) for r in rows]
