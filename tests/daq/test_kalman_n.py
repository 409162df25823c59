"""The n-state Kalman filter and RTS smoother (svss_daq.nav.kalman.filter_smooth_n)
against independent calculations: the two-state filter of the horizontal axes on the
same model, and, for the four states of the down axis, the batch weighted
least-squares solution of the whole record, which a linear-Gaussian smoother equals."""

from __future__ import annotations

import numpy as np

from svss_daq.nav.kalman import filter_smooth, filter_smooth_n


def test_two_states_agree_with_the_two_state_filter():
    rng = np.random.default_rng(3)
    k_n = 200
    u, f01 = rng.normal(0, 0.1, k_n - 1), np.full(k_n - 1, 0.2)
    f11 = np.exp(-0.2 / 50.0) * np.ones(k_n - 1)
    qp, qc = np.full(k_n - 1, 1e-4), np.full(k_n - 1, 1e-6)
    step = np.sort(rng.integers(0, k_n, 80))
    h0, h1 = np.ones(80), rng.choice([0.0, 1.0], 80)
    z, r = rng.normal(0, 1, 80), np.full(80, 0.09)
    x0, p0 = np.array([0.3, 0.0]), np.diag([4.0, 1e-4])
    f = np.zeros((k_n - 1, 2, 2))
    f[:, 0, 0], f[:, 0, 1], f[:, 1, 1] = 1.0, f01, f11
    q = np.zeros((k_n - 1, 2, 2))
    q[:, 0, 0], q[:, 1, 1] = qp, qc
    uu = np.stack([u, np.zeros(k_n - 1)], -1)
    for smooth in (False, True):
        xa, pa = filter_smooth(x0, p0, u, f01, f11, qp, qc, (step, h0, h1, z, r), smooth)
        xb, pb = filter_smooth_n(x0, p0, uu, f, q, (step, np.stack([h0, h1], -1), z, r),
                                 smooth)
        np.testing.assert_allclose(xb, xa, rtol=0, atol=1e-9)
        np.testing.assert_allclose(pb, pa, rtol=0, atol=1e-12)


def test_four_states_smoothed_are_the_batch_least_squares_solution():
    """x[k+1] = F[k] x[k] + u[k] + w[k], w ~ N(0, Q[k]) (Q positive definite), x[0] ~
    N(x0, P0), measurements z = h x[k] + v: the smoothed states minimise the sum of the
    squared, weighted residuals of prior, process and measurements; solved here as one
    dense least-squares problem over all 4 K unknowns."""
    rng = np.random.default_rng(5)
    k_n, n = 40, 4
    disp = rng.normal(0.3, 0.05, (k_n - 1, 2))
    f = np.tile(np.eye(n), (k_n - 1, 1, 1))
    f[:, 1, 2], f[:, 1, 3] = disp[:, 0], disp[:, 1]
    u = np.zeros((k_n - 1, n))
    u[:, 0] = rng.normal(0, 0.01, k_n - 1)
    q = np.tile(np.diag([1e-4, 4e-6, 1e-5, 1e-5]), (k_n - 1, 1, 1))
    x0, p0 = np.array([0.5, 4.0, 0.0, 0.0]), np.diag([0.36, 1e4, 0.09, 0.09])
    rows, steps, zs = [], [], []
    for k in range(k_n):
        for _ in range(3):                       # three beams' footprints
            o = rng.normal(0, 1.5, 2)
            rows.append([-1.0, 1.0, o[0], o[1]])
            steps.append(k)
            zs.append(3.5 + 0.1 * o[0] - 0.05 * o[1] + rng.normal(0, 0.02))
        if k % 5 == 0:                           # a GPS height
            rows.append([1.0, 0.0, 0.0, 0.0])
            steps.append(k)
            zs.append(0.5 + rng.normal(0, 0.3))
    rows, steps, zs = np.array(rows), np.array(steps), np.array(zs)
    r = np.where(rows[:, 1] == 1.0, 4e-4, 0.09)
    xs, ps = filter_smooth_n(x0, p0, u, f, q, (steps, rows, zs, r), smooth=True)

    def whiten(cov):
        return np.linalg.cholesky(np.linalg.inv(cov)).T
    blocks, rhs = [], []
    a = np.zeros((n, n * k_n))
    a[:, :n] = np.eye(n)
    blocks.append(whiten(p0) @ a)
    rhs.append(whiten(p0) @ x0)
    for k in range(k_n - 1):
        a = np.zeros((n, n * k_n))
        a[:, n * k:n * k + n] = -f[k]
        a[:, n * (k + 1):n * (k + 2)] = np.eye(n)
        blocks.append(whiten(q[k]) @ a)
        rhs.append(whiten(q[k]) @ u[k])
    for h, k, z, var in zip(rows, steps, zs, r):
        a = np.zeros((1, n * k_n))
        a[0, n * k:n * k + n] = h
        blocks.append(a / np.sqrt(var))
        rhs.append(np.array([z / np.sqrt(var)]))
    sol, *_ = np.linalg.lstsq(np.vstack(blocks), np.concatenate(rhs), rcond=None)
    np.testing.assert_allclose(xs, sol.reshape(k_n, n), rtol=0, atol=1e-7)
