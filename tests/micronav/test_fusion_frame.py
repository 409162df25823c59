"""The re-navigation's fusion at the array's reference point (renav.fuse_poses).

The navigation's body-origin positions carry the heading's noise over the lever arm from
the DVL head to the body origin; the echoes' body-origin increments carry it over the
lever arm to the array (the estimator measures the array's displacement and was given
the navigation's attitudes). At the array both are what the models say: the
navigation's error is the DVL's plus the attitude's noise over the 0.8 m from the DVL
head (its position noise), the echoes' is their own. Simulated here with the configured
instruments (HDT 0.17 deg at 5 Hz, tilt 0.05 deg, DVL 3 mm/s) and echoes of 3.5 mm along
and across, 0.45 mm down (bench_focus's sand): fused at the array the steps across are
about half the navigation's; the same models applied at the body origin (what the code
did before) made them worse than the navigation's (the benchmark: 3.5 against 1.65 mm)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from svss_daq.config import (DevicesConfig, HardwareConfig, ProcessingConfig, config_path,
                             load)
from svss_daq.frames import body_to_ned
from svss_daq.ping import NAV_BOTTOM_LOCK, NAV_DVL_VELOCITY, NAV_FUSED, NavSnapshot
from svss_proc.micronav.fusion import fuse_increments
from svss_proc.micronav.renav import (array_lever_m, attitude_position_noise, fuse_poses,
                                      nav_increment_sigma)

N = 300
DT = 0.1
ECHO_SIGMA_M = np.array([3.5e-3, 3.5e-3, 0.45e-3])
LOCKED = NAV_FUSED | NAV_BOTTOM_LOCK | NAV_DVL_VELOCITY


def _noise(rng, t, interval, sigma_deg, phase):
    ts = -phase + interval * np.arange(int(t[-1] / interval) + 3)
    return np.interp(t, ts, rng.normal(0.0, math.radians(sigma_deg), ts.size))


def _rot(att):
    return np.array([body_to_ned(*a) for a in att])


@pytest.fixture(scope="module")
def configs():
    hw = load(HardwareConfig, config_path("hardware.toml"))
    nav = load(DevicesConfig, config_path("devices.toml")).navigation
    mn = load(ProcessingConfig, config_path("processing.toml")).micronav
    return hw.lever_arms, nav, mn


def _case(seed, lever_arms, nav_cfg):
    rng = np.random.default_rng(seed)
    t = np.arange(N) * DT
    true_att = np.column_stack([0.01 * np.sin(t / 4 * 2 * math.pi / 4),
                                0.01 * np.sin(t / 4.5 * 2 * math.pi / 4.5),
                                0.3 + 0.008 * np.sin(t * 2 * math.pi / 8)])
    body = np.column_stack([t * math.cos(0.3), t * math.sin(0.3) + 0.05 * np.sin(t / 7),
                            5 + 0.03 * np.sin(t / 5)])
    nav_att = true_att + np.column_stack([
        _noise(rng, t, nav_cfg.dvl_interval_s, nav_cfg.dvl_tilt_sigma_deg, 0.11),
        _noise(rng, t, nav_cfg.dvl_interval_s, nav_cfg.dvl_tilt_sigma_deg, 0.11),
        _noise(rng, t, nav_cfg.heading_interval_s, nav_cfg.heading_sigma_deg, 0.07)])
    r_true, r_nav = _rot(true_att), _rot(nav_att)
    dvl_arm = np.asarray(lever_arms.dvl_m, dtype=np.float64)
    arr_arm = np.asarray(lever_arms.array_m, dtype=np.float64)
    head = body + r_true @ dvl_arm
    walk = np.cumsum(rng.normal(0.0, nav_cfg.dvl_velocity_sigma_m_s * DT, (N, 3)), axis=0)
    nav_body = head + walk - r_nav @ dvl_arm
    true_array = body + r_true @ arr_arm
    # the echoes: the array's true displacement, returned as the body origin's with the
    # navigation's attitudes
    echo = (np.diff(true_array, axis=0) - np.diff(r_nav @ arr_arm, axis=0)
            + rng.normal(0.0, 1.0, (N - 1, 3)) * ECHO_SIGMA_M)
    ecov = np.repeat(np.diag(ECHO_SIGMA_M ** 2)[None], N - 1, axis=0)
    poses = [NavSnapshot(time_ns=int(round(k * DT * 1e9)), north_m=float(x[0]),
                         east_m=float(x[1]), down_m=float(x[2]),
                         vel_north_m_s=math.cos(0.3), vel_east_m_s=math.sin(0.3),
                         vel_down_m_s=0.0, roll_rad=float(a[0]), pitch_rad=float(a[1]),
                         heading_rad=float(a[2]), altitude_m=2.0, quality=LOCKED)
             for k, (x, a) in enumerate(zip(nav_body, nav_att))]
    return poses, echo, ecov, true_array, r_nav, arr_arm


def _across(err, heading=0.3):
    return err[:, 0] * -math.sin(heading) + err[:, 1] * math.cos(heading)


@pytest.mark.parametrize("seed", [4, 5])
def test_fused_at_the_array_halves_the_navigations_step_error(configs, seed):
    lever_arms, nav_cfg, mn = configs
    mn = dataclasses.replace(mn, bias_min_steps=10 ** 6)      # no bias in this simulation
    poses, echo, ecov, true_array, r_nav, arr_arm = _case(seed, lever_arms, nav_cfg)
    truth = np.diff(true_array, axis=0)

    def array_steps(ps):
        return np.diff(np.array([p.ned for p in ps]) + r_nav @ arr_arm, axis=0)

    fused, _, bias = fuse_poses(poses, echo, ecov, lever_arms, nav_cfg, mn)
    assert bias is None
    nav_err = _across(array_steps(poses) - truth)
    fus_err = _across(array_steps(fused) - truth)
    # the same models at the body origin (the code before)
    pos = np.array([p.ned for p in poses])
    lever = array_lever_m(lever_arms)
    own = nav_increment_sigma(poses, nav_cfg, lever, lever_term=False)
    x, _ = fuse_increments(pos, np.einsum("ki,ij->kij", own ** 2, np.eye(3)), echo, ecov,
                           mn.anchor_sigma_m, mn.acceleration_sigma_m_s2 * DT ** 2,
                           position_noise=attitude_position_noise(poses, nav_cfg, lever),
                           step_covariance=False)
    old_err = _across(np.diff(x + r_nav @ arr_arm, axis=0) - truth)
    rms = lambda e: float(np.sqrt(np.mean(e ** 2)))            # noqa: E731
    print(f"across-track step errors rms: navigation {rms(nav_err) * 1e3:.2f} mm, fused at "
          f"the array {rms(fus_err) * 1e3:.2f}, at the body origin {rms(old_err) * 1e3:.2f}")
    assert rms(fus_err) < 0.7 * rms(nav_err)
    assert rms(old_err) > rms(nav_err)
