"""Delay-and-sum backprojection kernels (numba CPU, parallel over along-track slices).

One ping's coherent sum is added into a tile:

    I(v) += sum_ch a_ch y_ch(tau) exp(+j 2 pi f_c tau),   tau = t_tx(v) + t_ch(v),

with y the complex baseband matched-filter output (:mod:`svss_daq.conventions`), a_ch an
optional apodisation weight, t the one-way travel times (straight rays, a refraction
table, or exact Fermat paths: :mod:`svss_proc.imaging.delays`), and, with gating on, only
voxels inside both the projector's and the receiver's beam cones.

Phase without trigonometry: the kernels read "tap planes" that fold the remodulation
into the samples (:mod:`svss_proc.imaging.kernel_args`); the remaining factor
exp(j theta (w - s)) is a short Taylor series of an angle below 1.4 rad (halved and
squared back when theta is larger), exact to ~1e-7 in float32. The kernels take one
structured argument, :class:`~svss_proc.imaging.kernel_args.KernelArgs` (tap planes,
voxel geometry, travel-time model), and are specialised at compile time on the
interpolation, delay mode, gating and the number of angle halvings.

Loop order (CPU): prange over along-track slices; per block of COLUMN_BLOCK neighbouring
voxel columns (along, cross) the projector delays and cone mask are computed once per
depth, then channels are the outer loop, the block's columns the middle one and depth
the inner one, over the projector cone's depth interval padded to whole 16-lane vectors
(padded lanes weigh 0); a channel's tap samples and table rows are thus reused from L1
across the block (issue 32). Per channel the depth loop runs in three
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

import numba as nb
import numpy as np

from .delays import _cpu as refraction_cpu
from .kernel_args import (EXACT, GATE_BAND, LINEAR, NEAREST, SHIFT, STRAIGHT, TABLE, TAPS,
                          ConeGate, DelayModel, ImageSlice, KernelArgs, KernelData,
                          PingArray, TapPlanes, TravelTimes, VoxelGeometry, check_call,
                          curved, kernel_args)
from .kernel_math import build, cast_like, kernel_one
from .window_gather import LANES, window_gather_1, window_gather_2, window_gather_4


#: cross-track columns of a slice that the column kernel sweeps per channel (issue 32:
#: on a 2-core Zen 3 without AVX-512, 8 gave 1.1-1.3x the one-column order, 16 about the
#: same as 8, 32 less: the block's work rows then outgrow L1)
COLUMN_BLOCK = 8

_cpu = build(nb.njit(inline="always", cache=True), refraction_cpu)
_voxel_sum = _cpu.voxel_sum          # voxel-order sum (the GPU kernel's building block)
_cis = _cpu.cis
_weights = _cpu.weights
_tx_inside64 = _cpu.tx_inside64
_rx_inside64 = _cpu.rx_inside64


@nb.njit(inline="always", cache=True)
def _position(u, interp, nt, one):
    """Sample index (31-bit, returned unsigned: no negative-index wraparound, 32-bit
    indices), fractional position and validity (0/1) of the fractional sample index u,
    as in :mod:`svss_proc.imaging.kernel_math` ``sample``. The clamped index lies in
    [0, nt), so the signed conversion gives the unsigned one's value: a single
    ``vcvttps2dq`` on AVX2, where a float-to-unsigned conversion (an AVX-512
    instruction) took six (issue 32)."""
    zero = one - one
    half = one / (one + one)
    if interp == NEAREST:
        lo = zero
        hi = cast_like(one, nt - 1)
        uc = min(max(u, lo), hi)
        i0 = np.int32(uc + half) & np.int32(0x7FFFFFFF)
    elif interp == LINEAR:
        lo = zero
        hi = cast_like(one, nt - 1) - cast_like(one, 1e-3)
        uc = min(max(u, lo), hi)
        i0 = np.int32(uc) & np.int32(0x7FFFFFFF)
    else:
        lo = one
        hi = cast_like(one, nt - 2) - cast_like(one, 1e-3)
        uc = min(max(u, lo), hi)
        i0 = np.int32(uc) & np.int32(0x7FFFFFFF)
    valid = (one if u >= lo else zero) * (one if u <= hi else zero)
    return np.uint32(i0), uc - cast_like(one, i0), valid


@nb.njit(inline="always", cache=True)
def _table_row(dx, dy, h, inv_drho, n_rho, h_ref, one):
    """Row and weight of the horizontal offset (dx, dy) in the refraction table, and the
    height offset h - h_ref of the element, for :func:`_table_time`."""
    rho = math.sqrt(np.float64(dx) * dx + np.float64(dy) * dy)
    ur = min(max(rho * inv_drho, 0.0), n_rho - 1.001)
    ir = int(ur)
    return ir, cast_like(one, ur - ir), cast_like(one, h - h_ref)


@nb.njit(inline="always", cache=True)
def _table_time(tz, ez, kz, curved, ir, a, dh, iz, one):
    """One-way time from the table interpolated at the voxel depths (``tz``, ``ez``,
    ``kz``: (n_rho, depths)): linear in offset between rows ir and ir + 1, first-order
    in the element height, second-order ``curved`` (a compile-time constant: over a
    sloping interface)."""
    if curved:
        hh = cast_like(one, 0.5) * dh
        return ((one - a) * (tz[ir, iz] + dh * (ez[ir, iz] + hh * kz[ir, iz]))
                + a * (tz[ir + 1, iz] + dh * (ez[ir + 1, iz] + hh * kz[ir + 1, iz])))
    return ((one - a) * (tz[ir, iz] + dh * ez[ir, iz])
            + a * (tz[ir + 1, iz] + dh * ez[ir + 1, iz]))


@nb.njit(inline="always", cache=True)
def _receive_u(mode, u1, r2, k_straight, tz, ez, kz, curved, ir, a, dh, iz, inv_dt, one):
    """Fractional sample index of a receive leg: the projector leg ``u1`` (samples) plus
    the receive leg, straight (``r2`` m at ``k_straight`` samples/m) or from the table."""
    if mode == STRAIGHT:
        return u1 + r2 * k_straight
    return u1 + _table_time(tz, ez, kz, curved, ir, a, dh, iz, one) * inv_dt


@nb.njit(inline="always", cache=True)
def _padded(n):
    """``n`` depths rounded up to whole vectors of LANES."""
    return (n + LANES - 1) // LANES * LANES


@nb.njit(cache=True)
def spread_step(n):
    """A step coprime with ``n`` near n / golden ratio: ``j -> (j * step) % n`` is a
    permutation of 0..n-1 under which every contiguous run of j covers the range evenly
    (a low-discrepancy order). The parallel loops run over along-track slices in this
    order: numba splits a prange into one contiguous block of iterations per thread, and
    the work per slice follows the projector cone (little at its edges, most under the
    projector), so contiguous blocks of slices left the threads at the cone's edges idle
    while the middle ones worked; spread, every thread gets slices from the whole cone.
    Each slice is computed by the same code whatever the order: images are unchanged."""
    if n <= 2:
        return 1
    step = max(1, int(n * 0.6180339887498949 + 0.5))
    while True:
        a, b = step, n
        while b:
            a, b = b, a % b
        if a == 1:
            return step
        step += 1


# ------------------------------------------------------------------------- the kernel


def _make_voxel_kernel(interp: int, mode: int, gating: bool, halvings: int,
                       spread: bool = True):
    """Voxel-order kernel (channel loop innermost, :mod:`svss_proc.imaging.kernel_math`
    ``voxel_sum``), used for exact Fermat delays, whose per-pair solve dominates and does
    not vectorise."""

    @nb.njit(parallel=True, fastmath=True, cache=True)
    def kernel(img_re, img_im, args, ia0, ia1):
        # numba's parallel loop takes flat arguments: unpack the bundles here and
        # rebuild them inside the loop
        p, g, d = args.planes, args.geometry, args.delays
        re, im, t0, inv_dt, theta = p.re, p.im, p.t0, p.inv_dt, p.theta
        ax, cy, dz, h_tx, rx_dx, rx_dy, rx_h, apod, bore, cos_tx, cos_rx, surf = (
            g.ax, g.cy, g.dz, g.h_tx, g.rx_dx, g.rx_dy, g.rx_h, g.apod, g.bore, g.cos_tx,
            g.cos_rx, g.surf)
        inv_cw, cw, cs, ttab, etab, inv_drho, z0, inv_dz, h_ref, tzd, ezd, ktab, kzd = (
            d.inv_cw, d.cw, d.cs, d.time, d.eta, d.inv_drho, d.z0, d.inv_dz, d.h_ref, d.tz,
            d.ez, d.kappa, d.kz)
        c = args.gate
        gx, gy, gz, gh, gdx, gdy, gdh, gb, gct, gcr, gs = (
            c.ax, c.cy, c.dz, c.h_tx, c.rx_dx, c.rx_dy, c.rx_h, c.bore, c.cos_tx, c.cos_rx,
            c.surf)
        one = kernel_one(re)
        nc = cy.size
        nd = dz.size
        counts = np.zeros(ia1 - ia0, dtype=np.int64)
        step = spread_step(ia1 - ia0) if spread else 1
        for j in nb.prange(ia1 - ia0):
            k = (j * step) % (ia1 - ia0)             # balanced order (spread_step)
            a = KernelArgs(TapPlanes(re, im, t0, inv_dt, theta),
                           VoxelGeometry(ax, cy, dz, h_tx, rx_dx, rx_dy, rx_h, apod, bore,
                                         cos_tx, cos_rx, surf),
                           TravelTimes(inv_cw, cw, cs, ttab, etab, inv_drho, z0, inv_dz,
                                       h_ref, tzd, ezd, ktab, kzd),
                           ConeGate(gx, gy, gz, gh, gdx, gdy, gdh, gb, gct, gcr, gs))
            ia = ia0 + k
            n_upd = 0
            for ic in range(nc):
                for iz in range(nd):
                    sr, si, n = _voxel_sum(ia, ic, iz, interp, mode, gating, halvings, a,
                                           one)
                    img_re[ia, ic, iz] += sr
                    img_im[ia, ic, iz] += si
                    n_upd += n
            counts[k] = n_upd
        return counts.sum()

    return kernel


def _make_kernel(interp: int, mode: int, gating: bool, halvings: int,
                 spread: bool = True, block: int = COLUMN_BLOCK, curved: bool = False):
    """Column-order kernel for straight rays (mode 0) and the refraction table (mode 1),
    specialised at compile time on interpolation, delay mode, gating and ``curved`` (a
    sloping interface: the table's second-order height correction) (constant
    branches fold away, so that the depth loop vectorises). Keep the prange body free of
    array views: numba then marks the arrays noalias, which the depth loop needs to
    vectorise (gathers next to accumulator stores)."""
    if mode == EXACT:
        return _make_voxel_kernel(interp, mode, gating, halvings, spread)

    ntap = len(TAPS[interp])
    shift_s = SHIFT[interp]                 # phase reference of the fraction, samples
    if block < 1:
        raise ValueError(f"column block of {block}: expected 1 or more")
    nb_col = int(block)                     # cross-track columns per channel sweep

    @nb.njit(parallel=True, fastmath=True, cache=True)
    def kernel(img_re, img_im, args, ia0, ia1):
        # unpacked here, outside the parallel loop: the loop body then sees plain arrays
        re = args.planes.re
        im = args.planes.im
        t0 = args.planes.t0
        inv_dt = args.planes.inv_dt
        theta = args.planes.theta
        ax = args.geometry.ax
        cy = args.geometry.cy
        dz = args.geometry.dz
        h_tx = args.geometry.h_tx
        rx_dx = args.geometry.rx_dx
        rx_dy = args.geometry.rx_dy
        rx_h = args.geometry.rx_h
        apod = args.geometry.apod
        bore = args.geometry.bore
        cos_tx = args.geometry.cos_tx
        cos_rx = args.geometry.cos_rx
        surf = args.geometry.surf
        inv_c = args.delays.inv_cw
        ttab = args.delays.time
        etab = args.delays.eta
        inv_drho = args.delays.inv_drho
        ktab = args.delays.kappa
        tz0 = args.delays.z0
        inv_dz = args.delays.inv_dz
        h_ref = args.delays.h_ref
        gx, gy, gz, gh, gdx, gdy, gdh, gb, gct, gcr, gs = args.gate   # float64: cone edges
        one = cast_like(re[0, 0, 0], 1)          # the kernel precision
        zero = one - one
        shift = cast_like(one, shift_s)
        band = cast_like(one, GATE_BAND)
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
        if mode == TABLE:
            tz = np.empty((n_rho, npad), dtype=ft)
            ez_tab = np.empty((n_rho, npad), dtype=ft)
            kz = np.empty((n_rho, npad) if curved else (1, 1), dtype=ft)
            n_z = ttab.shape[1]
            for iz in range(npad):
                v = min(max((dzp[iz] - tz0) * inv_dz, 0.0), n_z - 1.001)
                j = int(v)
                b = v - j
                for i in range(n_rho):
                    tz[i, iz] = (1 - b) * ttab[i, j] + b * ttab[i, j + 1]
                    ez_tab[i, iz] = (1 - b) * etab[i, j] + b * etab[i, j + 1]
                    if curved:
                        kz[i, iz] = (1 - b) * ktab[i, j] + b * ktab[i, j + 1]
        else:
            tz = np.empty((1, 1), dtype=ft)
            ez_tab = np.empty((1, 1), dtype=ft)
            kz = np.empty((1, 1), dtype=ft)
        # per along-track slice work rows (allocated here, outside the parallel loop, so
        # that they reach it as distinct arrays). Per column of the slice's current block
        # of `nb_col` cross-track columns: projector delay and cone mask (zero beyond the
        # last depth: padded lanes weigh 0), accumulators, and the cone's depth interval;
        # per slice, for the (column, channel) pair at hand: sample index, fraction,
        # weight and gathered taps of each depth
        nk = ia1 - ia0
        counts = np.zeros(nk, dtype=np.int64)
        n_blk = nk * nb_col * npad
        u1_w = np.zeros(n_blk, dtype=ft)             # projector delay - t0, samples
        txm_w = np.zeros(n_blk, dtype=ft)            # 1 inside the projector cone, else 0
        acr_w = np.empty(n_blk, dtype=ft)
        aci_w = np.empty(n_blk, dtype=ft)
        zr_w = np.zeros(nk * nb_col * 2, dtype=np.int64)   # the cone's depths lo, hi
        idx_w = np.empty(nk * npad, dtype=np.uint32)
        frac_w = np.empty(nk * npad, dtype=ft)
        wt_w = np.empty(nk * npad, dtype=ft)
        tap_w = np.empty(nk * 2 * ntap * npad, dtype=ft)  # re taps, then im taps
        step = spread_step(nk) if spread else 1      # balanced order: spread_step
        for j in nb.prange(nk):
            k = (j * step) % nk
            ia = ia0 + k
            x = ax[ia]
            gate = ConeGate(gx, gy, gz, gh, gdx, gdy, gdh, gb, gct, gcr, gs)
            bs = np.uint64(k * npad)                 # unsigned: no negative-index wraparound
            bt = np.uint64(k * 2 * ntap * npad)
            n_upd = 0
            for ic0 in range(0, nc, nb_col):
                ncol = min(nb_col, nc - ic0)
                n_live = 0
                for c in range(ncol):                # the block's projector legs
                    ic = ic0 + c
                    y = cy[ic]
                    bc = np.uint64((k * nb_col + c) * npad)
                    h1 = h_tx + surf[ia, ic]             # above this column's interface
                    ir1, a1, dh1 = _table_row(x, y, h1, inv_drho, n_rho, h_ref, one)
                    n_edge = zero                        # depths at the projector's edge
                    for iz in range(nd):
                        z = dzp[iz]
                        vz = z + h1
                        r1 = math.sqrt(x * x + y * y + vz * vz)
                        inside = True
                        if gating:
                            m1 = x * b0 + y * b1 + vz * b2 - r1 * cos_tx
                            inside = m1 >= zero
                            n_edge += one if abs(m1) <= band * r1 else zero
                        txm_w[bc + iz] = one if inside else zero
                        if mode == STRAIGHT:
                            t1 = r1 * inv_c
                        else:
                            t1 = _table_time(tz, ez_tab, kz, curved, ir1, a1, dh1, iz, one)
                        u1_w[bc + iz] = (t1 - t0) * inv_dt
                    if gating and n_edge > zero:         # rare: decide those in float64
                        for iz in range(nd):
                            vz = dzp[iz] + h1
                            r1 = math.sqrt(x * x + y * y + vz * vz)
                            if abs(x * b0 + y * b1 + vz * b2 - r1 * cos_tx) <= band * r1:
                                txm_w[bc + iz] = (one if _tx_inside64(gate, ia, ic, iz)
                                                  else zero)
                    # the cone's depth interval (txm = 0 outside)
                    lo = 0
                    while lo < nd and txm_w[bc + lo] == zero:
                        lo += 1
                    hi = nd
                    while hi > lo and txm_w[bc + hi - 1] == zero:
                        hi -= 1
                    zc = (k * nb_col + c) * 2
                    if hi <= lo:
                        lo = hi = 0
                    zr_w[zc] = lo
                    zr_w[zc + 1] = hi
                    n_live += 1 if hi > lo else 0
                    for iz in range(np.uint64(lo), np.uint64(lo + _padded(hi - lo))):
                        acr_w[bc + iz] = zero
                        aci_w[bc + iz] = zero
                if n_live == 0:
                    continue
                # channels outer, the block's columns inner: a channel's tap samples and
                # table rows stay in L1 across the block's neighbouring columns instead of
                # coming back from L2 for every column (issue 32). Each voxel still sums
                # its channels in channel order: the image is unchanged.
                for ch in range(nch):
                    h0 = rx_h[ch]
                    g0 = apod[ch]
                    ex = x - rx_dx[ch]
                    for c in range(ncol):
                        zc = (k * nb_col + c) * 2
                        lo = zr_w[zc]
                        hi = zr_w[zc + 1]
                        if hi <= lo:
                            continue
                        ic = ic0 + c
                        bc = np.uint64((k * nb_col + c) * npad)
                        # the depth interval padded to whole vectors (padded lanes weigh 0)
                        z_lo = np.uint64(lo)
                        z_hi = z_lo + np.uint64(_padded(hi - lo))
                        ey = cy[ic] - rx_dy[ch]
                        h = h0 + surf[ia, ic]            # above this column's interface
                        e2 = ex * ex + ey * ey
                        eb = ex * b0 + ey * b1
                        ir, a, dh = _table_row(ex, ey, h, inv_drho, n_rho, h_ref, one)
                        n_ch = zero                      # updates (exact: < 2^24)
                        n_edge = zero                    # depths at a receiver cone edge
                        for iz in range(z_lo, z_hi):    # delays and weights (vectorised)
                            z = dzp[iz]
                            ez = z + h
                            g = g0 * txm_w[bc + iz]
                            r2 = math.sqrt(e2 + ez * ez)  # dead code in ungated table mode
                            if gating:
                                m2 = eb + ez * b2 - r2 * cos_rx
                                n_edge += one if abs(m2) <= band * r2 else zero
                                g = g if m2 >= zero else zero
                            u = _receive_u(mode, u1_w[bc + iz], r2, k_straight, tz, ez_tab,
                                           kz, curved, ir, a, dh, iz, inv_dt, one)
                            i0, w, valid = _position(u, interp, nt, one)
                            idx_w[bs + iz] = i0
                            frac_w[bs + iz] = w
                            wt_w[bs + iz] = g * valid
                        if gating and n_edge > zero:    # rare: decide those in float64
                            for iz in range(z_lo, min(z_hi, nd)):
                                ez = dzp[iz] + h
                                r2 = math.sqrt(e2 + ez * ez)
                                if abs(eb + ez * b2 - r2 * cos_rx) <= band * r2:
                                    u = _receive_u(mode, u1_w[bc + iz], r2, k_straight, tz,
                                                   ez_tab, kz, curved, ir, a, dh, iz,
                                                   inv_dt, one)
                                    valid = _position(u, interp, nt, one)[2]
                                    inside = _rx_inside64(gate, ia, ic, iz, ch)
                                    wt_w[bs + iz] = (g0 * txm_w[bc + iz] * valid if inside
                                                     else zero)
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
                        for iz in range(z_lo, z_hi):    # interpolate, phase, sum (vectorised)
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
                            cr, ci = _cis(theta * (w - shift), halvings, one)
                            acr_w[bc + iz] += g * (sr * cr - si * ci)
                            aci_w[bc + iz] += g * (sr * ci + si * cr)
                            n_ch += one if g != zero else zero
                        n_upd += np.int64(n_ch)
                for c in range(ncol):
                    zc = (k * nb_col + c) * 2
                    ic = ic0 + c
                    bc = np.uint64((k * nb_col + c) * npad)
                    for iz in range(zr_w[zc], zr_w[zc + 1]):
                        img_re[ia, ic, iz] += acr_w[bc + iz]
                        img_im[ia, ic, iz] += aci_w[bc + iz]
            counts[k] = n_upd
        return counts.sum()

    return kernel


_KERNELS: dict[tuple[int, int, bool, int], object] = {}


def kernel_for(interp: int, mode: int, gating: bool, halvings: int,
               curved: bool = False):
    """The compiled kernel ``kernel(img_re, img_im, args: KernelArgs, ia0, ia1)`` for an
    (interpolation, delay mode, gating, halvings, sloping interface) combination: adds
    one ping into the image planes (along x cross x depth) for along-track indices
    ia0 <= ia < ia1 and returns the voxel-channel updates."""
    key = (interp, mode, bool(gating), int(halvings), bool(curved and mode == TABLE))
    if key not in _KERNELS:
        _KERNELS[key] = _make_kernel(*key[:4], curved=key[4])
    return _KERNELS[key]


def run_ping(out: ImageSlice, kd: KernelData, array: PingArray, delays: DelayModel, *,
             gating: bool = True) -> int:
    """Add one ping (tap planes ``kd``, its ``array`` in the tile frame, float64) into
    the image planes of ``out`` for its along-track indices ``out.ia0 <= ia < out.ia1``,
    with travel times from ``delays``; ``gating``: sum only voxels inside both cones.
    The kernel precision is the image planes'. Returns the number of voxel-channel
    updates."""
    if kd.dtype != out.re.dtype:
        raise ValueError(f"kernel data is {kd.dtype}, the image planes are {out.re.dtype}")
    check_call(out)
    args = kernel_args(kd, array, out.axes, delays)
    kernel = kernel_for(kd.interp, delays.code, gating, kd.halvings, curved(out.axes))
    return int(kernel(out.re, out.im, args, out.ia0, out.ia1))
