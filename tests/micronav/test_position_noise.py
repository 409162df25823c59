"""The attitude's noise as the positions' noise in the fusion (svss_proc/micronav/renav.py
``attitude_position_noise``, fusion.py ``fuse_increments(position_noise=...)``).

The HDT heading (0.17 deg at 5 Hz) and the DVL's roll and pitch (0.05 deg at 5 Hz),
interpolated linearly to 10 pings a second, turn the 0.8 m lever arm from the DVL head to
the array: an error of each ping's *position*, correlated between neighbouring pings, so
the navigation's step errors are correlated too (negatively at lag 1). Simulated here
(the attitude samples at a phase to the pings the model does not know), with the DVL's
independent step noise and echo increments of 1 mm: fused with that model, the steps'
errors are smaller than fused as independent step noise (the re-navigation's sigma), and
their stated sigma is right (rms(err/sigma) ~ 1)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from svss_daq.config import DevicesConfig, HardwareConfig, config_path, load
from svss_daq.ping import NAV_BOTTOM_LOCK, NAV_DVL_VELOCITY, NAV_FUSED, NavSnapshot
from svss_proc.micronav.fusion import fuse_increments
from svss_proc.micronav.renav import (_turned, array_lever_m, attitude_position_noise,
                                      nav_increment_sigma)

N = 300
DT = 0.1
ECHO_SIGMA_M = 1e-3
LOCKED = NAV_FUSED | NAV_BOTTOM_LOCK | NAV_DVL_VELOCITY


def _poses(truth: np.ndarray, heading: float) -> list[NavSnapshot]:
    return [NavSnapshot(time_ns=int(round(k * DT * 1e9)), north_m=float(x[0]),
                        east_m=float(x[1]), down_m=float(x[2]), vel_north_m_s=1.0,
                        vel_east_m_s=0.0, vel_down_m_s=0.0, roll_rad=0.0, pitch_rad=0.0,
                        heading_rad=heading, altitude_m=2.0, quality=LOCKED)
            for k, x in enumerate(truth)]


def _interp_noise(rng, t, interval, sigma, phase):
    """White samples every ``interval`` from ``-phase`` interpolated linearly to ``t``."""
    ts = -phase + interval * np.arange(int(t[-1] / interval) + 3)
    return np.interp(t, ts, rng.normal(0.0, sigma, ts.size))


@pytest.fixture(scope="module")
def setup():
    nav_cfg = load(DevicesConfig, config_path("devices.toml")).navigation
    lever = array_lever_m(load(HardwareConfig, config_path("hardware.toml")).lever_arms)
    return nav_cfg, lever


def _trial(seed: int, nav_cfg, lever):
    rng = np.random.default_rng(seed)
    t = np.arange(N) * DT
    truth = np.column_stack([t * 1.0, 0.01 * np.sin(t / 3), 5 + 0.005 * np.cos(t / 2)])
    heading = 0.0
    poses_true = _poses(truth, heading)
    jac = _turned(poses_true, lever)                     # (n, 3 angles, 3 NED)
    angles = np.column_stack([
        _interp_noise(rng, t, nav_cfg.dvl_interval_s,
                      math.radians(nav_cfg.dvl_tilt_sigma_deg), 0.13),
        _interp_noise(rng, t, nav_cfg.dvl_interval_s,
                      math.radians(nav_cfg.dvl_tilt_sigma_deg), 0.13),
        _interp_noise(rng, t, nav_cfg.heading_interval_s,
                      math.radians(nav_cfg.heading_sigma_deg), 0.07)])
    delta = np.einsum("ka,kai->ki", angles, jac)
    walk = np.cumsum(rng.normal(0.0, nav_cfg.dvl_velocity_sigma_m_s * DT, (N, 3)), axis=0)
    nav = truth + delta + walk
    poses = _poses(nav, heading)
    true_steps = np.diff(truth, axis=0)
    echo = true_steps + rng.normal(0.0, ECHO_SIGMA_M, (N - 1, 3))
    ecov = np.repeat(np.eye(3)[None] * ECHO_SIGMA_M ** 2, N - 1, axis=0)
    # as independent step noise: the re-navigation's step sigma, the lever arm's part in
    step_sig = nav_increment_sigma(poses, nav_cfg, lever)
    x_step, _ = fuse_increments(nav, np.einsum("ki,ij->kij", step_sig ** 2, np.eye(3)),
                                echo, ecov)
    # as the positions' noise
    own = nav_increment_sigma(poses, nav_cfg, lever, lever_term=False)
    x_pos, cov = fuse_increments(nav, np.einsum("ki,ij->kij", own ** 2, np.eye(3)), echo,
                                 ecov, position_noise=attitude_position_noise(
                                     poses, nav_cfg, lever), step_covariance=True)
    err_step = np.diff(x_step, axis=0) - true_steps
    err_pos = np.diff(x_pos, axis=0) - true_steps
    sig = np.sqrt(np.einsum("kii->ki", cov))
    return err_step, err_pos, sig, np.diff(nav, axis=0) - true_steps


def test_the_navigations_step_errors_are_negatively_correlated(setup):
    """The premise: the attitude's part of the steps' errors is anticorrelated at lag 1."""
    nav_cfg, lever = setup
    _, _, _, nav_err = _trial(3, nav_cfg, lever)
    e = nav_err[:, 1]                                     # east: across (heading 0)
    r1 = float(np.corrcoef(e[:-1], e[1:])[0, 1])
    print("lag-1 correlation of the navigation's across-track step errors", r1)
    assert abs(r1) > 0.2


@pytest.mark.parametrize("seed", [1, 2])
def test_position_noise_fuses_better_than_step_noise(setup, seed):
    nav_cfg, lever = setup
    err_step, err_pos, sig, _ = _trial(seed, nav_cfg, lever)
    rms_step = np.sqrt(np.mean(err_step ** 2, axis=0))
    rms_pos = np.sqrt(np.mean(err_pos ** 2, axis=0))
    ratio = np.sqrt(np.mean((err_pos / sig) ** 2, axis=0))
    print(f"fused step error rms (N, E, D) mm: as step noise {np.round(rms_step * 1e3, 3)}, "
          f"as position noise {np.round(rms_pos * 1e3, 3)}; rms(err/sigma) "
          f"{np.round(ratio, 2)}")
    # across (east) and down, where the lever arm turns: smaller errors
    assert rms_pos[1] < 0.95 * rms_step[1] and rms_pos[2] <= rms_step[2] * 1.02
    # the stated sigma is the errors'
    assert np.all((ratio > 0.8) & (ratio < 1.25)), ratio
