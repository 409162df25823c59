"""The live stage (svss_proc/micronav/live.py) weighs the navigation's steps as the
re-navigation's fusion does (renav.nav_increment_sigma: its lock rule, which needs the
DVL's velocity, and the attitude's noise turning the lever arm to the array): the stage
of a real Worker built from a processing configuration with ``[micronav] live``."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from svss_daq.config import (DevicesConfig, HardwareConfig, ProcessingConfig, config_path,
                             load, load_with_text, loaded_from_text)
from svss_daq.ping import (NAV_BOTTOM_LOCK, NAV_DVL_VELOCITY, NAV_FUSED, NAV_GPS_FIX,
                           NavSnapshot, Ping)
from svss_proc.micronav.renav import array_lever_m, nav_increment_sigma
from svss_proc.run_worker import Worker

from .test_live_stage import processing_text


def _ping(k: int, quality: int) -> Ping:
    nav = NavSnapshot(time_ns=k * 100_000_000, north_m=0.1 * k, east_m=0.0, down_m=5.0,
                      roll_rad=0.0, pitch_rad=0.0, heading_rad=0.0, altitude_m=2.0,
                      vel_north_m_s=1.0, vel_east_m_s=0.0, vel_down_m_s=0.0,
                      quality=quality)
    return Ping(sequence=k, projector=0, transmit_time_ns=nav.time_ns,
                sample_rate_hz=125e3, window_start_ns=0,
                samples=np.zeros((1, 1), np.int32), nav=nav)


@pytest.fixture(scope="module")
def stage(tmp_path_factory):
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    proc = loaded_from_text(ProcessingConfig, processing_text(True, 2.0, -0.1, 0.4), "live")
    nav_cfg = load(DevicesConfig, config_path("devices.toml")).navigation
    w = Worker(hw, proc, tmp_path_factory.mktemp("live_sigma"))
    assert w.micronav is not None
    return w.micronav, nav_cfg, hw.value


@pytest.mark.parametrize("quality", [
    NAV_FUSED | NAV_BOTTOM_LOCK | NAV_DVL_VELOCITY,       # locked: the DVL's sigma
    NAV_FUSED | NAV_BOTTOM_LOCK,      # ranges without a valid velocity: held, not locked
    NAV_FUSED | NAV_GPS_FIX])         # no bottom lock
def test_the_live_step_sigma_is_the_renavigations(stage, quality):
    live, nav_cfg, hw = stage
    assert live.nav_cfg == nav_cfg             # devices.toml's [navigation]
    a, b = _ping(10, quality), _ping(11, quality)
    want = nav_increment_sigma([a.nav, b.nav], nav_cfg, array_lever_m(hw.lever_arms))[0]
    got = np.sqrt(np.diag(live._nav_cov(a, b)))
    np.testing.assert_allclose(got, want, rtol=1e-12)
    dvl = nav_cfg.dvl_velocity_sigma_m_s * 0.1
    if quality & NAV_DVL_VELOCITY:
        # the attitude's noise over the 0.8 m lever arm dominates across (east)
        assert got[1] > 3 * dvl and got[0] < 2 * dvl
    else:                          # the held velocity's sigma, not the DVL's
        assert np.all(got >= nav_cfg.dvl_gap_velocity_sigma_m_s * 0.1 * (1 - 1e-9))


def test_a_held_velocity_is_weighed_less_than_a_locked_one(stage):
    live, _, _ = stage
    locked = NAV_FUSED | NAV_BOTTOM_LOCK | NAV_DVL_VELOCITY
    lk = np.diag(live._nav_cov(_ping(0, locked), _ping(1, locked)))
    held = np.diag(live._nav_cov(_ping(0, NAV_FUSED | NAV_BOTTOM_LOCK),
                                 _ping(1, NAV_FUSED | NAV_BOTTOM_LOCK)))
    assert np.all(held > 10 * lk), (held, lk)


def test_the_live_stage_weighs_a_step_as_the_renavigation_on_real_pings(stage):
    """The same through the poses of dataclasses.replace'd pings (any field the sigma
    reads: the time, the attitude, the velocity)."""
    live, nav_cfg, hw = stage
    q = NAV_FUSED | NAV_BOTTOM_LOCK | NAV_DVL_VELOCITY
    a = _ping(0, q)
    b = dataclasses.replace(a, nav=dataclasses.replace(
        a.nav, time_ns=200_000_000, heading_rad=0.3, pitch_rad=0.05))
    want = nav_increment_sigma([a.nav, b.nav], nav_cfg, array_lever_m(hw.lever_arms))[0]
    np.testing.assert_allclose(np.sqrt(np.diag(live._nav_cov(a, b))), want, rtol=1e-12)
