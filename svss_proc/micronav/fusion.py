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

**Position noise** (``position_noise`` S, sparse (3n, m)): where part of the
navigation's error is an error of each position, p_k = x_k + (S theta)_k + (the DVL's
random walk), theta m unit-variance white unknowns (the attitude's noise turning a lever
arm: :func:`.renav.attitude_position_noise`), the first sum becomes

    sum_k |x_(k+1) - x_k + (S theta)_(k+1) - (S theta)_k - n_k|^2_(N_k^-1) + |theta|^2

and theta is estimated with the positions (N_k then the steps' own noise only): the
step errors' correlation between neighbours, which a step noise cannot state.
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


def _difference(n: int) -> sp.csr_matrix:
    """(3 (n - 1), 3 n): the increments x_(k+1) - x_k of n positions (3 axes each)."""
    d = sp.diags([-np.ones(n - 1), np.ones(n - 1)], [0, 1], shape=(n - 1, n))
    return sp.kron(d, sp.identity(3), format="csr")


def _block_diag(blocks: np.ndarray) -> sp.csr_matrix:
    return sp.block_diag(list(blocks), format="csr")


def fuse_increments(nav_positions_m: np.ndarray, nav_cov_m2: np.ndarray,
                    micro_increments_m: np.ndarray, micro_cov_m2: np.ndarray,
                    anchor_sigma_m: float = 0.3, step_change_sigma_m=None,
                    position_noise=None, step_covariance: bool = True
                    ) -> tuple[np.ndarray, np.ndarray | None]:
    """The fused positions (n, 3) of n pings and the covariance of each fused increment
    (n - 1, 3, 3) (module docstring). ``nav_positions_m`` (n, 3) the
    navigation's; ``nav_cov_m2`` (n - 1, 3, 3) its increments' covariances (the
    independent part: the DVL's); ``micro_increments_m`` (n - 1, 3) the echoes'
    increments, NaN rows where there is none (refused); ``micro_cov_m2`` (n - 1, 3, 3)
    theirs (ignored on NaN rows); ``step_change_sigma_m`` (scalar or (3,), m): the
    acceleration prior's sigma of a second difference, None for none.
    ``position_noise``: None, or a sparse (3 n, m) S: the navigation's positions carry
    an error S theta, theta m unit-variance white unknowns (module docstring, "Position
    noise"; :func:`.renav.attitude_position_noise`), estimated with the positions.
    Without it the covariances are (N_k^-1 + M_k^-1)^-1 (without the anchor and the
    prior); with it those of the fused increments under the whole model, computed only
    with ``step_covariance`` (a solve per step: None without)."""
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
    ninfo = np.linalg.inv(ncov)
    have = np.all(np.isfinite(mic), axis=1)
    minfo = np.zeros_like(ninfo)
    minfo[have] = np.linalg.inv(mcov[have])
    d = _difference(n)
    m_rhs = np.einsum("kij,kj->ki", minfo, np.where(have[:, None], mic, 0.0)).ravel()
    n_rhs = np.einsum("kij,kj->ki", ninfo, nav_inc).ravel()
    wn, wm = _block_diag(ninfo), _block_diag(minfo)
    # normal equations of the positions: the steps' two measurements, the anchor
    hxx = d.T @ (wn + wm) @ d + sp.identity(3 * n) / anchor_sigma_m ** 2
    bx = d.T @ (n_rhs + m_rhs) + p.ravel() / anchor_sigma_m ** 2
    if step_change_sigma_m is not None and n >= 3:
        sc = np.broadcast_to(np.asarray(step_change_sigma_m, dtype=np.float64), (3,))
        if not np.all(sc > 0):
            raise ValueError(f"step change sigma {step_change_sigma_m!r} m: expected > 0")
        d2 = sp.kron(sp.diags([np.ones(n - 2), -2 * np.ones(n - 2), np.ones(n - 2)],
                              [0, 1, 2], shape=(n - 2, n)), sp.identity(3), format="csr")
        hxx = hxx + d2.T @ sp.kron(sp.identity(n - 2), sp.diags(1.0 / sc ** 2)) @ d2
    if position_noise is None:
        x = spla.spsolve(sp.csc_matrix(hxx), bx).reshape(n, 3)
        return x, np.linalg.inv(ninfo + minfo)
    s_ = sp.csr_matrix(position_noise)
    if s_.shape[0] != 3 * n:
        raise ValueError(f"position noise {s_.shape}: expected (3 n = {3 * n}, m)")
    # the navigation's steps are x_(k+1) - x_k + (S theta)_(k+1) - (S theta)_k + w_k
    ds = d @ s_
    hxt = d.T @ wn @ ds
    htt = ds.T @ wn @ ds + sp.identity(s_.shape[1])
    h = sp.bmat([[hxx, hxt], [hxt.T, htt]], format="csc")
    b = np.concatenate([bx, ds.T @ n_rhs])
    lu = spla.splu(h)
    x = lu.solve(b)[:3 * n].reshape(n, 3)
    return x, _step_covariance(lu, d, h.shape[0]) if step_covariance else None


def _step_covariance(lu, d: sp.csr_matrix, size: int, block: int = 256) -> np.ndarray:
    """The (n - 1, 3, 3) covariances of the increments d x of the solution of the normal
    equations factorised in ``lu`` (x its first d.shape[1] unknowns), a few columns at a
    time (the inverse is dense)."""
    m = d.shape[0]
    dt = sp.vstack([d.T, sp.csr_matrix((size - d.shape[1], m))], format="csc")
    out = np.empty((m // 3, 3, 3))
    for a in range(0, m, 3 * block):
        cols = dt[:, a:a + 3 * block].toarray()
        z = d @ lu.solve(cols)[:d.shape[1]]            # (m, cols): d H^-1 d^T's columns
        for j in range(cols.shape[1] // 3):
            k = a // 3 + j
            out[k] = z[3 * k:3 * k + 3, 3 * j:3 * j + 3]
    return 0.5 * (out + out.transpose(0, 2, 1))
