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

from svss_daq.conventions import remodulation

from .conditioning import Conditioned
from .kernel_math import build
from .refraction import TravelTimeTable
from .refraction import _cpu as refraction_cpu

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


_cpu = build(nb.njit(inline="always", cache=True), refraction_cpu)
_voxel_sum = _cpu.voxel_sum


# ------------------------------------------------------------------------- the kernel


def _make_kernel(interp: int, mode: int, gating: bool, halvings: int):
    """Compile-time specialisation of the kernel on interpolation, delay mode and gating
    (constant branches fold away, so the straight-ray channel loop vectorises)."""

    @nb.njit(parallel=True, fastmath=True, cache=True)
    def kernel(img_re, img_im, re, im, t0, inv_dt, theta, ax, cy, dz, h_tx, rx_dx,
               rx_dy, rx_h, apod, bore, cos_tx, cos_rx, inv_c, cw, cs, ttab, etab, inv_drho,
               tz0, inv_dz, h_ref, ia0, ia1):
        one = re[0, 0, 0] * 0 + 1
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
                    sr, si, n = _voxel_sum(x, y, dz[iz], interp, mode, gating, halvings, re,
                                           im, t0, inv_dt, theta, h_tx, rx_dx, rx_dy, rx_h,
                                           apod, bore, cos_tx, cos_rx, inv_c, cw, cs, ttab,
                                           etab, inv_drho, tz0, inv_dz, h_ref, one)
                    img_re[ia, ic, iz] += sr
                    img_im[ia, ic, iz] += si
                    n_upd += n
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


def geometry_args(ft, kd: KernelData, tx, rx, along, cross, depth, *, bore, cos_tx, cos_rx,
                  apod=None, mode="straight", c=1500.0, cw=1500.0, cs=1500.0,
                  table: TravelTimeTable | None = None) -> tuple:
    """The kernel arguments after the image planes and before the along-track range:
    geometry from the tile frame (float64) made relative to the projector, then cast to
    the kernel precision ``ft``."""
    nch = rx.shape[0]
    ax = np.ascontiguousarray(along - tx[0], dtype=ft)
    cy = np.ascontiguousarray(cross - tx[1], dtype=ft)
    dz = np.ascontiguousarray(depth, dtype=ft)
    rx_dx = np.ascontiguousarray(rx[:, 0] - tx[0], dtype=ft)
    rx_dy = np.ascontiguousarray(rx[:, 1] - tx[1], dtype=ft)
    rx_h = np.ascontiguousarray(-rx[:, 2], dtype=ft)
    apod = np.ones(nch, dtype=ft) if apod is None else np.ascontiguousarray(apod, dtype=ft)
    if DELAY[mode] == 1:
        if table is None:
            raise ValueError("delay mode 'table' needs a travel-time table")
        ttab, etab = table.time, table.eta
        inv_drho, tz0, inv_dz, h_ref = 1 / table.drho, table.z0, 1 / table.dz, table.h_ref
    else:
        ttab = etab = _EMPTY_TABLE
        inv_drho, tz0, inv_dz, h_ref = 1.0, 0.0, 1.0, 0.0
    if kd.re.dtype != ft:
        raise ValueError(f"kernel data is {kd.re.dtype}, the image planes are {np.dtype(ft)}")
    return (kd.re, kd.im, ft(kd.t0), ft(1.0 / kd.dt), ft(kd.theta), ax, cy, dz, ft(-tx[2]),
            rx_dx, rx_dy, rx_h, apod, np.ascontiguousarray(bore, dtype=ft), ft(cos_tx),
            ft(cos_rx), ft(1.0 / c), float(cw), float(cs), ttab, etab, inv_drho, tz0, inv_dz,
            h_ref)


def run_ping(img_re, img_im, kd: KernelData, tx, rx, along, cross, depth, ia0, ia1, *,
             bore, cos_tx, cos_rx, gating=True, apod=None, mode="straight", c=1500.0,
             cw=1500.0, cs=1500.0, table: TravelTimeTable | None = None) -> int:
    """Add one ping into the image planes (along x cross x depth) for along-track indices
    ia0 <= ia < ia1, with geometry in the tile frame (float64): ``tx`` (3,), ``rx``
    (channels, 3), voxel axes. The kernel precision is the image planes'. Returns the
    number of voxel-channel updates."""
    args = geometry_args(img_re.dtype.type, kd, tx, rx, along, cross, depth, bore=bore,
                         cos_tx=cos_tx, cos_rx=cos_rx, apod=apod, mode=mode, c=c, cw=cw,
                         cs=cs, table=table)
    kernel = kernel_for(kd.interp, DELAY[mode], gating, kd.halvings)
    return int(kernel(img_re, img_im, *args, ia0, ia1))
