"""Delay-and-sum backprojection kernel (numba, parallel over along-track slices).

Pure kernel: geometry comes in precomputed in the tile frame (float64), data as complex
baseband (see :mod:`svss_daq.conventions`), and the kernel adds one ping's coherent sum
into the image:

    I(v) += sum_ch y_ch((r_tx(v) + r_ch(v)) / c) * exp(+j 2 pi f_c tau)

with linear interpolation of y and, when gating is on, only voxels inside both the
projector's and the receiver's beam cones.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from svss_daq.conventions import ECHO_PHASE_SIGN

_TWO_PI_REMOD = -ECHO_PHASE_SIGN * 2.0 * math.pi


@nb.njit(parallel=True, fastmath=False, cache=True)
def backproject_ping(image, data, t0, dt, fc, c, tx, rx, bore, cos_tx, cos_rx,
                     along, cross, depth, ia0, ia1, gating):
    """Add one ping into ``image`` (along x cross x depth, complex64) for along-track
    indices ia0 <= ia < ia1. Returns the number of voxel-channel updates made."""
    nch, nt = data.shape
    nc = cross.size
    nd = depth.size
    w_ph = _TWO_PI_REMOD * fc
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
                    tau = (r1 + r2) / c
                    u = (tau - t0) / dt
                    i0 = int(math.floor(u))
                    if i0 < 0 or i0 >= nt - 1:
                        continue
                    w = u - i0
                    s0 = data[ch, i0]
                    s1 = data[ch, i0 + 1]
                    sr = s0.real + w * (s1.real - s0.real)
                    si = s0.imag + w * (s1.imag - s0.imag)
                    ph = w_ph * tau
                    cph = math.cos(ph)
                    sph = math.sin(ph)
                    acc_re += sr * cph - si * sph
                    acc_im += sr * sph + si * cph
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
