"""Contacts and products that carry their circumstances (issue 47), end to end: the demo
scene's six points simulated with 8 pings lost in the middle of a 3 s GPS outage
(dead-reckoned poses around them) and then a few held poses, recorded, imaged by `svss
process`'s function (the real imager, products and run products). The contacts that
the lost pings and the flagged poses could have seen carry them, within what the
simulator's true poses say; the far contact carries nothing; the tiles keep their
pings' flags and say their counts; the map draws the stretches; the GeoJSON, the
mosaic's HDF5 and the GeoPackage hold them; and no contact is an image edge of the gap
(every contact is one of the six points, at tile and run level)."""

from __future__ import annotations

import csv
import dataclasses
import itertools
import json
import math
from pathlib import Path

import h5py
import numpy as np
import pytest
from PIL import Image

from sim_device.scene import load_scene
from sim_device.track import ping_pose
from svss.score import score_tiles
from svss_daq import ping as P
from svss_daq.config import ProcessingConfig, config_path, loaded_from_text
from svss_daq.frames import body_to_ned
from svss_daq.geometry import array_geometry
from svss_daq.navigation import geodetic_to_ned
from svss_proc.products.circumstances import PARTIAL_COVERAGE_BELOW
from svss_proc.products.raster import rgb8
from svss_proc.products.run_products import (CONTACTS_CSV, CONTACTS_GEOJSON,
                                             CONTACTS_GPKG, MOSAIC_H5, MOSAIC_PNG,
                                             STRETCH_RGB, write_run_products)
from svss_proc.tiles import read_tile_header
from tests.computed_once import computed_once

SCENE = config_path("scenes/demo.toml")
ORIGIN = (41.5240, -70.6710, 0.0)
#: frames lost: pings 12-19 never recorded (0.8 m of track)
MISSING = frozenset(range(12, 20))
#: a GPS outage over pings 3-32 (3 s: dead-reckoned on the DVL), then 3 held poses
DEAD_RECKONED = frozenset(range(3, 33)) - MISSING
HELD = frozenset(range(33, 36))
GOOD = P.NAV_GPS_FIX | P.NAV_FUSED | P.NAV_BOTTOM_LOCK | P.NAV_DVL_VELOCITY
#: as the fusion flags a pose through a GPS outage with bottom lock (the outage empties
#: the HDT too: heading from the DVL's compass), and one held with neither
DR_FLAGS = (P.NAV_DEAD_RECKONED | P.NAV_FUSED | P.NAV_BOTTOM_LOCK | P.NAV_DVL_VELOCITY
            | P.NAV_HEADING_FROM_COMPASS)
HELD_FLAGS = P.NAV_HELD | P.NAV_FUSED | P.NAV_HEADING_FROM_COMPASS


def flags_of(seq: int) -> int:
    return DR_FLAGS if seq in DEAD_RECKONED else HELD_FLAGS if seq in HELD else GOOD


def processing():
    """The demo's processing, held poses imaged (shipped: refused, so missing)."""
    text = Path(config_path("processing-demo.toml")).read_text()
    new = text.replace('held = "refuse"', 'held = "image"')
    assert new != text
    return loaded_from_text(ProcessingConfig, new, "processing-demo.toml, held imaged")


def processed(tmp_path_factory, hardware, name: str, missing: frozenset, flags) -> Path:
    """The demo scene's pings with ``missing`` left out and each kept one's navigation
    flags ``flags(sequence)`` (None: as simulated), recorded and imaged by ``svss
    process``'s function: the run's tiles and run products (computed once a session)."""
    from sim_device.environment_source import EnvironmentSource
    from svss_daq.rawfile import RawRunWriter
    from svss_proc.run_worker import process_raw

    def run() -> Path:
        root = tmp_path_factory.mktemp(name)
        raw = root / f"{name}.h5"
        scene = load_scene(SCENE)
        with RawRunWriter(raw, hardware, run_attrs={}) as rec:
            for p in itertools.islice(iter(EnvironmentSource(hardware, scene)),
                                      scene.track.n_pings):
                if p.sequence in missing:
                    continue
                rec.append(p if flags is None else dataclasses.replace(
                    p, nav=dataclasses.replace(p.nav, quality=flags(p.sequence))))
        process_raw(raw, root / "tiles", processing())
        return root / "tiles"
    return computed_once(tmp_path_factory, f"run_circumstances-{name}", run)


@pytest.fixture(scope="module")
def gapped(tmp_path_factory, hardware) -> Path:
    """The run's tiles and run products (``svss process``'s function)."""
    return processed(tmp_path_factory, hardware, "gapped", MISSING, flags_of)


def _contacts(folder: Path) -> list[dict]:
    with open(folder / CONTACTS_CSV, newline="") as f:
        return list(csv.DictReader(f))


def truth_counts(hardware, contact: dict, height_m: float, slack_m: float) -> dict:
    """The pings of each circumstance whose array (the projectors' mean position, at the
    simulator's true pose of the ping, lost ones too) lies horizontally within the
    projector cone's reach of the contact at its depth, ``(h + z) tan(half-angle)``,
    widened by ``slack_m``."""
    scene = load_scene(SCENE)
    geo = array_geometry(hardware.value)
    mean = geo.projectors.mean(axis=0)
    reach = (height_m + float(contact["depth_below_seabed_m"])) \
        * math.tan(geo.projector_half_angle) + slack_m
    p = np.array([float(contact["north_m"]), float(contact["east_m"])])
    out = {}
    for key, seqs in (("pings_missing", MISSING), ("poses_dead_reckoned", DEAD_RECKONED),
                      ("poses_held", HELD)):
        n = 0
        for k in seqs:
            nav = ping_pose(scene.track, hardware.value, k, scene.scene.seed)
            at = nav.ned + body_to_ned(nav.roll_rad, nav.pitch_rad, nav.heading_rad) @ mean
            n += bool(np.hypot(*(at[:2] - p)) <= reach)
        out[key] = n
    return out


@pytest.mark.slow
def test_contacts_carry_what_happened_among_the_pings_that_could_see_them(gapped,
                                                                          hardware):
    rows = _contacts(gapped)
    assert len(rows) == 6
    heights = [float(read_tile_header(p)["attrs"]["projector_height_m"])
               for p in sorted(gapped.glob("tile_*.h5"))]
    h = float(np.mean(heights))
    words = {"pings_missing": "gap", "poses_dead_reckoned": "dead-reckoned",
             "poses_held": "held"}
    marked = clean = 0
    for c in rows:
        lo = truth_counts(hardware, c, h, -0.1)
        hi = truth_counts(hardware, c, h, 0.1)
        for key, word in words.items():
            got = int(c[key])
            assert lo[key] <= got <= hi[key], (c, key, lo, hi)
            assert (word in c["circumstances"]) == (got > 0), c
        partial = float(c["coverage_fraction"]) < PARTIAL_COVERAGE_BELOW
        assert ("partial coverage" in c["circumstances"]) == partial, c
        if any(hi.values()):
            marked += 1
        if not any(hi.values()):
            clean += 1
            assert c["circumstances"] == "" and not partial, c
    assert marked >= 4 and clean >= 1, rows
    # the point at 4.6 m: all 8 lost pings were within its reach
    first = min(rows, key=lambda c: float(c["along_m"]))
    assert int(first["pings_missing"]) == 8
    assert first["circumstances"].startswith("gap 8 pings; dead-reckoned ")


@pytest.mark.slow
def test_no_contact_is_an_image_edge_of_the_gap(gapped):
    """Every contact, in the tiles and in the run, is one of the six points."""
    for level in ("tile", "run"):
        s = score_tiles(gapped, SCENE, level=level)["summary"]
        assert (s["hits"], s["false_alarms"], s["duplicates"]) == (6, 0, 0), (level, s)


@pytest.mark.slow
def test_tiles_keep_their_pings_flags_and_say_their_counts(gapped):
    counts = {}
    for path in sorted(gapped.glob("tile_*.h5")):
        h = read_tile_header(path)
        seq = h["ping_sequence"]
        np.testing.assert_array_equal(h["ping_nav_flags"], [flags_of(int(s)) for s in seq])
        a = h["attrs"]
        counts[path.name] = (int(a["pings_missing"]), int(a["poses_dead_reckoned"]),
                             int(a["poses_held"]))
        s = set(seq.tolist())
        assert counts[path.name] == (len(set(range(min(s), max(s) + 1)) - s),
                                     len(s & DEAD_RECKONED), len(s & HELD))
    assert counts["tile_0001.h5"][0] == 8 and counts["tile_0001.h5"][1] > 0
    assert counts["tile_0003.h5"] == (0, 0, 0)


@pytest.mark.slow
def test_the_map_and_the_files_hold_the_stretches(gapped, tmp_path):
    files = write_run_products(gapped, tmp_path, origin=ORIGIN)
    assert {p.name for p in files} >= {CONTACTS_GEOJSON, MOSAIC_H5, MOSAIC_PNG,
                                       CONTACTS_GPKG}
    want = [("missing", 12, 19, 8), ("dead_reckoned", 3, 11, 9),
            ("dead_reckoned", 20, 32, 13), ("held", 33, 35, 3)]
    # the map: each kind in its colour
    rgb = np.asarray(Image.open(tmp_path / MOSAIC_PNG).convert("RGB"))
    for kind, colour in STRETCH_RGB.items():
        assert np.all(rgb == rgb8(colour), axis=2).sum() > 20, kind
    # the mosaic's HDF5: the stretches as a table
    with h5py.File(tmp_path / MOSAIC_H5) as f:
        g = f["stretches"]
        got = list(zip([k.decode() for k in g["kind"][()]], g["first_sequence"][()].tolist(),
                       g["last_sequence"][()].tolist(), g["pings"][()].tolist()))
        assert got == want
        ends = np.stack([g[k][()] for k in ("start_north_m", "start_east_m", "end_north_m",
                                            "end_east_m")], axis=1)
        assert np.all(np.diff(f["track/ping"][()]) > 0)
        assert not set(f["track/ping"][()].tolist()) & MISSING
    # GeoJSON (RFC 7946): the contacts' Points, then the stretches' LineStrings
    gj = json.loads((tmp_path / CONTACTS_GEOJSON).read_text())
    points = [f for f in gj["features"] if f["geometry"]["type"] == "Point"]
    lines = [f for f in gj["features"] if f["geometry"]["type"] == "LineString"]
    assert len(points) == len(_contacts(tmp_path)) == 6
    assert gj["features"][:6] == points and all(f["properties"]["kind"] == "contact"
                                                for f in points)
    assert [(f["properties"]["kind"], f["properties"]["first_sequence"],
             f["properties"]["last_sequence"], f["properties"]["pings"]) for f in lines] == want
    for f, end in zip(lines, ends):
        coords = f["geometry"]["coordinates"]
        assert len(coords) >= 2 and all(len(c) == 2 for c in coords)
        # [longitude, latitude] about the survey origin: the table's ends (1e-7 deg: 1 cm)
        ned = geodetic_to_ned(np.array([c[1] for c in coords]),
                              np.array([c[0] for c in coords]), np.zeros(len(coords)),
                              ORIGIN)
        np.testing.assert_allclose(ned[[0, -1], :2].ravel(), end, atol=0.02)
    assert len({f["id"] for f in gj["features"]}) == len(gj["features"])
    assert gj["svss_run"]["stretches"] == {"missing": 1, "dead_reckoned": 2, "held": 1}
    # the GeoPackage: a stretches layer beside the contacts
    import pyogrio.raw
    _, _, geometry, data = pyogrio.raw.read(str(tmp_path / CONTACTS_GPKG),
                                            layer="stretches")
    assert list(data[0]) == [k for k, *_ in want] and len(geometry) == 4


#: a gap wider than the projector's cone: pings 18-43 lost (2.6 m of track; the array
#: passes 5.3-7.9 m unseen, over the points at 5.4, 6.2, 7.0 and 7.8 m). Before the
#: coverage rule's hidden responses were sidelobe sources, this gap gave 3 false
#: contacts in the tiles and 2 in the run, the sidelobes of the points under it.
WIDE = frozenset(range(18, 44))


@pytest.fixture(scope="module")
def wide_gap(tmp_path_factory, hardware) -> Path:
    return processed(tmp_path_factory, hardware, "wide", WIDE, None)


@pytest.mark.slow
def test_a_gap_wider_than_the_cone_makes_no_contact_at_its_edges(wide_gap):
    """The point under the gap is reached by too few pings to detect; its sidelobes in
    the covered voxels beside the gap are sidelobes still (the point is their source,
    detected or not), and no contact; the contacts beside the gap say so."""
    for level in ("tile", "run"):
        r = score_tiles(wide_gap, SCENE, level=level)
        s = r["summary"]
        assert s["false_alarms"] == 0 and s["duplicates"] == 0, (level, r["detections"])
        assert s["hits"] >= 2, (level, r["truth"])   # points beside the gap
    rows = _contacts(wide_gap)
    assert any("gap" in c["circumstances"] and int(c["pings_missing"]) > 0 for c in rows)
