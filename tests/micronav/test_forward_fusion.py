"""The forward fusion the live worker runs (svss_proc/micronav/forward_fusion.py) against
the batch fusion (svss_proc/micronav/fusion.py): with the pings up to k, the filter's
position of ping k is the batch minimiser's last position on those pings."""

from __future__ import annotations

import numpy as np

from svss_proc.micronav.forward_fusion import FusionState, fuse_forward, fusion_step
from svss_proc.micronav.fusion import fuse_increments


def _case(n=30, seed=5):
    rng = np.random.default_rng(seed)
    steps = np.column_stack([np.full(n - 1, 0.1), rng.normal(0, 0.004, n - 1),
                             rng.normal(0, 0.002, n - 1)])
    nav = np.vstack([np.zeros(3), np.cumsum(steps + rng.normal(0, 0.003, steps.shape), 0)])
    ncov = []
    for k in range(n - 1):
        a = rng.normal(size=(3, 3)) * 0.002
        ncov.append(a @ a.T + np.eye(3) * (0.03 if 10 <= k < 16 else 0.0005) ** 2)
    mic = steps + rng.normal(0, 0.002, steps.shape)
    mcov = []
    for k in range(n - 1):
        a = rng.normal(size=(3, 3)) * 0.001
        mcov.append(a @ a.T + np.diag([0.0025, 0.003, 0.0004]) ** 2)
    mic[5::6] = np.nan                                  # refused: the sequence's wrap
    return nav, np.array(ncov), mic, np.array(mcov)


def test_forward_equals_the_batch_minimiser_at_its_last_ping():
    nav, ncov, mic, mcov = _case()
    fwd = fuse_forward(nav, ncov, mic, mcov, 0.3)
    for k in range(2, nav.shape[0] + 1):
        batch, _ = fuse_increments(nav[:k], ncov[:k - 1], mic[:k - 1], mcov[:k - 1], 0.3)
        np.testing.assert_allclose(fwd[k - 1], batch[-1], atol=1e-9, rtol=0)
    # and the echoes changed something: the filter is not the navigation
    assert np.abs(fwd - nav).max() > 1e-3


def test_refused_steps_leave_the_navigation_unchanged():
    nav, ncov, mic, mcov = _case()
    mic[:] = np.nan
    np.testing.assert_array_equal(fuse_forward(nav, ncov, mic, mcov, 0.3), nav)


def test_a_step_from_a_known_ping_is_the_inverse_covariance_mean():
    # ping k's position known exactly and an anchor far weaker than the step: the fused
    # step is (N^-1 + M^-1)^-1 (N^-1 n + M^-1 m)
    n_cov, m_cov = np.diag([4e-6, 9e-6, 1e-6]), np.diag([1e-6, 1e-6, 4e-6])
    nav_step, micro = np.array([0.1, 0.002, -0.001]), np.array([0.103, 0.0, 0.0005])
    s0 = FusionState(np.zeros(3), np.zeros((3, 3)))
    s1, f_cov = fusion_step(s0, n_cov, micro - nav_step, m_cov, 1e4)
    ni, mi = np.linalg.inv(n_cov), np.linalg.inv(m_cov)
    want = np.linalg.solve(ni + mi, ni @ nav_step + mi @ micro)
    np.testing.assert_allclose(nav_step + s1.correction_m, want, atol=1e-9)
    np.testing.assert_allclose(f_cov, np.linalg.inv(ni + mi), rtol=1e-12)
