"""benchmarks/fit_classifier.py (issue 51): the logistic fit recovers a known model, its
result written into a processing configuration that still loads, and the known-speed
configuration of benchmarks/bench_classify.py."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from svss_daq.config import ProcessingConfig, load
from svss_proc.products.classify import logistic, probability

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_classify import curve, known_processing  # noqa: E402
from fit_classifier import PROCESSING, fit_logistic, usable, write_model  # noqa: E402


def test_the_fit_recovers_a_known_model():
    rng = np.random.default_rng(51)
    x = rng.normal([7.0, -3.0], [3.0, 4.0], size=(20000, 2))
    z = (x - x.mean(axis=0)) / x.std(axis=0)
    y = (rng.random(len(x)) < logistic(0.5 + z @ np.array([2.0, -1.0]))).astype(float)
    m = fit_logistic(x, y, l2=0.0)
    assert m["converged"]
    np.testing.assert_allclose(m["coefficients"], [2.0, -1.0], atol=0.08)
    assert m["intercept"] == pytest.approx(0.5, abs=0.06)
    # separable data: the ridge keeps the weights finite
    m = fit_logistic(np.array([[1.0], [2.0], [8.0], [9.0]]), np.array([0, 0, 1, 1.0]), 1.0)
    assert m["converged"] and 0 < m["coefficients"][0] < 10


def test_the_fitted_model_is_written_and_loads(tmp_path):
    path = tmp_path / "processing.toml"
    shutil.copy(PROCESSING, path)
    model = {"mean": [6.5, -2.0], "scale": [3.6, 3.7], "coefficients": [1.56, 1.18],
             "intercept": -0.095}
    write_model(model, ["aspect_width_deg", "late_to_specular_db"], [11.0, 4.5], path)
    assert load(ProcessingConfig, path).products.features.point_aspect_deg == (11.0, 4.5)
    c = load(ProcessingConfig, path).products.classify
    assert c.features == ("aspect_width_deg", "late_to_specular_db")
    assert c.mean == (6.5, -2.0) and c.coefficients == (1.56, 1.18) and c.intercept == -0.095
    p = probability(np.array([[6.5, -2.0]]), c)[0]
    assert p == pytest.approx(logistic(np.array([-0.095]))[0])
    # the other keys and their comments are kept
    assert "manmade_above" in path.read_text().split("[products.classify]")[1]
    # the run's model goes into its own table and leaves the point reference alone
    pings = {**model, "mean": [6.5, -2.0, 0.9], "scale": [3.6, 3.7, 1.9],
             "coefficients": [1.1, 0.8, -0.8]}
    write_model(pings, ["aspect_width_deg", "late_to_specular_db",
                        "late_over_background_db"], [99.0, 99.0], path,
                table="products.classify_pings")
    got = load(ProcessingConfig, path).products
    assert got.classify_pings.features[2] == "late_over_background_db"
    assert got.classify_pings.coefficients == (1.1, 0.8, -0.8)
    assert got.classify.coefficients == (1.56, 1.18)
    assert got.features.point_aspect_deg == (11.0, 4.5)


def test_usable_rows_and_the_curve():
    row = {"status": "detected", "class": "natural", "feature_flags": 0,
           "aspect_width_deg": 3.0, "late_to_specular_db": -5.0}
    assert usable(row, ("aspect_width_deg",), (32,))
    assert not usable({**row, "feature_flags": 32}, ("aspect_width_deg",), (32,))
    assert not usable({**row, "aspect_width_deg": float("nan")}, ("aspect_width_deg",), ())
    assert not usable({**row, "class": "other"}, ("aspect_width_deg",), ())
    c = curve([{"class": "man-made", "status": "detected", "p_manmade": 0.9},
               {"class": "man-made", "status": "missed"},
               {"class": "natural", "status": "detected", "p_manmade": 0.3}])
    assert c[0] == {"threshold": 0.0, "manmade_called": 0.5, "natural_called": 1.0}
    assert c[-1]["manmade_called"] == 0.0 and c[-1]["natural_called"] == 0.0


def test_the_known_speed_configuration(tmp_path):
    c = load(ProcessingConfig, known_processing("classify_test_silt", tmp_path))
    assert c.seabed.speed == "configured"
    assert c.imaging.sediment_sound_speed_m_s == 1650.0          # stiff clay
    assert [(la.thickness_m, la.sound_speed_m_s) for la in c.imaging.sediment_layers] == \
        [(0.6, 1476.0)]                                          # very fine silt
    c = load(ProcessingConfig, known_processing("classify_test_sand", tmp_path))
    assert c.imaging.sediment_sound_speed_m_s == 1767.0 and not c.imaging.sediment_layers


def test_peak_near_finds_the_brightest_voxel_and_says_where(tmp_path):
    """A tile file (real HDF5) with a flat background, an interface echo and a weaker
    voxel below it: peak_near gives the brightest voxel in its cube, where it is, and
    whether that is the interface's echo; a cube beside every tile gives None."""
    import h5py
    from fit_classifier import peak_near
    along, cross, depth = (np.arange(0, 2.0, 0.02), np.arange(-0.5, 0.5, 0.02),
                           np.arange(-0.2, 1.0, 0.02))
    img = np.ones((along.size, cross.size, depth.size), dtype=np.complex64)
    iz0 = int(np.argmin(np.abs(depth)))
    img[50, 25, iz0] = 100.0                       # the interface's echo: 40 dB
    img[52, 25, iz0 + 10] = 10.0                   # 20 cm deeper: 20 dB
    with h5py.File(tmp_path / "tile_0000.h5", "w") as f:
        for k, v in (("along", along), ("cross", cross), ("depth", depth)):
            f[k] = v
        f["image"] = img
        f["background"] = np.ones(img.shape, dtype=np.float32)
    at = [float(along[51]), float(cross[25]), 0.25]
    top = peak_near(tmp_path, at)                  # the cube reaches the interface
    assert top["db"] == pytest.approx(40.0) and top["interface"]
    assert top["at_m"] == pytest.approx([along[50], cross[25], depth[iz0]])
    deep = peak_near(tmp_path, [at[0], at[1], 0.5])    # 0.15-0.85 m: not the interface
    assert deep["db"] == pytest.approx(20.0) and not deep["interface"]
    assert deep["at_m"][2] == pytest.approx(depth[iz0 + 10])
    assert peak_near(tmp_path, [5.0, 0.0, 0.2]) is None
