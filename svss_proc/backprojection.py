"""Delay-and-sum backprojection kernels (numba CPU, parallel over along-track slices).

One ping's coherent sum is added into a tile:

    I(v) += sum_ch a_ch y_ch(tau) exp(+j 2 pi f_c tau),   tau = t_tx(v) + t_ch(v),

with y the complex baseband matched-filter output (:mod:`svss_daq.conventions`), a_ch an
optional apodisation weight, t the one-way travel times (straight rays, a refraction
table, or exact Fermat paths: :mod:`svss_proc.refraction`), and, with gating on, only
voxels inside both the projector's and the receiver's beam cones.

Phase without trigonometry: :func:`prepare` folds the remodulation at the sample times
into "tap planes"

    P_k[n] = y_{n+k} exp(+j 2 pi f_c t_{n+k}) exp(-j theta (k - s)),  theta = 2 pi f_c dt,

so that y(tau) e^{+j 2 pi f_c tau} = e^{j theta (w - s)} sum_k c_k(w) P_k[n], with n and
w the integer and fractional sample of tau and c_k the interpolation weights (nearest:
one tap, s = 0, w in [-1/2, 1/2); linear: two taps, s = 1/2; cubic (Keys, a = -1/2):
four taps k = -1..2, s = 1/2). The remaining factor is a short Taylor series of an angle
below 1.4 rad (halved and squared back when theta is larger), exact to ~1e-7 in float32.

Precision: geometry is computed in float64 relative to the ping's projector and handed
to the kernel in the chosen precision (float32 or float64); the kernel accumulates each
ping in that precision and the tile in complex64.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np
from numba import types
from numba.extending import overload

from svss_daq.conventions import remodulation

from .conditioning import Conditioned
from .refraction import TravelTimeTable, one_way_time

INTERP = {"nearest": 0, "linear": 1, "cubic": 2}
DELAY = {"straight": 0, "table": 1, "exact": 2}
_TAPS = {0: (0,), 1: (0, 1), 2: (-1, 0, 1, 2)}
_SHIFT = {0: 0.0, 1: 0.5, 2: 0.5}
MAX_HALF_ANGLE = 1.4      # rad: Taylor series range of the phase factor


@dataclass(frozen=True)
class KernelData:
    """One ping's data prepared for the kernels."""
    re: np.ndarray      # (taps, channels, n) tap planes, real parts
    im: np.ndarray      # (taps, channels, n) imaginary parts
    t0: float           # s, delay of sample 0
    dt: float           # s
    theta: float        # rad, 2 pi f_c dt
    halvings: int       # angle halvings before the series
    interp: int         # INTERP code


def prepare(cond: Conditioned, interp: str = "linear", dtype=np.float32) -> KernelData:
    """Fold the remodulation into tap planes for interpolation ``interp``."""
    code = INTERP[interp]
    n = cond.data.shape[1]
    t = cond.t0_s + cond.dt_s * np.arange(n)
    theta = 2.0 * math.pi * cond.center_hz * cond.dt_s
    y = cond.data.astype(np.complex128) * remodulation(t, cond.center_hz)
    s = _SHIFT[code]
    taps = _TAPS[code]
    planes = np.zeros((len(taps), y.shape[0], n), dtype=np.complex128)
    for i, k in enumerate(taps):
        shifted = np.zeros_like(y)
        if k >= 0:
            shifted[:, : n - k] = y[:, k:]
        else:
            shifted[:, -k:] = y[:, :k]
        planes[i] = shifted * np.exp(-1j * theta * (k - s))
    max_angle = 0.5 * theta     # |w - s| <= 1/2 for every interpolation
    halvings = max(0, math.ceil(math.log2(max(max_angle, 1e-12) / MAX_HALF_ANGLE)))
    return KernelData(np.ascontiguousarray(planes.real, dtype=dtype),
                      np.ascontiguousarray(planes.imag, dtype=dtype), cond.t0_s,
                      cond.dt_s, theta, halvings, code)


# ----------------------------------------------------------------- scalar building blocks


def cast_like(ref, x):
    """``x`` converted to the floating type of ``ref`` (numba only)."""
    raise NotImplementedError("cast_like is for numba-compiled code only")


@overload(cast_like, inline="always")
def _cast_like(ref, x):
    if ref == types.float32:
        return lambda ref, x: np.float32(x)
    return lambda ref, x: np.float64(x)



@nb.njit(inline="always", cache=True)
def _cis(x, halvings, one):
    """(cos x, sin x) in the precision of ``one``, by Taylor series after halvings."""
    for _ in range(halvings):
        x = x * cast_like(one, 0.5)
    x2 = x * x
    c = one + x2 * (cast_like(one, -1 / 2) + x2 * (cast_like(one, 1 / 24) + x2 * (
        cast_like(one, -1 / 720) + x2 * (cast_like(one, 1 / 40320)
                                         + x2 * cast_like(one, -1 / 3628800)))))
    s = x * (one + x2 * (cast_like(one, -1 / 6) + x2 * (cast_like(one, 1 / 120) + x2 * (
        cast_like(one, -1 / 5040) + x2 * (cast_like(one, 1 / 362880)
                                          + x2 * cast_like(one, -1 / 39916800))))))
    for _ in range(halvings):
        c, s = c * c - s * s, (one + one) * c * s
    return c, s


@nb.njit(inline="always", cache=True)
def _weights(interp, w, one):
    """Interpolation weights (up to four taps) at fractional position w."""
    zero = one - one
    if interp == 0:
        return one, zero, zero, zero
    if interp == 1:
        return one - w, w, zero, zero
    # Keys cubic convolution, a = -1/2, taps at -1, 0, 1, 2
    half = one / (one + one)
    w2 = w * w
    w3 = w2 * w
    c0 = half * (-w3 + (one + one) * w2 - w)
    c1 = half * ((one + one + one) * w3 - (one + one + one + one + one) * w2) + one
    c2 = half * (-(one + one + one) * w3 + (one + one + one + one) * w2 + w)
    c3 = half * (w3 - w2)
    return c0, c1, c2, c3


@nb.njit(inline="always", cache=True)
def _sample(re, im, ch, u, interp, halvings, theta, nt, one):
    """Remodulated, interpolated sample of channel ``ch`` at fractional index u, branch
    free so that the channel loop vectorises. Returns (re, im, valid as 0/1 weight)."""
    zero = one - one
    half = cast_like(one, 0.5)
    if interp == 0:
        lo = zero
        hi = cast_like(one, nt - 1)
        uc = min(max(u, lo), hi)
        i0 = np.int32(uc + half)
        shift = zero
    elif interp == 1:
        lo = zero
        hi = cast_like(one, nt - 1) - cast_like(one, 1e-3)
        uc = min(max(u, lo), hi)
        i0 = np.int32(uc)
        shift = half
    else:
        lo = one
        hi = cast_like(one, nt - 2) - cast_like(one, 1e-3)
        uc = min(max(u, lo), hi)
        i0 = np.int32(uc)
        shift = half
    valid = (one if u >= lo else zero) * (one if u <= hi else zero)
    w = uc - cast_like(one, i0)
    c0, c1, c2, c3 = _weights(interp, w, one)
    sr = c0 * re[0, ch, i0]
    si = c0 * im[0, ch, i0]
    if interp > 0:
        sr += c1 * re[1, ch, i0]
        si += c1 * im[1, ch, i0]
    if interp == 2:
        sr += c2 * re[2, ch, i0] + c3 * re[3, ch, i0]
        si += c2 * im[2, ch, i0] + c3 * im[3, ch, i0]
    cr, cs = _cis(theta * (w - shift), halvings, one)
    return sr * cr - si * cs, sr * cs + si * cr, valid


@nb.njit(inline="always", cache=True)
def _time(mode, dx, dy, z, h, inv_c, cw, cs, ttab, etab, inv_drho, tz0, inv_dz, h_ref):
    """One-way travel time from an element at height h above the interface (horizontal
    offset (dx, dy) to the voxel at depth z below the interface)."""
    if mode == 0:
        dz = z + h
        return math.sqrt(dx * dx + dy * dy + dz * dz) * inv_c
    one = inv_c * 0 + 1
    rho = math.sqrt(np.float64(dx) * dx + np.float64(dy) * dy)
    if mode == 1:
        n_rho, n_z = ttab.shape
        u = min(max(rho * inv_drho, 0.0), n_rho - 1.001)
        v = min(max((z - tz0) * inv_dz, 0.0), n_z - 1.001)
        i = int(u)
        j = int(v)
        a = u - i
        b = v - j
        t = ((1 - a) * ((1 - b) * ttab[i, j] + b * ttab[i, j + 1])
             + a * ((1 - b) * ttab[i + 1, j] + b * ttab[i + 1, j + 1]))
        e = ((1 - a) * ((1 - b) * etab[i, j] + b * etab[i, j + 1])
             + a * ((1 - b) * etab[i + 1, j] + b * etab[i + 1, j + 1]))
        return cast_like(one, t + (h - h_ref) * e)
    return cast_like(one, one_way_time(np.float64(h), rho, np.float64(z), cw, cs))


# ------------------------------------------------------------------------- the kernel


def _make_kernel(interp: int, mode: int, gating: bool, halvings: int):
    """Compile-time specialisation of the kernel on interpolation, delay mode and gating
    (constant branches fold away, so the straight-ray channel loop vectorises)."""

    @nb.njit(parallel=True, fastmath=True, cache=True)
    def kernel(img_re, img_im, re, im, t0, inv_dt, theta, ax, cy, dz, h_tx, rx_dx,
               rx_dy, rx_h, apod, bore, cos_tx, cos_rx, inv_c, cw, cs, ttab, etab, inv_drho,
               tz0, inv_dz, h_ref, ia0, ia1):
        one = re[0, 0, 0] * 0 + 1
        nch = re.shape[1]
        nt = re.shape[2]
        nc = cy.size
        nd = dz.size
        counts = np.zeros(ia1 - ia0, dtype=np.int64)
        for k in nb.prange(ia1 - ia0):
            ia = ia0 + k
            x = ax[ia]
            n_upd = 0
            for ic in range(nc):
                y = cy[ic]
                for iz in range(nd):
                    z = dz[iz]
                    vz = z + h_tx                   # vertical offset below the projector
                    r1 = math.sqrt(x * x + y * y + vz * vz)
                    if gating and x * bore[0] + y * bore[1] + vz * bore[2] < r1 * cos_tx:
                        continue
                    t1 = _time(mode, x, y, z, h_tx, inv_c, cw, cs, ttab, etab, inv_drho,
                               tz0, inv_dz, h_ref) - t0
                    acc_re = one - one
                    acc_im = one - one
                    for ch in range(nch):             # branch free: vectorises
                        ex = x - rx_dx[ch]
                        ey = y - rx_dy[ch]
                        ez = z + rx_h[ch]
                        g = apod[ch]
                        if gating:
                            r2 = math.sqrt(ex * ex + ey * ey + ez * ez)
                            inside = ex * bore[0] + ey * bore[1] + ez * bore[2] >= r2 * cos_rx
                            g = g if inside else one - one
                        t2 = _time(mode, ex, ey, z, rx_h[ch], inv_c, cw, cs, ttab, etab,
                                   inv_drho, tz0, inv_dz, h_ref)
                        u = (t1 + t2) * inv_dt
                        sr, si, valid = _sample(re, im, ch, u, interp, halvings, theta, nt,
                                                one)
                        g = g * valid
                        acc_re += g * sr
                        acc_im += g * si
                        n_upd += np.int64(g != 0)
                    img_re[ia, ic, iz] += acc_re
                    img_im[ia, ic, iz] += acc_im
            counts[k] = n_upd
        return counts.sum()

    return kernel


_KERNELS: dict[tuple[int, int, bool, int], object] = {}


def kernel_for(interp: int, mode: int, gating: bool, halvings: int):
    """The compiled kernel for an (interpolation, delay mode, gating) combination.

    Kernel arguments: image planes (along x cross x depth), tap planes, t0 (s), 1/dt
    (1/s), theta; geometry relative to the projector: ``ax``/``cy`` voxel
    along/cross offsets, ``dz`` voxel depths below the interface, ``h_tx``/``rx_h``
    element heights above the interface, ``rx_dx``/``rx_dy`` receiver offsets (m);
    apodisation, boresight and cone cosines; 1/c; the water and sediment speeds and the
    refraction table; the along-track index range. Returns the voxel-channel updates.
    """
    key = (interp, mode, bool(gating), int(halvings))
    if key not in _KERNELS:
        _KERNELS[key] = _make_kernel(*key)
    return _KERNELS[key]


def along_reach(tx_tile: np.ndarray, bore: np.ndarray, half_angle: float,
                max_depth: float) -> float:
    """Largest horizontal distance from the projector at which a voxel no deeper than
    ``max_depth`` (tile frame) can lie inside the projector cone, m."""
    tilt = math.acos(max(-1.0, min(1.0, float(bore[2]))))
    cone = min(half_angle + tilt, math.radians(89.0))
    return max(0.0, (max_depth - float(tx_tile[2]))) * math.tan(cone)


_EMPTY_TABLE = np.zeros((2, 2))


def run_ping(img_re, img_im, kd: KernelData, tx, rx, along, cross, depth, ia0, ia1, *,
             bore, cos_tx, cos_rx, gating=True, apod=None, mode="straight", c=1500.0,
             cw=1500.0, cs=1500.0, table: TravelTimeTable | None = None) -> int:
    """Call :func:`backproject_ping` with geometry in the tile frame (float64): ``tx``
    (3,), ``rx`` (channels, 3), voxel axes; the kernel precision is the image planes'."""
    ft = img_re.dtype.type
    nch = rx.shape[0]
    ax = np.ascontiguousarray(along - tx[0], dtype=ft)
    cy = np.ascontiguousarray(cross - tx[1], dtype=ft)
    dz = np.ascontiguousarray(depth, dtype=ft)
    rx_dx = np.ascontiguousarray(rx[:, 0] - tx[0], dtype=ft)
    rx_dy = np.ascontiguousarray(rx[:, 1] - tx[1], dtype=ft)
    rx_h = np.ascontiguousarray(-rx[:, 2], dtype=ft)
    apod = np.ones(nch, dtype=ft) if apod is None else np.ascontiguousarray(apod, dtype=ft)
    code = DELAY[mode]
    if code == 1:
        if table is None:
            raise ValueError("delay mode 'table' needs a travel-time table")
        ttab, etab = table.time, table.eta
        inv_drho, tz0, inv_dz, h_ref = 1 / table.drho, table.z0, 1 / table.dz, table.h_ref
    else:
        ttab = etab = _EMPTY_TABLE
        inv_drho, tz0, inv_dz, h_ref = 1.0, 0.0, 1.0, 0.0
    if kd.re.dtype != img_re.dtype:
        raise ValueError(f"kernel data is {kd.re.dtype}, image planes are {img_re.dtype}")
    kernel = kernel_for(kd.interp, code, gating, kd.halvings)
    return int(kernel(
        img_re, img_im, kd.re, kd.im, ft(kd.t0), ft(1.0 / kd.dt), ft(kd.theta),
        ax, cy, dz, ft(-tx[2]), rx_dx, rx_dy, rx_h, apod,
        np.ascontiguousarray(bore, dtype=ft), ft(cos_tx), ft(cos_rx), ft(1.0 / c), cw, cs,
        ttab, etab, inv_drho, tz0, inv_dz, h_ref, ia0, ia1))
