"""The bridges from the drivers' records to navigation inputs, on the real recordings."""

from __future__ import annotations

import math

import numpy as np
import pytest

from svss_daq.drivers.nmea import GgaFix, NmeaStreamParser
from svss_daq.drivers.pd0 import Pd0StreamParser
from svss_daq.navigation import dvl_sample_from_pd0, samples_from_nmea
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


def test_gps_fixes_and_headings_from_real_nmea():
    if not GPS.exists():
        pytest.skip(f"real recordings not found: {GPS.parent}")
    parser = NmeaStreamParser()
    records = []
    for i, line in enumerate(GPS.read_bytes().splitlines(keepends=True)):
        for rec in parser.feed(line):
            records.append((10**18 + i * 10**8, rec))     # host receive times
    fixes, heads = samples_from_nmea(records)
    ggas = [r for _, r in records if isinstance(r, GgaFix) and r.fix_quality > 0
            and r.time_ns is not None]
    assert len(fixes) >= len(ggas) > 0
    for f, g in zip(fixes, ggas):
        assert f.time_ns == g.time_ns
        assert (f.latitude_deg, f.longitude_deg) == (g.latitude_deg, g.longitude_deg)
    assert heads and all(0 <= h.heading_rad < 2 * math.pi for h in heads)
