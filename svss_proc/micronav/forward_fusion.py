"""The fusion of :mod:`.fusion` run forward, ping by ping, as the live worker needs it
(docs/micronavigation.md, "Live").

:func:`.fusion.fuse_increments` minimises, over the positions x_k of all pings,

    sum_k |x_(k+1) - x_k - f_k|^2_(F_k^-1) + sum_k |x_k - p_k|^2 / s_a^2,

where each step's two measurements (the navigation's n_k, covariance N_k, and the
echoes' m_k, covariance M_k) combine into f_k = F_k (N_k^-1 n_k + M_k^-1 m_k),
F_k = (N_k^-1 + M_k^-1)^-1 (f_k = n_k, F_k = N_k where the echoes refused). That is a
random walk x_(k+1) = x_k + f_k + w_k (w_k ~ N(0, F_k)) observed as p_k = x_k + v_k
(v_k ~ N(0, s_a^2 I)), and the Kalman filter of that model gives, at each ping, the
minimiser's value at that ping given the pings so far: the last position of
:func:`.fusion.fuse_increments` on the same data (``tests/micronav/test_forward_fusion.py``
checks it to 1e-9 m at every length). In the correction e_k = x_k - p_k, with the
echoes' correction of the step c_k = m_k - n_k:

    predict:  e- = e_(k) + F_k M_k^-1 c_k,   P- = P_k + F_k        (f_k - n_k = F_k M_k^-1 c_k)
    update:   K = P- (P- + s_a^2 I)^-1,   e_(k+1) = (I - K) e-,   P_(k+1) = (I - K) P-

from e_0 = 0, P_0 = s_a^2 I. A refused step leaves e- = e_k and adds N_k to P. Pure
functions of numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FusionState", "fuse_forward", "fusion_start", "fusion_step"]


@dataclass(frozen=True)
class FusionState:
    """After a ping: its fused position minus the navigation's (``correction_m`` (3,))
    and that correction's covariance ``cov_m2`` (3, 3), m."""
    correction_m: np.ndarray
    cov_m2: np.ndarray


def fusion_start(anchor_sigma_m: float) -> FusionState:
    """The first ping: the navigation's position, known to the anchor's sigma."""
    if not anchor_sigma_m > 0:
        raise ValueError(f"anchor sigma {anchor_sigma_m!r} m: expected > 0")
    return FusionState(np.zeros(3), np.eye(3) * anchor_sigma_m ** 2)


def fusion_step(state: FusionState, nav_cov_m2: np.ndarray, micro_correction_m,
                micro_cov_m2, anchor_sigma_m: float) -> tuple[FusionState, np.ndarray]:
    """The next ping's state, and the covariance F of the fused step (module docstring).
    ``nav_cov_m2`` (3, 3): the navigation's step covariance N; ``micro_correction_m``
    (3,): the echoes' increment minus the navigation's (None: refused, the step is the
    navigation's), ``micro_cov_m2`` (3, 3) its covariance M."""
    n = np.asarray(nav_cov_m2, dtype=np.float64)
    if micro_correction_m is None:
        e_pred, f_cov = state.correction_m, n
    else:
        n_inv = np.linalg.inv(n)
        m_inv = np.linalg.inv(np.asarray(micro_cov_m2, dtype=np.float64))
        f_cov = np.linalg.inv(n_inv + m_inv)
        e_pred = state.correction_m + f_cov @ (m_inv @ np.asarray(micro_correction_m,
                                                                   dtype=np.float64))
    p_pred = state.cov_m2 + f_cov
    gain = p_pred @ np.linalg.inv(p_pred + np.eye(3) * anchor_sigma_m ** 2)
    keep = np.eye(3) - gain
    p_new = keep @ p_pred
    return FusionState(keep @ e_pred, 0.5 * (p_new + p_new.T)), f_cov


def fuse_forward(nav_positions_m: np.ndarray, nav_cov_m2: np.ndarray,
                 micro_increments_m: np.ndarray, micro_cov_m2: np.ndarray,
                 anchor_sigma_m: float) -> np.ndarray:
    """The forward-fused positions (n, 3) of n pings, each given only the pings up to it:
    the arguments of :func:`.fusion.fuse_increments` (NaN rows of ``micro_increments_m``
    refused)."""
    p = np.asarray(nav_positions_m, dtype=np.float64)
    state = fusion_start(anchor_sigma_m)
    out = [p[0].copy()]
    for k in range(p.shape[0] - 1):
        m = np.asarray(micro_increments_m[k], dtype=np.float64)
        corr = (m - (p[k + 1] - p[k])) if np.all(np.isfinite(m)) else None
        state, _ = fusion_step(state, nav_cov_m2[k], corr, micro_cov_m2[k], anchor_sigma_m)
        out.append(p[k + 1] + state.correction_m)
    return np.array(out)
