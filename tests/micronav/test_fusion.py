"""Fusion of the navigation's and the echoes' increments (svss_proc/micronav/fusion.py):
against the closed form of each step's inverse-covariance mean, and on a simulated
track whose DVL has noise, a scale error and misalignment, and a dropout, with the
echoes' increments refused at every sixth step (the projector sequence's wrap)."""

from __future__ import annotations

import numpy as np

from svss_proc.micronav.fusion import fuse_increments, increment_covariance


def _track(n, rng):
    """A true track at 1 m/s, 10 pings/s, with a wandering sway and heave, m."""
    inc = np.column_stack([0.1 + 0.002 * rng.normal(size=n - 1),
                           0.004 * rng.normal(size=n - 1), 0.002 * rng.normal(size=n - 1)])
    return np.vstack([np.zeros(3), np.cumsum(inc, axis=0)])


def test_each_step_is_the_inverse_covariance_mean_of_its_two_measurements():
    rng = np.random.default_rng(5)
    n = 40
    nav = np.cumsum(rng.normal(size=(n, 3)) * 0.01, axis=0)
    mic = rng.normal(size=(n - 1, 3)) * 0.01
    ncov = np.array([increment_covariance(rng.uniform(0.5e-3, 3e-3, 3)) for _ in range(n - 1)])
    mcov = []
    for _ in range(n - 1):                      # full covariances, correlated components
        q = rng.normal(size=(3, 3)) * 1e-3
        mcov.append(q @ q.T + np.eye(3) * 1e-7)
    mcov = np.array(mcov)
    mic[::6] = np.nan                          # refused steps
    x, fcov = fuse_increments(nav, ncov, mic, mcov, anchor_sigma_m=1e3)
    for k in range(n - 1):
        ni = np.linalg.inv(ncov[k])
        if np.isnan(mic[k]).any():
            want = nav[k + 1] - nav[k]
            wcov = ncov[k]
        else:
            mi = np.linalg.inv(mcov[k])
            wcov = np.linalg.inv(ni + mi)
            want = wcov @ (ni @ (nav[k + 1] - nav[k]) + mi @ mic[k])
        np.testing.assert_allclose(x[k + 1] - x[k], want, atol=1e-8)
        np.testing.assert_allclose(fcov[k], wcov, rtol=1e-9)
    # the anchor keeps the mean where the navigation has it (to the solver's precision:
    # the anchor's weight is 1e-12 of the steps')
    np.testing.assert_allclose(x.mean(axis=0), nav.mean(axis=0), atol=1e-4)


def test_the_echoes_carry_the_geometry_where_the_dvl_is_worse_and_not_where_it_is_better():
    rng = np.random.default_rng(8)
    n = 150                                     # 15 s
    true = _track(n, rng)
    t_inc = np.diff(true, axis=0)
    # DVL: 0.5 % scale error along, 1 degree misalignment, noise, a 10 s dropout (60-160:
    # the last velocity held)
    turn = np.radians(1.0)
    rot = np.array([[np.cos(turn), -np.sin(turn), 0], [np.sin(turn), np.cos(turn), 0],
                    [0, 0, 1]])
    dvl_sigma = np.array([0.3e-3, 0.3e-3, 0.3e-3])
    dvl_inc = (t_inc * [1.005, 1.0, 1.0]) @ rot.T + rng.normal(size=t_inc.shape) * dvl_sigma
    drop = slice(40, 140)
    dvl_inc[drop] = dvl_inc[39]
    ncov = np.array([increment_covariance(dvl_sigma) for _ in range(n - 1)])
    # held velocity: its error grows with what the boat does, a few mm a step here
    ncov[drop] = increment_covariance([5e-3, 5e-3, 3e-3])
    nav = np.vstack([np.zeros(3), np.cumsum(dvl_inc, axis=0)])
    # the echoes: 2.5 / 2.5 / 0.4 mm per step, none at every sixth step
    mic_sigma = np.array([2.5e-3, 2.5e-3, 0.4e-3])
    mic = t_inc + rng.normal(size=t_inc.shape) * mic_sigma
    mic[5::6] = np.nan
    mcov = np.array([increment_covariance(mic_sigma) for _ in range(n - 1)])
    x, fcov = fuse_increments(nav, ncov, mic, mcov)

    def err(pos, where):
        e = np.diff(pos, axis=0)[where] - t_inc[where]
        return np.sqrt(np.mean(e ** 2, axis=0))

    inside = np.zeros(n - 1, bool)
    inside[drop] = True
    measured = ~np.isnan(mic).any(axis=1)
    # in the dropout the fused steps follow the echoes (their error, not the DVL's)
    e_nav, e_fused = err(nav, inside & measured), err(x, inside & measured)
    print("dropout, steps with echoes: nav", np.round(e_nav * 1e3, 2), "fused",
          np.round(e_fused * 1e3, 2), "mm")
    assert np.all(e_fused < 0.7 * e_nav)
    assert np.all(e_fused < 1.3 * mic_sigma)
    # outside it the DVL's noise is the smaller: the fused steps are no worse than the
    # DVL's, and the misalignment's 1.7 mm sway a step stays (the echoes weigh 1/70)
    out = ~inside
    e_nav, e_fused = err(nav, out), err(x, out)
    print("outside: nav", np.round(e_nav * 1e3, 2), "fused", np.round(e_fused * 1e3, 2), "mm")
    assert np.all(e_fused <= e_nav * 1.01)
    # the reported covariance of a fused step is the smaller of the two where both exist
    k = np.flatnonzero(inside & measured)[0]
    assert np.all(np.diag(fcov[k]) < np.diag(mcov[k]))
    assert np.all(np.diag(fcov[k]) < np.diag(ncov[k]))


def test_the_acceleration_prior_carries_a_step_neither_measurement_knows():
    """A smooth track (sway and heave of a boat in a chop: 0.04 m/s^2); every sixth step
    has no echo increment and the navigation's is unknown (a dropout: 30 mm sigma, the
    GPS's noise). With the prior (0.2 m/s^2: 2 mm a second difference at 10 pings/s)
    those steps follow their neighbours; without it they keep the navigation's error.
    With a single free step and no anchor, the prior's solution is the mean of its two
    neighbours, whatever the navigation says."""
    rng = np.random.default_rng(21)
    n = 91
    t = np.arange(n) * 0.1
    true = np.column_stack([t, 0.05 * np.sin(2 * np.pi * t / 7.0),
                            0.03 * np.sin(2 * np.pi * t / 5.0)])
    t_inc = np.diff(true, axis=0)
    mic_sigma = np.array([2.5e-3, 2.5e-3, 0.4e-3])
    mic = t_inc + rng.normal(size=t_inc.shape) * mic_sigma
    mic[5::6] = np.nan
    mcov = np.array([increment_covariance(mic_sigma)] * (n - 1))
    nav_sigma = 0.03
    nav = true + rng.normal(size=true.shape) * nav_sigma / np.sqrt(2)
    ncov = np.array([increment_covariance([nav_sigma] * 3)] * (n - 1))
    free = np.isnan(mic).any(axis=1)
    x0, _ = fuse_increments(nav, ncov, mic, mcov)
    x1, _ = fuse_increments(nav, ncov, mic, mcov, step_change_sigma_m=0.2 * 0.1 ** 2)
    e0 = np.abs(np.diff(x0, axis=0) - t_inc)[free]
    e1 = np.abs(np.diff(x1, axis=0) - t_inc)[free]
    print("free steps' rms error (mm) without / with the prior",
          np.round(np.sqrt(np.mean(e0 ** 2, axis=0)) * 1e3, 2),
          np.round(np.sqrt(np.mean(e1 ** 2, axis=0)) * 1e3, 2))
    assert np.all(np.sqrt(np.mean(e0 ** 2, axis=0)) > 8e-3)
    assert np.all(np.sqrt(np.mean(e1 ** 2, axis=0)) < 3e-3)
    # the measured steps are not made worse by the prior
    e_meas = np.sqrt(np.mean((np.diff(x1, axis=0) - t_inc)[~free] ** 2, axis=0))
    assert np.all(e_meas < 1.3 * mic_sigma)
    # closed form: one free step between two exactly measured ones
    nav3 = np.array([[0.0, 0, 0], [0.1, 0.0, 0], [0.5, 0.3, -0.2], [0.6, 0.3, -0.2]])
    mic3 = np.array([[0.1, 0.01, 0.002], [np.nan] * 3, [0.12, 0.03, -0.002]])
    mcov3 = np.array([np.eye(3) * 1e-14] * 3)
    ncov3 = np.array([np.eye(3) * 1.0] * 3)
    x3, _ = fuse_increments(nav3, ncov3, mic3, mcov3, anchor_sigma_m=1e4,
                            step_change_sigma_m=1e-3)
    np.testing.assert_allclose(np.diff(x3, axis=0)[1], 0.5 * (mic3[0] + mic3[2]), atol=1e-6)
