"""Ping positions from the navigation's increments and the echoes' increments together
(docs/micronavigation.md, "Fusion").

The navigation (DVL-carried, GPS-bounded: svss_daq/nav) gives each ping's position p_k;
its increments n_k = p_(k+1) - p_k carry the DVL's errors (noise, a scale error, a
mounting misalignment, the held velocity of a dropout), each with a covariance N_k. The
micronavigation measures some of the same increments from the echoes, m_k with
covariance M_k, and none where it refused. The fused positions x_k minimise

    sum_k |x_(k+1) - x_k - n_k|^2_(N_k^-1) + sum_(k measured) |x_(k+1) - x_k - m_k|^2_(M_k^-1)
        + sum_k |x_k - p_k|^2 / s_a^2,

the last term a weak anchor (``anchor_sigma_m``, default 0.3 m: the GPS's) that keeps the
absolute position where the navigation has it and decides nothing within an aperture.
Optionally (``step_change_sigma_m`` s_c) a prior on the platform's acceleration adds

    sum_k |x_(k+1) - 2 x_k + x_(k-1)|^2 / s_c^2,

s_c = a T^2 for an acceleration a and ping interval T: a step neither the navigation nor
the echoes measure well (the projector sequence's 5 -> 0 step in a DVL dropout) then
follows its neighbours instead of the navigation's uncertain increment.
Without the anchor the steps decouple, and each fused increment is the
inverse-covariance mean of the two measurements of it,

    x_(k+1) - x_k = (N_k^-1 + M_k^-1)^-1 (N_k^-1 n_k + M_k^-1 m_k),

with covariance (N_k^-1 + M_k^-1)^-1 (the test checks the solution against this). So the
geometry comes from the echoes where their error is smaller than the DVL's and from the
DVL where the echoes are weak or absent, step by step. The problem is solved as sparse
normal equations, 3 unknowns per ping.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["fuse_increments", "increment_covariance"]


def increment_covariance(sigma_m) -> np.ndarray:
    """A diagonal (3, 3) covariance from standard deviations (3,), m."""
    s = np.asarray(sigma_m, dtype=np.float64).reshape(3)
    return np.diag(s * s)


def fuse_increments(nav_positions_m: np.ndarray, nav_cov_m2: np.ndarray,
                    micro_increments_m: np.ndarray, micro_cov_m2: np.ndarray,
                    anchor_sigma_m: float = 0.3, step_change_sigma_m=None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The fused positions (n, 3) of n pings and the covariance of each fused increment
    (n - 1, 3, 3) without the anchor (module docstring). ``nav_positions_m`` (n, 3) the
    navigation's; ``nav_cov_m2`` (n - 1, 3, 3) its increments' covariances;
    ``micro_increments_m`` (n - 1, 3) the echoes' increments, NaN rows where there is
    none (refused); ``micro_cov_m2`` (n - 1, 3, 3) theirs (ignored on NaN rows);
    ``step_change_sigma_m`` (scalar or (3,), m): the acceleration prior's sigma of a
    second difference, None for none (the returned covariances leave it out)."""
    p = np.asarray(nav_positions_m, dtype=np.float64)
    n = p.shape[0]
    if n < 2:
        return p.copy(), np.zeros((0, 3, 3))
    nav_inc = np.diff(p, axis=0)
    mic = np.asarray(micro_increments_m, dtype=np.float64)
    ncov = np.asarray(nav_cov_m2, dtype=np.float64)
    mcov = np.asarray(micro_cov_m2, dtype=np.float64)
    if mic.shape != (n - 1, 3) or ncov.shape != (n - 1, 3, 3) or mcov.shape != (n - 1, 3, 3):
        raise ValueError(f"{n} pings: expected increments (n - 1, 3) and covariances "
                         f"(n - 1, 3, 3), got {mic.shape}, {ncov.shape}, {mcov.shape}")
    if not anchor_sigma_m > 0:
        raise ValueError(f"anchor sigma {anchor_sigma_m!r} m: expected > 0")
    # each step's information and information-weighted increment
    info = np.linalg.inv(ncov)
    rhs_step = np.einsum("kij,kj->ki", info, nav_inc)
    fused_cov = np.empty((n - 1, 3, 3))
    have = np.all(np.isfinite(mic), axis=1)
    mi = np.zeros_like(info)
    mi[have] = np.linalg.inv(mcov[have])
    info = info + mi
    rhs_step = rhs_step + np.einsum("kij,kj->ki", mi, np.where(have[:, None], mic, 0.0))
    fused_cov[:] = np.linalg.inv(info)
    # normal equations: sum_k (x_(k+1) - x_k)^T I_k (x_(k+1) - x_k) - 2 (..)^T r_k
    #   + |x - p|^2 / s^2
    a = 1.0 / anchor_sigma_m ** 2
    rows, cols, vals = [], [], []
    b = np.zeros((n, 3))
    idx = lambda k: 3 * k + np.arange(3)                       # noqa: E731
    for k in range(n - 1):
        i, j = idx(k), idx(k + 1)
        for (r, c, s) in ((i, i, 1.0), (j, j, 1.0), (i, j, -1.0), (j, i, -1.0)):
            rr, cc = np.meshgrid(r, c, indexing="ij")
            rows.append(rr.ravel())
            cols.append(cc.ravel())
            vals.append((s * info[k]).ravel())
        b[k] -= rhs_step[k]
        b[k + 1] += rhs_step[k]
    if step_change_sigma_m is not None and n >= 3:
        sc = np.broadcast_to(np.asarray(step_change_sigma_m, dtype=np.float64), (3,))
        if not np.all(sc > 0):
            raise ValueError(f"step change sigma {step_change_sigma_m!r} m: expected > 0")
        w = 1.0 / sc ** 2
        coef = (1.0, -2.0, 1.0)
        ax = np.arange(3)
        for k in range(1, n - 1):
            for a_i, c_i in zip((k - 1, k, k + 1), coef):
                for a_j, c_j in zip((k - 1, k, k + 1), coef):
                    rows.append(3 * a_i + ax)
                    cols.append(3 * a_j + ax)
                    vals.append(c_i * c_j * w)
    diag = np.arange(3 * n)
    rows.append(diag)
    cols.append(diag)
    vals.append(np.full(3 * n, a))
    b += a * p
    h = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(3 * n, 3 * n))
    x = spla.spsolve(h, b.ravel()).reshape(n, 3)
    return x, fused_cov
