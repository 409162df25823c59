"""The reproduction's pieces that need no simulation: the paper-era hardware, the scene
variants, the figures and the report from a synthetic summary, the command's parser."""

from __future__ import annotations

import math

import numpy as np
import pytest

from svss.cli import build_parser
from svss.reproduce import figures, measures, report, scenes
from svss.reproduce.scenes import Variant
from svss_daq.geometry import array_geometry


def test_paper_hardware_is_the_seeds_array():
    hw = scenes.load_hardware("paper").value
    geo = array_geometry(hw)
    rx = np.asarray(geo.receivers)
    assert rx.shape[0] == 32 == hw.digitiser.n_channels
    # 4 along x 8 across at 9.1 cm
    assert np.unique(np.round(rx[:, 0], 4)).size == 4
    assert np.unique(np.round(rx[:, 1], 4)).size == 8
    assert np.diff(np.unique(np.round(rx[:, 1], 4))) == pytest.approx(np.full(7, 0.091))
    tx = np.asarray(geo.projectors)
    assert tx.shape[0] == 5 and np.diff(tx[:, 1]) == pytest.approx(np.full(4, 0.229))
    assert np.all(tx[:, 0] > rx[:, 0].max())          # forward of the receive array
    # the array 2.0 m above the interface in the seed scenes: 0.5 m below the body origin
    assert rx[:, 2] == pytest.approx(np.full(32, 0.5))
    assert sorted(hw.sequencer.projector_order) == [0, 1, 2, 3, 4]


def test_scene_variants():
    base = scenes.seed_scene("sand")
    along = scenes.seed_scene("sand", Variant(axis="along", seed=5, per_cell=1.0))
    assert base.targets[0].axis_heading_deg == 90.0
    assert along.targets[0].axis_heading_deg == 0.0
    assert along.scene.seed == 5 and along.scattering.scatterers_per_resolution_cell == 1.0
    # geometry the seed states: array 2 m above the interface in 2.5 m of water
    assert base.medium.depth_m == 2.5
    assert base.track.altitude_m - 0.5 == pytest.approx(2.0)
    from sim_device.acoustics import load_sediments
    sed = load_sediments()["medium_sand"]
    tilted = scenes.seed_scene("sand", Variant(gamma=3.5)).seabed.layers[0]
    k = 2 * 2 * math.pi * 27500.0 / 1500.0
    # the tilted spectrum keeps W(2k)
    assert tilted.spectral_strength_si * k ** -3.5 == pytest.approx(
        sed.spectral_strength * k ** -sed.spectral_exponent, rel=1e-9)
    scaled = scenes.seed_scene("sand", Variant(w2_scale=2.0)).seabed.layers[0]
    assert scaled.spectral_strength_si == pytest.approx(2 * sed.spectral_strength)
    with pytest.raises(ValueError, match="axis"):
        scenes.seed_scene("sand", Variant(axis="diagonal"))


def test_pings_over_and_reach():
    src = scenes.source("paper", "sand")
    pings = scenes.pings_over(src, 8.0, 12.0)
    along = [scenes.array_along(src, i) for i in (pings.start, pings.stop - 1)]
    assert 8.0 <= along[0] < 8.1 and 11.9 < along[1] <= 12.0
    # at the interface: 2 m x tan(25 + 2 deg)
    assert scenes.reach_m(src, 0.0) == pytest.approx(2.0 * math.tan(math.radians(27.0)))
    assert scenes.reach_m(src, 1.0) > scenes.reach_m(src, 0.0)


def _summary(tmp_path):
    depth = np.arange(-0.3, 3.5, 0.01)
    feats = [measures.Feature(0.589, 0.547, -15.0, 10.0),
             measures.Feature(2.944, 2.902, -30.0, 20.0)]

    def case(scene, array, axis, excess, group="main", seed=None):
        return {"tag": f"{array}_{scene}_{axis}", "array": array, "scene": scene,
                "group": group, "variant": {"axis": axis, "seed": seed},
                "label": f"axis {axis}", "ping_range": [46, 87], "pings": 42, "n_channels": 32,
                "water_speed": 1500.0, "sediment_speed": 1767.0, "excess_db": excess,
                "surround_excess_db": excess + 4.0,
                "peak": [10.0, 0.0, 0.85], "first": vars(feats[0]), "second": vars(feats[1]),
                "features": [vars(f) for f in feats], "profile_depth": depth.tolist(),
                "profile_db": (-depth).tolist(), "simulation_s": 1.0, "imaging_s": 1.0}
    cases = [case("sand", "paper", "along", 10.4), case("sand", "paper", "across", 19.8),
             case("silt", "paper", "along", 24.0),
             case("sand", "paper", "along", 11.6, "seeds", 101),
             case("silt", "paper", "along", 26.0, "seeds", 101)]
    return {"quick": True, "n_seeds": 2, "elapsed_s": 12.0, "cases": cases,
            "field": None, "figures": {"profile": "profile_sand.png"},
            "expected": {"first order (1 m)": 0.589, "second order (5 m)": 2.945},
            "seed_config": {"array": "paper", "axis": "along"}}


def test_report_states_the_measured_values(tmp_path):
    path = report.write_report(tmp_path / "report.md", _summary(tmp_path))
    text = path.read_text()
    assert "peak 0.589 m" in text and "peak 2.944 m" in text
    assert "0.589 m" in text and "2.945 m" in text          # the arithmetic beside
    assert "10.4 dB" in text and "19.8" in text
    # the spread over two seabeds: sand 10.4 and 11.6 -> mean 11.0, sd 0.85
    assert "11.0 ± 0.8 dB" in text
    assert "silt − sand = +13.6 dB" in text
    assert "![profile](profile_sand.png)" in text
    assert "| 46–87 (42) |" in text


def test_figures_write_pngs(tmp_path):
    a = np.arange(40) * 0.05 + 9.0
    c = (np.arange(20) - 9.5) * 0.05
    d = np.arange(30) * 0.05
    img = np.ones((40, 20, 30), np.complex64)
    img[20, 10, 17] = 100
    p = figures.orthogonal_slices(tmp_path / "s.png", img, (a, c, d), (a[20], c[10], d[17]),
                                  "t", gain_db_per_m=10.0)
    q = figures.field_figure(tmp_path / "f.png", np.abs(img) / 100, np.ones((40, 30)) * 0.5,
                             (a, c, d), 0.8, [(10.0, 0.0, 0.85, "cyl")], "t")
    r = figures.profile_figure(tmp_path / "p.png", d, {"x": -d}, {}, {"e": 1.0}, "t")
    for f in (p, q, r):
        assert f.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_command_is_wired():
    args = build_parser().parse_args(["reproduce", "--out", "x", "--quick", "--seeds", "3"])
    assert args.quick and args.seeds == 3 and args.out == "x"
    assert args.func.__name__ == "cmd_reproduce"
