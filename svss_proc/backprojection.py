"""Delay-and-sum backprojection kernel (numba, parallel over along-track slices).

The kernel adds one ping's coherent sum into a tile:

    I(v) += sum_ch y_ch(tau) * exp(+j 2 pi f_c tau),   tau = (r_tx(v) + r_ch(v)) / c,

with y the complex baseband matched-filter output (:mod:`svss_daq.conventions`), linear
interpolation of y between samples and, when gating is on, only voxels inside both the
projector's and the receiver's beam cones. Geometry arrives precomputed in the tile frame
(float64).

No sine or cosine is evaluated per update: :func:`prepare` folds the remodulation at the
sample times into the data (D_n = y_n e^{+j2pi fc t_n} e^{+j theta/2},
F_n = y_{n+1} e^{+j2pi fc t_{n+1}} e^{-j theta/2}, theta = 2 pi f_c dt), so that

    y(tau) e^{+j2pi fc tau} = e^{j theta (w - 1/2)} [(1 - w) D_n + w F_n],

with w the fractional sample; the remaining factor is a short Taylor series of an angle
below 1.4 rad (halved and squared back when theta is larger), accurate to ~1e-9.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from svss_daq.conventions import remodulation

from .conditioning import Conditioned


@dataclass(frozen=True)
class KernelData:
    """One ping's data prepared for the kernel."""
    d: np.ndarray       # (channels, n - 1) complex128: D_n
    f: np.ndarray       # (channels, n - 1) complex128: F_n
    t0: float           # s, delay of sample 0
    dt: float           # s
    theta: float        # rad, 2 pi f_c dt
    halvings: int       # angle halvings before the series


def prepare(cond: Conditioned) -> KernelData:
    """Fold the remodulation into the conditioned data (see the module docstring)."""
    n = cond.data.shape[1]
    t = cond.t0_s + cond.dt_s * np.arange(n)
    theta = 2.0 * math.pi * cond.center_hz * cond.dt_s
    y = cond.data.astype(np.complex128) * remodulation(t, cond.center_hz)
    half = np.exp(0.5j * theta)
    halvings = max(0, math.ceil(math.log2(max(theta / 2.0, 1e-12) / 1.4)))
    return KernelData(np.ascontiguousarray(y[:, :-1] * half),
                      np.ascontiguousarray(y[:, 1:] / half), cond.t0_s, cond.dt_s, theta,
                      halvings)


@nb.njit(inline="always", cache=True)
def _cis(x, halvings):
    """(cos x, sin x) by Taylor series for |x| / 2**halvings <= 1.4, then squaring."""
    x = x / (1 << halvings)
    x2 = x * x
    c = 1.0 + x2 * (-1 / 2 + x2 * (1 / 24 + x2 * (-1 / 720 + x2 * (1 / 40320 + x2 * (
        -1 / 3628800 + x2 * (1 / 479001600))))))
    s = x * (1.0 + x2 * (-1 / 6 + x2 * (1 / 120 + x2 * (-1 / 5040 + x2 * (
        1 / 362880 + x2 * (-1 / 39916800 + x2 * (1 / 6227020800)))))))
    for _ in range(halvings):
        c, s = c * c - s * s, 2.0 * c * s
    return c, s


@nb.njit(parallel=True, cache=True)
def backproject_ping(image, d, f, t0, dt, theta, halvings, c, tx, rx, bore, cos_tx, cos_rx,
                     along, cross, depth, ia0, ia1, gating):
    """Add one ping into ``image`` (along x cross x depth, complex64) for along-track
    indices ia0 <= ia < ia1. Returns the number of voxel-channel updates made."""
    nch, nt = d.shape
    nc = cross.size
    nd = depth.size
    inv_c = 1.0 / c
    inv_dt = 1.0 / dt
    counts = np.zeros(ia1 - ia0, dtype=np.int64)
    for k in nb.prange(ia1 - ia0):
        ia = ia0 + k
        x = along[ia]
        n_upd = 0
        for ic in range(nc):
            y = cross[ic]
            for iz in range(nd):
                z = depth[iz]
                d1x = x - tx[0]
                d1y = y - tx[1]
                d1z = z - tx[2]
                r1 = math.sqrt(d1x * d1x + d1y * d1y + d1z * d1z)
                if gating and d1x * bore[0] + d1y * bore[1] + d1z * bore[2] < r1 * cos_tx:
                    continue
                acc_re = 0.0
                acc_im = 0.0
                for ch in range(nch):
                    d2x = x - rx[ch, 0]
                    d2y = y - rx[ch, 1]
                    d2z = z - rx[ch, 2]
                    r2 = math.sqrt(d2x * d2x + d2y * d2y + d2z * d2z)
                    if gating and d2x * bore[0] + d2y * bore[1] + d2z * bore[2] < r2 * cos_rx:
                        continue
                    u = ((r1 + r2) * inv_c - t0) * inv_dt
                    if u < 0.0 or u >= nt:
                        continue
                    i0 = int(u)
                    w = u - i0
                    a = d[ch, i0]
                    b = f[ch, i0]
                    sr = a.real + w * (b.real - a.real)
                    si = a.imag + w * (b.imag - a.imag)
                    cr, cs = _cis(theta * (w - 0.5), halvings)
                    acc_re += sr * cr - si * cs
                    acc_im += sr * cs + si * cr
                    n_upd += 1
                image[ia, ic, iz] += complex(acc_re, acc_im)
        counts[k] = n_upd
    return counts.sum()


def along_reach(tx_tile: np.ndarray, bore: np.ndarray, half_angle: float,
                max_depth: float) -> float:
    """Largest horizontal distance from the projector at which a voxel no deeper than
    ``max_depth`` (tile frame) can lie inside the projector cone, m."""
    tilt = math.acos(max(-1.0, min(1.0, float(bore[2]))))
    cone = min(half_angle + tilt, math.radians(89.0))
    return max(0.0, (max_depth - float(tx_tile[2]))) * math.tan(cone)
