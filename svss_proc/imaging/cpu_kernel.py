"""Delay-and-sum backprojection kernels (numba CPU, parallel over along-track slices).

One ping's coherent sum is added into a tile:

    I(v) += sum_ch a_ch y_ch(tau) exp(+j 2 pi f_c tau),   tau = t_tx(v) + t_ch(v),

with y the complex baseband matched-filter output (:mod:`svss_daq.conventions`), a_ch an
optional apodisation weight, t the one-way travel times (straight rays, a refraction
table, or exact Fermat paths: :mod:`svss_proc.imaging.delays`), and, with gating on, only
voxels inside both the projector's and the receiver's beam cones.

Phase without trigonometry: :func:`prepare` folds the remodulation at the sample times
into "tap planes"

    P_k[n] = y_{n+k} exp(+j 2 pi f_c t_{n+k}) exp(-j theta (k - s)),  theta = 2 pi f_c dt,

so that y(tau) e^{+j 2 pi f_c tau} = e^{j theta (w - s)} sum_k c_k(w) P_k[n], with n and
w the integer and fractional sample of tau and c_k the interpolation weights (nearest:
one tap, s = 0, w in [-1/2, 1/2); linear: two taps, s = 1/2; cubic (Keys, a = -1/2):
four taps k = -1..2, s = 1/2). The remaining factor is a short Taylor series of an angle
below 1.4 rad (halved and squared back when theta is larger), exact to ~1e-7 in float32.

Loop order (CPU): prange over along-track slices; per voxel column (along, cross) the
projector delays and cone mask are computed once per depth, then channels are the outer
loop and depth the inner one, over the projector cone's depth interval padded to whole
16-lane vectors (padded lanes weigh 0). Per channel the depth loop runs in three
branch-free passes: delays, sample indices, fractions and weights (vectorised); the tap
samples, 16 depths at a time by :mod:`svss_proc.imaging.window_gather` (consecutive depths read
samples within a 32-sample window, served by two loads and one permute instead of a
hardware gather); then interpolation, phase and accumulation (vectorised). The passes
exchange data through per-slice work rows allocated outside the parallel loop. With the
refraction table the horizontal offset of a (column, channel) pair is constant along
depth, so the table row is fixed and the table is interpolated in z once per call at the
voxel depths. The GPU kernel (:mod:`svss_proc.imaging.gpu_kernel`) and exact Fermat delays keep the
voxel-order sum of :mod:`svss_proc.imaging.kernel_math`.

Precision: geometry is computed in float64 relative to the ping's projector and handed
to the kernel in the chosen precision (float32 or float64); the kernel computes and
accumulates each ping in that precision and the tile in complex64.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from svss_daq.conventions import remodulation

from ..conditioning import Conditioned
from .kernel_math import build, cast_like
from .delays import TravelTimeTable
from .delays import _cpu as refraction_cpu
from .window_gather import LANES, window_gather_1, window_gather_2, window_gather_4

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
_voxel_sum = _cpu.voxel_sum          # voxel-order sum (the GPU kernel's building block)
_cis = _cpu.cis
_weights = _cpu.weights
_travel_time = _cpu.travel_time


@nb.njit(inline="always", cache=True)
def _position(u, interp, nt, one):
    """Sample index (unsigned 31-bit: no negative-index wraparound, 32-bit indices),
    fractional position and validity (0/1) of the fractional sample index u, as in
    :mod:`svss_proc.imaging.kernel_math` ``sample``."""
    zero = one - one
    half = one / (one + one)
    if interp == 0:
        lo = zero
        hi = cast_like(one, nt - 1)
        uc = min(max(u, lo), hi)
        i0 = np.uint32(uc + half) & np.uint32(0x7FFFFFFF)
    elif interp == 1:
        lo = zero
        hi = cast_like(one, nt - 1) - cast_like(one, 1e-3)
        uc = min(max(u, lo), hi)
        i0 = np.uint32(uc) & np.uint32(0x7FFFFFFF)
    else:
        lo = one
        hi = cast_like(one, nt - 2) - cast_like(one, 1e-3)
        uc = min(max(u, lo), hi)
        i0 = np.uint32(uc) & np.uint32(0x7FFFFFFF)
    valid = (one if u >= lo else zero) * (one if u <= hi else zero)
    return i0, uc - cast_like(one, i0), valid


# ------------------------------------------------------------------------- the kernel


def _make_voxel_kernel(interp: int, mode: int, gating: bool, halvings: int):
    """Voxel-order kernel (channel loop innermost, :mod:`svss_proc.imaging.kernel_math`
    ``voxel_sum``), used for exact Fermat delays, whose per-pair solve dominates and does
    not vectorise."""

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


def _make_kernel(interp: int, mode: int, gating: bool, halvings: int):
    """Column-order kernel for straight rays (mode 0) and the refraction table (mode 1),
    specialised at compile time on interpolation, delay mode and gating (constant
    branches fold away, so that the depth loop vectorises). Keep the prange body free of
    array views: numba then marks the arrays noalias, which the depth loop needs to
    vectorise (gathers next to accumulator stores)."""
    if mode == 2:
        return _make_voxel_kernel(interp, mode, gating, halvings)

    ntap = len(_TAPS[interp])
    shift_s = _SHIFT[interp]                 # phase reference of the fraction, samples

    @nb.njit(parallel=True, fastmath=True, cache=True)
    def kernel(img_re, img_im, re, im, t0, inv_dt, theta, ax, cy, dz, h_tx, rx_dx,
               rx_dy, rx_h, apod, bore, cos_tx, cos_rx, inv_c, cw, cs, ttab, etab, inv_drho,
               tz0, inv_dz, h_ref, ia0, ia1):
        one = cast_like(re[0, 0, 0], 1)          # the kernel precision
        zero = one - one
        shift = cast_like(one, shift_s)
        ft = img_re.dtype
        nch = re.shape[1]
        nt = re.shape[2]
        nc = cy.size
        nd = dz.size
        npad = nd + LANES                            # room for a padded depth range
        b0, b1, b2 = bore[0], bore[1], bore[2]
        k_straight = inv_c * inv_dt                  # samples per metre of receive path
        dzp = np.empty(npad, dtype=ft)               # depths, padded with the last one
        for iz in range(npad if nd > 0 else 0):
            dzp[iz] = dz[min(iz, nd - 1)]
        # table: times and slownesses interpolated in z at the voxel depths, (n_rho, npad)
        n_rho = ttab.shape[0]
        if mode == 1:
            tz = np.empty((n_rho, npad), dtype=ft)
            ez_tab = np.empty((n_rho, npad), dtype=ft)
            n_z = ttab.shape[1]
            for iz in range(npad):
                v = min(max((dzp[iz] - tz0) * inv_dz, 0.0), n_z - 1.001)
                j = int(v)
                b = v - j
                for i in range(n_rho):
                    tz[i, iz] = (1 - b) * ttab[i, j] + b * ttab[i, j + 1]
                    ez_tab[i, iz] = (1 - b) * etab[i, j] + b * etab[i, j + 1]
        else:
            tz = np.empty((1, 1), dtype=ft)
            ez_tab = np.empty((1, 1), dtype=ft)
        # per along-track slice work rows (allocated here, outside the parallel loop, so
        # that they reach it as distinct arrays): projector delay and cone mask (zero
        # beyond the last depth: padded lanes weigh 0), accumulators, and per channel the
        # sample index, fraction, weight and gathered taps of each depth
        nk = ia1 - ia0
        counts = np.zeros(nk, dtype=np.int64)
        u1_w = np.zeros(nk * npad, dtype=ft)         # projector delay - t0, samples
        txm_w = np.zeros(nk * npad, dtype=ft)        # 1 inside the projector cone, else 0
        acr_w = np.empty(nk * npad, dtype=ft)
        aci_w = np.empty(nk * npad, dtype=ft)
        idx_w = np.empty(nk * npad, dtype=np.uint32)
        frac_w = np.empty(nk * npad, dtype=ft)
        wt_w = np.empty(nk * npad, dtype=ft)
        tap_w = np.empty(nk * 2 * ntap * npad, dtype=ft)  # re taps, then im taps
        for k in nb.prange(nk):
            ia = ia0 + k
            x = ax[ia]
            bs = np.uint64(k * npad)                 # unsigned: no negative-index wraparound
            bt = np.uint64(k * 2 * ntap * npad)
            n_upd = 0
            for ic in range(nc):
                y = cy[ic]
                for iz in range(nd):
                    z = dzp[iz]
                    vz = z + h_tx
                    inside = True
                    if gating:
                        r1 = math.sqrt(x * x + y * y + vz * vz)
                        inside = x * b0 + y * b1 + vz * b2 >= r1 * cos_tx
                    txm_w[bs + iz] = one if inside else zero
                    u1_w[bs + iz] = (_travel_time(mode, x, y, z, h_tx, inv_c, cw, cs, ttab,
                                                  etab, inv_drho, tz0, inv_dz, h_ref)
                                     - t0) * inv_dt
                # the cone's depth interval, padded to whole vectors (txm = 0 outside)
                lo = 0
                while lo < nd and txm_w[bs + lo] == zero:
                    lo += 1
                hi = nd
                while hi > lo and txm_w[bs + hi - 1] == zero:
                    hi -= 1
                if hi <= lo:
                    continue
                z_lo = np.uint64(lo)
                z_hi = z_lo + np.uint64((hi - lo + LANES - 1) // LANES * LANES)
                for iz in range(z_lo, z_hi):
                    acr_w[bs + iz] = zero
                    aci_w[bs + iz] = zero
                for ch in range(nch):
                    ex = x - rx_dx[ch]
                    ey = y - rx_dy[ch]
                    h = rx_h[ch]
                    e2 = ex * ex + ey * ey
                    eb = ex * b0 + ey * b1
                    g0 = apod[ch]
                    # table: row and weight of the horizontal offset, height correction
                    rho = math.sqrt(np.float64(ex) * ex + np.float64(ey) * ey)
                    ur = min(max(rho * inv_drho, 0.0), n_rho - 1.001)
                    ir = int(ur)
                    a = cast_like(one, ur - ir)
                    dh = cast_like(one, h - h_ref)
                    n_ch = zero                          # updates (exact: < 2^24)
                    for iz in range(z_lo, z_hi):        # delays and weights (vectorised)
                        z = dzp[iz]
                        ez = z + h
                        g = g0 * txm_w[bs + iz]
                        r2 = math.sqrt(e2 + ez * ez)     # dead code in ungated table mode
                        if gating:
                            g = g if eb + ez * b2 >= r2 * cos_rx else zero
                        if mode == 0:
                            u = u1_w[bs + iz] + r2 * k_straight
                        else:
                            t2 = ((one - a) * (tz[ir, iz] + dh * ez_tab[ir, iz])
                                  + a * (tz[ir + 1, iz] + dh * ez_tab[ir + 1, iz]))
                            u = u1_w[bs + iz] + t2 * inv_dt
                        i0, w, valid = _position(u, interp, nt, one)
                        idx_w[bs + iz] = i0
                        frac_w[bs + iz] = w
                        wt_w[bs + iz] = g * valid
                    for off in range(z_lo, z_hi, LANES):  # taps, 16 depths at a time
                        if ntap == 1:
                            window_gather_1(re, im, ch, idx_w, bs + off, tap_w, bt + off,
                                            npad)
                        elif ntap == 2:
                            window_gather_2(re, im, ch, idx_w, bs + off, tap_w, bt + off,
                                            npad)
                        else:
                            window_gather_4(re, im, ch, idx_w, bs + off, tap_w, bt + off,
                                            npad)
                    for iz in range(z_lo, z_hi):        # interpolate, phase, sum (vectorised)
                        w = frac_w[bs + iz]
                        g = wt_w[bs + iz]
                        c0, c1, c2, c3 = _weights(interp, w, one)
                        sr = c0 * tap_w[bt + iz]
                        si = c0 * tap_w[bt + np.uint64(ntap * npad) + iz]
                        if ntap > 1:
                            sr += c1 * tap_w[bt + np.uint64(npad) + iz]
                            si += c1 * tap_w[bt + np.uint64((ntap + 1) * npad) + iz]
                        if ntap > 2:
                            sr += (c2 * tap_w[bt + np.uint64(2 * npad) + iz]
                                   + c3 * tap_w[bt + np.uint64(3 * npad) + iz])
                            si += (c2 * tap_w[bt + np.uint64((ntap + 2) * npad) + iz]
                                   + c3 * tap_w[bt + np.uint64((ntap + 3) * npad) + iz])
                        cr, cs = _cis(theta * (w - shift), halvings, one)
                        acr_w[bs + iz] += g * (sr * cr - si * cs)
                        aci_w[bs + iz] += g * (sr * cs + si * cr)
                        n_ch += one if g != zero else zero
                    n_upd += np.int64(n_ch)
                for iz in range(lo, hi):
                    img_re[ia, ic, iz] += acr_w[bs + iz]
                    img_im[ia, ic, iz] += aci_w[bs + iz]
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
