"""``svss score`` per target class (issue 51): the truth classes from the scene's
materials, and per class the detected targets and how their contacts were called, on a
small folder of real tiles whose detections carry a class."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from svss.score import format_report, per_class, score_tiles, truth_class
from svss_daq.frames import TrackLine
from svss_proc.imaging.grid import tile_grid
from svss_proc.products.chain import compute_products
from svss_proc.products.classify import MANMADE, NATURAL, UNDECIDED
from svss_proc.products.run_products import CONTACTS_CSV, write_run_products
from svss_proc.tiles import read_tile, write_tile

from . import VOXEL, make_tile, plant, rayleigh_median, speckle
from .test_cli import HEADING, SCENE

def _rewrite(path, rows: list[dict]) -> None:
    """A run's contacts file written again with ``rows`` (as an edited file)."""
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


TARGETS = """
[[targets]]
kind = "sphere"
material = "cast_iron"
along_m = {a0}
cross_m = 0.1
depth_m = 0.3
radius_m = 0.05

[[targets]]
kind = "disc"
material = "granite"
along_m = {a1}
cross_m = -0.3
depth_m = 0.6
radius_m = 0.1
thickness_m = 0.05
axis_heading_deg = 0.0
axis_tilt_deg = 0.0

[[targets]]
kind = "shell"
material = "steel"
fill = "vacuum"
along_m = {a2}
cross_m = 0.2
depth_m = 0.5
radius_m = 0.05
thickness_m = 0.005

[[targets]]
kind = "disc"
material = "basalt"
along_m = {a3}
cross_m = 0.0
depth_m = 0.4
radius_m = 0.1
thickness_m = 0.05
axis_heading_deg = 0.0
axis_tilt_deg = 0.0

[[points]]
along_m = {a4}
cross_m = 0.0
depth_m = 0.5
target_strength_db = -20.0
"""


def test_truth_classes_from_the_materials():
    assert truth_class({"fields": {"material": "granite"}}) == "natural"
    assert truth_class({"fields": {"material": "limestone"}}) == "natural"
    assert truth_class({"fields": {"material": "aluminium"}}) == "man-made"
    assert truth_class({"fields": {"material": "cast_iron"}}) == "man-made"
    assert truth_class({"fields": {"material": "rigid"}}) == "other"
    assert truth_class({"fields": {"target_strength_db": -20.0}}) == "other"
    rows = per_class([{"class": "man-made", "status": "detected", "called": "man-made"},
                      {"class": "man-made", "status": "missed"},
                      {"class": "natural", "status": "detected", "called": "undecided"},
                      {"class": "natural", "status": "outside"}])
    assert rows["man-made"] == {"targets": 2, "detected": 1, "man-made": 1, "natural": 0,
                                "undecided": 0, "not classified": 0,
                                "detected_fraction": 0.5, "called_manmade_fraction": 0.5}
    assert rows["natural"]["targets"] == 1 and rows["natural"]["undecided"] == 1
    assert "other" not in rows


def test_score_reports_detection_and_classification_per_class(tmp_path, hardware,
                                                              demo_processing):
    # scene frame: along from the first ping's body origin; the tiles are imaged on a
    # line starting 0.5 m further along (tile along = scene along - 0.5)
    along = (1.0, 2.2, 3.4, 4.4, 5.4)
    scene = tmp_path / "scene.toml"
    scene.write_text(SCENE + TARGETS.format(**{f"a{i}": a for i, a in enumerate(along)}))
    shift = 0.5
    line = TrackLine((100.0 + shift * math.cos(HEADING), 200.0 + shift * math.sin(HEADING)),
                     HEADING, 0.5 + 2.5)
    # planted: the shot put (called man-made), the granite slab (natural), the basalt
    # slab (undecided) and the point; the empty shell is missed
    planted = [((along[0] - shift, 0.1, 0.3), MANMADE, 0.9),
               ((along[1] - shift, -0.3, 0.6), NATURAL, 0.1),
               ((along[3] - shift, 0.0, 0.4), UNDECIDED, 0.5),
               ((along[4] - shift, 0.0, 0.5), MANMADE, 0.8)]
    out = tmp_path / "tiles"
    out.mkdir()
    rng = np.random.default_rng(51)
    for k in (0, 1):
        grid = tile_grid(demo_processing.value.tile, k)
        axes = (grid.along, grid.cross, grid.depth)
        img = speckle(grid.shape, rng)
        for pos, _, _ in planted:
            plant(img, axes, pos, rayleigh_median(1.0) * 10 ** (30 / 20))
        prods = compute_products(img, axes, VOXEL, demo_processing.value.products)
        det = prods.detections
        for pos, cls, p in planted:        # each planted contact's class, as if measured
            if len(det):
                d = np.hypot(det["along_m"] - pos[0], det["cross_m"] - pos[1])
                i = int(np.argmin(d))
                if d[i] < 0.1:
                    det["class"][i], det["p_manmade"][i] = cls, p
        write_tile(out / f"tile_{k:04d}.h5", make_tile(grid, line, img, range(5)), hardware,
                   demo_processing, prods)
    r = score_tiles(out, scene)
    # the scene's targets in its own order, then its points
    r["truth"].sort(key=lambda t: (t["table"] != "targets", t["index"]))
    classes = [t["class"] for t in r["truth"]]
    assert classes == ["man-made", "natural", "man-made", "natural", "other"]
    assert [t["status"] for t in r["truth"]] == ["detected", "detected", "missed",
                                                 "detected", "detected"]
    assert [t.get("called") for t in r["truth"]] == ["man-made", "natural", None,
                                                     "undecided", "man-made"]
    assert r["truth"][0]["p_manmade"] == pytest.approx(0.9, abs=1e-6)
    pc = r["summary"]["per_class"]
    assert pc["man-made"] == {"targets": 2, "detected": 1, "man-made": 1, "natural": 0,
                              "undecided": 0, "not classified": 0,
                              "detected_fraction": 0.5, "called_manmade_fraction": 0.5}
    assert pc["natural"]["targets"] == 2 and pc["natural"]["detected"] == 2
    assert (pc["natural"]["natural"], pc["natural"]["undecided"]) == (1, 1)
    assert pc["natural"]["called_manmade_fraction"] == 0.0
    assert pc["other"]["man-made"] == 1
    text = format_report(r)
    assert "man-made: 1/2 detected; called man-made 1, natural 0, undecided 0" in text
    assert "natural: 2/2 detected; called man-made 0, natural 1, undecided 1" in text
    # the run's contacts file (written by svss process) may call a contact again with the
    # pings' features: the run-level score takes its call, the tile level the tile's
    write_run_products(out)
    rows = list(csv.DictReader(open(out / CONTACTS_CSV)))
    slab = min(rows, key=lambda c: abs(float(c["along_m"]) - (along[1] - shift))
               + abs(float(c["cross_m"]) + 0.3))
    assert slab["class"] == "natural" and slab["class_from"] == "image"
    slab.update({"class": "man-made", "p_manmade": "0.770", "class_from": "image and pings",
                 "late_over_background_db": "4.50"})
    _rewrite(out / CONTACTS_CSV, rows)
    again = score_tiles(out, scene)
    again["truth"].sort(key=lambda t: (t["table"] != "targets", t["index"]))
    assert [t.get("called") for t in again["truth"]] == ["man-made", "man-made", None,
                                                         "undecided", "man-made"]
    assert again["truth"][1]["p_manmade"] == pytest.approx(0.77)
    det = again["detections"][again["truth"][1]["detection"]]
    assert (det["class_image"], det["class_from"]) == (NATURAL, "image and pings")
    assert det["late_over_background_db"] == 4.5
    tile_level = score_tiles(out, scene, level="tile")
    tile_level["truth"].sort(key=lambda t: (t["table"] != "targets", t["index"]))
    assert tile_level["truth"][1]["called"] == "natural"
    # a file whose excess differs (another processing) lends no call
    slab["excess_db"] = f"{float(slab['excess_db']) + 1.0:.2f}"
    _rewrite(out / CONTACTS_CSV, rows)
    stale = score_tiles(out, scene)
    stale["truth"].sort(key=lambda t: (t["table"] != "targets", t["index"]))
    assert stale["truth"][1]["called"] == "natural"


def test_the_run_calls_pair_with_each_tile_row_the_run_kept(tmp_path, hardware,
                                                          demo_processing):
    """The run drops a tile's detection (one object seen by two tiles across their
    seam): the scored rows keep their places in the tiles' tables, so the run's
    contacts file pairs with every one of them."""
    scene = tmp_path / "scene.toml"
    scene.write_text(SCENE + TARGETS.format(a0=1.0, a1=2.2, a2=3.4, a3=4.4, a4=5.4))
    line = TrackLine((100.0, 200.0), HEADING, 3.0)
    out = tmp_path / "tiles"
    out.mkdir()
    rng = np.random.default_rng(52)
    points = [((1.0, 0.1, 0.3), 25), ((2.99, -0.2, 0.4), 40), ((4.4, 0.0, 0.4), 25)]
    for k in (0, 1):
        grid = tile_grid(demo_processing.value.tile, k)
        axes = (grid.along, grid.cross, grid.depth)
        img = speckle(grid.shape, rng)
        for pos, db in points:
            plant(img, axes, pos, rayleigh_median(1.0) * 10 ** (db / 20))
        prods = compute_products(img, axes, VOXEL, demo_processing.value.products)
        write_tile(out / f"tile_{k:04d}.h5", make_tile(grid, line, img, range(5)), hardware,
                   demo_processing, prods)
    tables = {p.name: read_tile(p)["detections"] for p in sorted(out.glob("tile_*.h5"))}
    r = score_tiles(out, scene, level="run")
    assert len(r["detections"]) < sum(len(t) for t in tables.values())   # one dropped
    for d in r["detections"]:
        assert tables[d["tile"]]["excess_db"][d["row"]] == pytest.approx(d["excess_db"])
    # a higher floor applied afterwards: only the bright point's contact is scored
    high = score_tiles(out, scene, level="run", min_excess_db=35.0)
    assert len(high["detections"]) == 1 and high["detections"][0]["excess_db"] >= 35.0
    assert all(tables[d["tile"]]["excess_db"][d["row"]] == pytest.approx(d["excess_db"])
               for d in high["detections"])
    write_run_products(out)
    rows = list(csv.DictReader(open(out / CONTACTS_CSV)))
    for row in rows:
        row.update({"class": "natural", "p_manmade": "0.100", "class_from": "image and pings"})
    _rewrite(out / CONTACTS_CSV, rows)
    again = score_tiles(out, scene, level="run")
    assert len(again["detections"]) == len(rows)
    assert all(d["class_from"] == "image and pings" and d["class"] == NATURAL
               for d in again["detections"])
