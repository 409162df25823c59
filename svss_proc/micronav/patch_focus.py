"""The micronavigation's focusing kernel: a sub-aperture of one ping focused on points of
the seabed (numba, on-disk cache), the cost :mod:`.horizontal` spends nearly all its
time in (docs/phase_centres.md, "The kernel and its cost").

It computes what :func:`.horizontal.focus_points` computes, summed over the channels,

    v(P) = sum_i bb_i(tau_i(P)) exp(+j 2 pi f_c tau_i(P)),   tau_i = (|P - t| + |P - r_i|) / c,

with bb linearly interpolated between samples k and k + 1 (u = (tau - t0) / dt, k =
floor(u), f = u - k), but without a sine or cosine per channel and point: with
t_k = t0 + k dt and theta = 2 pi f_c dt,

    bb(tau) exp(j 2 pi f_c tau) = [(1 - f) A_k + f B_k] exp(j theta (f - 1/2)),
    A_k = bb_k exp(j 2 pi f_c (t_k + dt / 2)),   B_k = bb_(k+1) exp(j 2 pi f_c (t_k + dt / 2)),

the "taps" A and B made once per ping (:func:`ping_taps`, every channel: each ping is
used by the two pairs it belongs to, both translations and both passes), and the
remaining factor a Taylor series of an angle |theta (f - 1/2)| <= theta / 2 (1.38 rad at
27.5 kHz and 62.5 kS/s): terms to x^11 and x^12, truncation below 2e-7
(:data:`MAX_HALF_ANGLE_RAD` bounds the angle it is used for). Geometry is float64 in a
frame local to the sub-aperture (the caller subtracts a nearby point first: a survey
frame's coordinates of kilometres would otherwise cost the distances' last digits).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

__all__ = ["MAX_HALF_ANGLE_RAD", "PingTaps", "SubAperture", "focus", "ping_taps", "warm_up"]

#: the largest |theta| / 2 the kernel's Taylor series of exp(j x) is used for, rad
#: (truncation x^12 / 12! = 1e-7 at 1.38 rad; 2e-6 at 1.6)
MAX_HALF_ANGLE_RAD = 1.6


class PingTaps(NamedTuple):
    """One ping's taps (:func:`ping_taps`): the real and imaginary parts of A and B
    (channels, n - 1) float64; ``t0_s``, ``dt_s`` its sample axis; ``theta`` = 2 pi f_c
    dt, rad."""
    a_re: np.ndarray
    a_im: np.ndarray
    b_re: np.ndarray
    b_im: np.ndarray
    t0_s: float
    dt_s: float
    theta: float


class SubAperture(NamedTuple):
    """The elements focused: ``channels`` (n,) int64 rows of the taps, the projector
    ``tx`` (3,) and the receivers ``rx`` (n, 3), m, in the points' (local) frame."""
    channels: np.ndarray
    tx: np.ndarray
    rx: np.ndarray


def ping_taps(bb: np.ndarray, t0_s: float, dt_s: float, center_hz: float) -> PingTaps:
    """The taps of complex baseband ``bb`` (channels, n) on samples t0 + k dt (module
    docstring)."""
    theta = 2.0 * math.pi * center_hz * dt_s
    if not abs(theta) / 2.0 <= MAX_HALF_ANGLE_RAD:
        raise ValueError(f"a carrier of {center_hz:g} Hz turns {theta:.2f} rad between "
                         f"samples {dt_s * 1e6:.2f} us apart: above the focusing kernel's "
                         f"2 x {MAX_HALF_ANGLE_RAD} rad")
    bb = np.asarray(bb)
    n = bb.shape[1]
    t = t0_s + dt_s * (np.arange(n - 1) + 0.5)
    carrier = np.exp(2j * math.pi * center_hz * t)
    out = [np.empty((bb.shape[0], n - 1)) for _ in range(4)]
    _taps(np.ascontiguousarray(bb.real, dtype=np.float64),
          np.ascontiguousarray(bb.imag, dtype=np.float64), carrier.real.copy(),
          carrier.imag.copy(), *out)
    return PingTaps(*out, float(t0_s), float(dt_s), float(theta))


@nb.njit(cache=True)
def _taps(bre, bim, cre, cim, a_re, a_im, b_re, b_im):
    for ch in range(a_re.shape[0]):
        for k in range(a_re.shape[1]):
            a_re[ch, k] = bre[ch, k] * cre[k] - bim[ch, k] * cim[k]
            a_im[ch, k] = bre[ch, k] * cim[k] + bim[ch, k] * cre[k]
            b_re[ch, k] = bre[ch, k + 1] * cre[k] - bim[ch, k + 1] * cim[k]
            b_im[ch, k] = bre[ch, k + 1] * cim[k] + bim[ch, k + 1] * cre[k]


@nb.njit(fastmath=True, cache=True)
def _focus(taps, channels, tx, rx, points, inv_c, re, im, dtx):
    """Channels outer, points inner (the inner loop vectorises: distances, sample
    indices, the phase's series; the taps gathered)."""
    a_re, a_im, b_re, b_im = taps.a_re, taps.a_im, taps.b_re, taps.b_im
    n = a_re.shape[1]
    m = points.shape[0]
    scale = inv_c / taps.dt_s
    off = taps.t0_s / taps.dt_s
    theta = taps.theta
    for p in range(m):
        dtx[p] = math.sqrt((points[p, 0] - tx[0]) ** 2 + (points[p, 1] - tx[1]) ** 2
                           + (points[p, 2] - tx[2]) ** 2)
        re[p] = 0.0
        im[p] = 0.0
    for i in range(channels.shape[0]):
        ch = channels[i]
        x0, y0, z0 = rx[i, 0], rx[i, 1], rx[i, 2]
        for p in range(m):
            d = dtx[p] + math.sqrt((points[p, 0] - x0) ** 2 + (points[p, 1] - y0) ** 2
                                   + (points[p, 2] - z0) ** 2)
            u = d * scale - off
            fk = math.floor(u)
            k = int(fk)
            w = 1.0 if (k >= 0 and k < n) else 0.0     # taps hold samples k, k + 1
            k = min(max(k, 0), n - 1)
            f = u - fk
            sr = (1.0 - f) * a_re[ch, k] + f * b_re[ch, k]
            si = (1.0 - f) * a_im[ch, k] + f * b_im[ch, k]
            x = theta * (f - 0.5)
            x2 = x * x
            c = 1.0 - x2 / 2.0 * (1.0 - x2 / 12.0 * (1.0 - x2 / 30.0 * (
                1.0 - x2 / 56.0 * (1.0 - x2 / 90.0 * (1.0 - x2 / 132.0)))))
            s = x * (1.0 - x2 / 6.0 * (1.0 - x2 / 20.0 * (1.0 - x2 / 42.0 * (
                1.0 - x2 / 72.0 * (1.0 - x2 / 110.0)))))
            re[p] += w * (sr * c - si * s)
            im[p] += w * (sr * s + si * c)


def focus(taps: PingTaps, sub: SubAperture, points: np.ndarray,
          sound_speed_m_s: float) -> np.ndarray:
    """The sub-aperture's focused value v(P) at each of ``points`` (m, 3) (same frame as
    ``sub``), complex128 (m,)."""
    m = points.shape[0]
    re, im, dtx = np.empty(m), np.empty(m), np.empty(m)
    _focus(taps, np.ascontiguousarray(sub.channels, dtype=np.int64),
           np.ascontiguousarray(sub.tx, dtype=np.float64),
           np.ascontiguousarray(sub.rx, dtype=np.float64),
           np.ascontiguousarray(points, dtype=np.float64), 1.0 / float(sound_speed_m_s),
           re, im, dtx)
    return re + 1j * im


def warm_up() -> None:
    """Compile the kernels (or load them from numba's cache) on a tiny problem, before
    pings come (a worker's first ping pair would otherwise wait for it)."""
    from .phase_centres import near_pairs
    taps = ping_taps(np.zeros((1, 4), dtype=np.complex64), 0.0, 1e-5, 1e4)
    focus(taps, SubAperture(np.zeros(1, dtype=np.int64), np.zeros(3), np.zeros((1, 3))),
          np.ones((1, 3)), 1500.0)
    near_pairs(np.zeros((1, 3)), np.zeros((1, 3)), 1.0)
