"""``svss trade --quick``: the speed/accuracy table on tiny workloads.

One run of the real command (``svss.cli.main``, in-process so that numba's compiled
kernels are shared with the rest of the session) measures every area; the tests check
the table's structure, that errors are measured against the reference (zero for the
reference itself, larger for a deliberately worse option than for the default), the
Pareto front against an independent dominance check, and the files.
"""

from __future__ import annotations

import csv
import json
import math

import pytest

from svss import cli
from svss.trade import report
from tests.computed_once import computed_once

AREAS = ("imaging", "simulation", "normalisation")


@pytest.fixture(scope="module")
def trade(tmp_path_factory):
    """One run for the session (:mod:`tests.computed_once`): the module's tests are
    spread over the workers, and each worker's own run compiled every option's kernels
    (3 CPU-minutes a time on a cold cache)."""
    def run():
        out = tmp_path_factory.mktemp("trade")
        rc = cli.main(["-q", "trade", "--quick", "--out", str(out), "--budget-s", "15"])
        assert rc == 0
        return out, json.loads((out / "trade.json").read_text())
    return computed_once(tmp_path_factory, "test_trade-trade", run)


def rows_of(result, area):
    return [r for r in result["rows"] if r["area"] == area]


@pytest.mark.slow
def test_files_written(trade):
    out, result = trade
    for name in ["trade.csv", "trade.json", "trade.md"] + [f"pareto_{a}.png" for a in AREAS]:
        assert (out / name).stat().st_size > 0, name
    assert (out / "pareto_imaging.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with open(out / "trade.csv") as fh:
        table = list(csv.DictReader(fh))
    assert len(table) == len(result["rows"])
    assert {"area", "option", "value", "time_s", "tile_s", "error", "on_front"} <= set(
        table[0])
    md = (out / "trade.md").read_text()
    for a in AREAS:
        assert f"### {a}" in md


@pytest.mark.parametrize("area", AREAS)
def test_each_area_has_one_reference_and_one_default_with_measured_times(trade, area):
    _, result = trade
    rows = rows_of(result, area)
    assert sum(r["is_reference"] for r in rows) == 1
    assert sum(r["is_default"] for r in rows) == 1
    assert len(rows) >= 4                          # the options were swept
    for r in rows:
        assert r["time_s"] > 0 and r["tile_s"] > 0 and r["error"] >= 0
        assert math.isfinite(r["error"])
    ref = next(r for r in rows if r["is_reference"])
    assert ref["error"] == 0.0                     # the reference against itself


def test_imaging_errors_are_measured(trade):
    """Nearest interpolation, a coarser voxel and half the channels err more than the
    default; the reference's own interpolation (cubic) errs less."""
    _, result = trade
    rows = {(r["option"], r["value"]): r for r in rows_of(result, "imaging")}
    default = next(r for r in rows.values() if r["is_default"])
    assert default["setting"]["interpolation"] == "linear"       # config/processing.toml
    assert rows[("interpolation", "nearest")]["error"] > 1.5 * default["error"]
    assert rows[("interpolation", "cubic")]["error"] < 0.5 * default["error"]
    assert rows[("channels", "every other")]["error"] > 3 * default["error"]
    coarse = [r for (o, _), r in rows.items() if o == "voxel_m"]
    assert coarse and all(r["error"] > default["error"] for r in coarse)
    assert coarse[0]["metrics"]["error_basis"] == "magnitude, resampled"


def test_simulation_and_normalisation_errors_are_measured(trade):
    _, result = trade
    sim = {(r["option"], r["value"]): r for r in rows_of(result, "simulation")}
    # a density 100 times below the reference's draws a different seabed: it must differ
    assert sim[("per_cell", "0.02")]["error"] > 0.05
    for r in sim.values():
        assert {"d_level_db", "d_contrast_db", "scintillation", "ks_exponential"} <= set(
            r["metrics"])
    norm = {r["value"]: r for r in rows_of(result, "normalisation")}
    # the histogram median's error is at most half a bin, and grows with the bin
    for v, r in norm.items():
        if v.startswith("histogram"):
            b = r["setting"]["histogram_bin_db"]
            assert 0 < r["error"] <= b / 2 + 1e-6
    assert norm["histogram 1 dB"]["error"] > norm["histogram 0.25 dB"]["error"]


def test_front_and_recommendation_follow_the_rows(trade):
    """Recomputed independently: a row is on the front iff no other row is faster (by
    10 %) and no worse, or better and not slower; the recommendation is the least error
    within the budget."""
    _, result = trade
    for area in AREAS:
        rows = rows_of(result, area)
        tol = report.ERROR_TOLERANCE[area]
        for r in rows:
            dominated = any(
                (o["tile_s"] < 0.9 * r["tile_s"] and o["error"] <= r["error"] + tol)
                or (o["error"] < r["error"] - tol and o["tile_s"] <= 1.1 * r["tile_s"])
                for o in rows if o is not r)
            assert r["on_front"] == (not dominated), (area, r["option"], r["value"])
        d = next(r for r in rows if r["is_default"])
        assert result["defaults_on_front"][area] == d["on_front"]
        fits = [r for r in rows if r["tile_s"] <= 15.0]
        rec = result["recommendation"][area]
        if fits:
            assert rec["error"] == min(r["error"] for r in fits)
        else:
            assert rec is None
    assert any("Pareto front" in s for s in result["summary"])


def test_every_simulation_option_reaches_the_scene():
    """Each option the simulation area varies is set on the scene it simulates (a dropped
    option would measure the default twice and show no error)."""
    from sim_device.scene import load_scene
    from svss.trade.simulation import scene_defaults, with_options
    from svss_daq.config import config_path

    sc = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
    base = scene_defaults(sc)
    s = dict(base, per_cell=0.5, order=0, below_noise=7.0, tol=1e-3, step=500.0)
    assert all(s[k] != base[k] for k in s)
    out = with_options(sc, s, seed=sc.scene.seed + 1)
    assert scene_defaults(out) == s
    assert out.scene.seed == sc.scene.seed + 1
