"""The re-navigation's step sigma (svss_proc.micronav.renav) on the bottom-track form a
real DVL records (``../shared/data/dvl_pd0/RDI_withBT.000``, a Workhorse with bottom
tracking, ensembles 1.5 s apart): 228 ensembles have an invalid bottom-track velocity
(RDI's -32768 on all four beams) but non-zero ranges, 3 of them on the three beams an
altitude needs. Decoded by the project's PD0 parser and navigated, those ensembles give
no velocity; the navigation holds the last one, so a step touching them is not a step
the DVL carried: its sigma is the held velocity's, not the DVL's 3 mm/s, even where the
ranges give the pose an altitude (``NAV_BOTTOM_LOCK``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from svss_daq.config import DevicesConfig, config_path, load
from svss_daq.navigation import compute_poses, dvl_sample_from_pd0
from svss_daq.ping import NAV_BOTTOM_LOCK, NAV_DVL_VELOCITY, NAV_FUSED
from svss_daq.protocols.pd0 import Pd0StreamParser
from svss_proc.micronav.renav import locked_steps, nav_increment_sigma
from tests.conftest import SHARED_DATA

DVL = SHARED_DATA / "dvl_pd0" / "RDI_withBT.000"


@pytest.fixture(scope="module")
def navigated(hardware):
    if not DVL.exists():
        pytest.skip(f"real recordings not found: {DVL.parent}")
    pairs = [(e, dvl_sample_from_pd0(e)) for e in Pd0StreamParser().feed(DVL.read_bytes())]
    pairs = [(e, s) for e, s in pairs if s is not None]
    invalid = np.array([e.bottom_track is not None
                        and np.all(np.asarray(e.bottom_track.velocity_raw)[:4] == -32768)
                        and np.any(np.nan_to_num(np.asarray(e.bottom_track.range_m,
                                                            dtype=float)) > 0)
                        for e, _ in pairs])
    cfg = dataclasses.replace(load(DevicesConfig, config_path("devices.toml")).navigation,
                              origin_latitude_deg=0.0, origin_longitude_deg=0.0,
                              origin_height_m=0.0)
    samples = [s for _, s in pairs]
    # posed at the ensembles' own times (dead reckoning from the configured origin)
    poses = compute_poses([s.time_ns for s in samples], [], [], samples, cfg,
                          hardware.value.lever_arms)
    return samples, invalid, poses, cfg


def test_invalid_bottom_track_velocity_with_ranges_is_no_lock(navigated):
    samples, invalid, poses, cfg = navigated
    assert invalid.sum() == 228
    # the parser gives those ensembles no velocity; some keep an altitude from the ranges
    assert all(np.all(np.isnan(s.velocity_body_m_s)) for s, bad in zip(samples, invalid)
               if bad)
    q = np.array([p.quality for p in poses], dtype=np.int64)
    with_altitude = invalid & ((q & NAV_BOTTOM_LOCK) > 0)
    assert with_altitude.sum() == 3
    # where the velocity is valid the navigation's steps are the DVL's
    valid = np.array([np.all(np.isfinite(s.velocity_body_m_s)) for s in samples])
    assert np.all((q[valid] & NAV_DVL_VELOCITY) > 0) and np.all((q[valid] & NAV_FUSED) > 0)
    assert not np.any((q[invalid] & NAV_DVL_VELOCITY) > 0)
    # every step touching an invalid ensemble is no lock: the held velocity's sigma
    touching = invalid[:-1] | invalid[1:]
    locked = locked_steps(poses)
    assert not locked[touching].any()
    sigma = nav_increment_sigma(poses, cfg)
    dt = np.diff([p.time_ns for p in poses]) * 1e-9
    np.testing.assert_allclose(sigma[touching, 0],
                               cfg.dvl_gap_velocity_sigma_m_s * dt[touching])
    both_valid = valid[:-1] & valid[1:]
    assert locked[both_valid].all()
