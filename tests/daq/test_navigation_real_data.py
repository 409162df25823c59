"""The bridges from the drivers' records to navigation inputs, on the real recordings."""

from __future__ import annotations

import math

import numpy as np
import pytest

from svss_daq.protocols.nmea import GgaFix, NmeaStreamParser
from svss_daq.protocols.pd0 import Pd0StreamParser
from svss_daq.config import DevicesConfig, config_path, load
from svss_daq.navigation import Navigator, compute_poses, dvl_sample_from_pd0, samples_from_nmea
from tests.conftest import SHARED_DATA

DVL = SHARED_DATA / "dvl_pd0" / "RDI_withBT.000"
GPS = SHARED_DATA / "gps_nmea" / "hemi.log"


@pytest.fixture(scope="module")
def ensembles():
    if not DVL.exists():
        pytest.skip(f"real recordings not found: {DVL.parent}")
    parser = Pd0StreamParser()
    return list(parser.feed(DVL.read_bytes()))


def test_dvl_samples_from_real_pd0(ensembles):
    samples = [(e, dvl_sample_from_pd0(e)) for e in ensembles]
    with_bt = [(e, s) for e, s in samples if s is not None]
    assert len(with_bt) > 1000
    n_range = 0
    for e, s in with_bt:
        assert s.time_ns == e.variable.time_ns
        rng = np.asarray(e.bottom_track.range_m, dtype=float)[:4]
        np.testing.assert_array_equal(np.isnan(s.ranges_m[: rng.size]), np.isnan(rng))
        n_range += int(np.isfinite(s.ranges_m).any())
        v = -np.asarray(e.bottom_track.velocity_mps[:3], dtype=float)
        body = np.asarray(s.velocity_body_m_s)
        # the mapping is a rotation: speed is kept
        if np.all(np.isfinite(v)):
            assert abs(np.linalg.norm(body) - np.linalg.norm(v)) < 1e-9
    assert n_range > 1000       # the bottom was found in most of the file


@pytest.fixture(scope="module")
def records():
    if not GPS.exists():
        pytest.skip(f"real recordings not found: {GPS.parent}")
    parser = NmeaStreamParser()
    out = []
    for i, line in enumerate(GPS.read_bytes().splitlines(keepends=True)):
        for rec in parser.feed(line):
            out.append((10**18 + i * 10**8, rec))     # host receive times
    return out


def test_gps_fixes_and_headings_from_real_nmea(records):
    fixes, heads = samples_from_nmea(records)
    ggas = [r for _, r in records if isinstance(r, GgaFix) and r.fix_quality > 0
            and r.time_ns is not None]
    assert len(fixes) >= len(ggas) > 0
    for f, g in zip(fixes, ggas):
        assert f.time_ns == g.time_ns
        assert (f.latitude_deg, f.longitude_deg) == (g.latitude_deg, g.longitude_deg)
    assert heads and all(0 <= h.heading_rad < 2 * math.pi for h in heads)


def test_navigator_collects_the_bridges_samples_and_poses_them(records, ensembles, hardware):
    """The hardware path's collector: what it holds is what the bridges give, its survey
    origin is the first fix (devices.toml sets none), its poses are compute_poses' on
    what it holds, and it forgets what is older than its history before the poses."""
    cfg = load(DevicesConfig, config_path("devices.toml")).navigation
    assert cfg.origin_latitude_deg is None
    lever = hardware.value.lever_arms
    nav = Navigator(cfg, lever, history_s=2.0)
    nav.add_nmea(records)
    for e in ensembles:
        nav.add_pd0(e)
    fixes, heads = samples_from_nmea(records, cfg.course_min_speed_m_s)
    dvl = [d for d in map(dvl_sample_from_pd0, ensembles) if d is not None]
    assert fixes and heads and dvl
    assert [f.time_ns for f in nav.fixes] == [f.time_ns for f in fixes]
    assert [h.time_ns for h in nav.headings] == [h.time_ns for h in heads]
    assert [d.time_ns for d in nav.dvl] == [d.time_ns for d in dvl]
    f0 = fixes[0]
    assert nav.origin == (f0.latitude_deg, f0.longitude_deg,
                          0.0 if math.isnan(f0.height_m) else f0.height_m)
    times = np.array([f.time_ns for f in fixes[len(fixes) // 2::7]], dtype=np.int64)
    got = nav.poses(times)
    keep = times.min() - 2 * 10**9
    want = compute_poses(times, [f for f in fixes if f.time_ns >= keep],
                         [h for h in heads if h.time_ns >= keep],
                         [d for d in dvl if d.time_ns >= keep], cfg, lever, nav.origin)
    assert len(got) == len(want) == times.size
    # field by field (altitude is NaN without bottom lock); the live chain re-adds each
    # step to the previous pose: equal to the last bits (5.6e-17 m seen)
    np.testing.assert_allclose(np.array([list(vars(g).values()) for g in got], dtype=float),
                               np.array([list(vars(w).values()) for w in want], dtype=float),
                               rtol=0, atol=1e-9, equal_nan=True)
    # the 10 s GPS recording is partly older than 2 s before the first pose; the DVL
    # recording (a year earlier) wholly
    assert 0 < len(nav.fixes) == sum(f.time_ns >= keep for f in fixes) < len(fixes)
    assert all(f.time_ns >= keep for f in nav.fixes) and nav.dvl == []
