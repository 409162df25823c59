"""Factorised back-projection: the live imaging method (``[imaging] live_method``).

A ping is imaged in two stages instead of one sum per voxel and channel:

1. **Coarse columns.** The imaging kernel itself (any delay model, precision or build)
   sums the ping's channels at a lattice of voxel columns ``factorised_step_m`` apart
   (along, across the track), at the tile's own voxel depths. The projector's cone is
   widened for this stage by the lattice's stencil, so that every voxel of the real
   cone has its neighbours computed.
2. **Interpolation.** At each depth the coarse image, demodulated by a reference delay
   tau_ref = t(projector -> voxel) + t(voxel -> array centre) from the same travel-time
   model, varies only as slowly as the receive aperture and the echo's envelope allow
   across a level plane; it is interpolated to the voxel columns with a separable
   Lanczos kernel of ``lanczos`` lobes (along, then across), remodulated with the
   voxel's own tau_ref and added where the voxel lies inside the projector's cone.

The depth axis is never interpolated (both stages use the same voxel depths), which keeps
the sharp range envelope exact. The channel sum is made once per coarse column instead
of once per voxel: (step_along x step_across / voxel^2) fewer updates less the
stencil's halo, for an interpolation error measured against the exact method
(docs/live_method.md; ``svss trade``; ``benchmarks/bench_live_method.py``).

Interpolation and phases run in the kernel precision, the cone decision in float64 (as
the kernels decide it, :class:`~.kernel_args.ConeGate`). The second stage is a numba CPU
kernel: with ``device = "cuda"`` the exact method is the live method (the configuration
says so).
"""

from __future__ import annotations

import dataclasses
import math

import numba as nb
import numpy as np

from .cpu_kernel import _cpu, _table_row, _table_time
from .kernel_args import (STRAIGHT, TABLE, ImageSlice, KernelData, PingArray, VoxelAxes,
                          kernel_args, surface_of)
from .kernel_math import cast_like

#: the second stage's phase factor and travel times, from the kernels' own building
#: blocks
_cis = _cpu.cis
_travel_time = _cpu.travel_time
_TWO_PI = 2.0 * math.pi


@dataclasses.dataclass(frozen=True)
class Factorisation:
    """The live method's lattice: coarse columns ``step_along_m`` apart along the track
    and ``step_across_m`` across it, a Lanczos interpolator of ``lanczos`` lobes
    (2 x lanczos taps per axis)."""
    step_along_m: float
    step_across_m: float
    lanczos: int

    @property
    def halo(self) -> int:
        """Coarse columns beyond the voxels that the stencil reads (a voxel between
        columns i and i + 1 reads i + 1 - lobes to i + lobes)."""
        return self.lanczos


def coarse_axis(lo: float, hi: float, step: float, halo: int) -> np.ndarray:
    """Lattice from ``halo`` steps below ``lo`` to at least ``halo`` steps above ``hi``."""
    n = int(math.floor((hi - lo) / step + 1e-9)) + 1 + 2 * halo
    return lo - halo * step + step * np.arange(n)


def lanczos_weights(x: np.ndarray, axis: np.ndarray, lobes: int
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Per output position ``x``: the first lattice index of its stencil and the
    2 x ``lobes`` Lanczos weights on the regular lattice ``axis`` (normalised to sum 1:
    a constant is interpolated exactly)."""
    step = float(axis[1] - axis[0])
    f = (np.asarray(x, dtype=np.float64) - axis[0]) / step
    first = np.floor(f).astype(np.int64) - (lobes - 1)
    if first.size and (first.min() < 0 or first.max() + 2 * lobes > axis.size):
        raise ValueError("factorised lattice does not cover the voxels' stencil")
    t = f[:, None] - (first[:, None] + np.arange(2 * lobes)[None, :])
    w = np.sinc(t) * np.sinc(t / lobes)
    w /= w.sum(axis=1, keepdims=True)
    return first, w


def coarse_surface(axes, along: np.ndarray, cross: np.ndarray) -> np.ndarray | None:
    """The interface's depth at the lattice's columns: bilinear in the tile's column
    surface, extended linearly beyond it (exact for a plane); None over a level one."""
    if getattr(axes, "surface", None) is None:
        return None
    surf = surface_of(axes)
    out = np.empty((along.size, surf.shape[1]))
    for j in range(surf.shape[1]):
        out[:, j] = _linear(along, axes.along, surf[:, j])
    res = np.empty((along.size, cross.size))
    for i in range(along.size):
        res[i] = _linear(cross, axes.cross, out[i])
    return res


def _linear(x, xp, fp):
    """Linear interpolation, extended linearly beyond the ends."""
    if xp.size < 2:
        return np.full(x.shape, float(fp[0]))
    y = np.interp(x, xp, fp)
    lo, hi = x < xp[0], x > xp[-1]
    y[lo] = fp[0] + (x[lo] - xp[0]) * (fp[1] - fp[0]) / (xp[1] - xp[0])
    y[hi] = fp[-1] + (x[hi] - xp[-1]) * (fp[-1] - fp[-2]) / (xp[-1] - xp[-2])
    return y


def _reference(kd: KernelData, array: PingArray, axes, delays, cos_tx: float):
    """Kernel arguments of the reference leg pair: the projector and one receiver at the
    array's centre (tap planes of one channel: only the geometry and times are read)."""
    p = kd.planes
    one = dataclasses.replace(kd, planes=p._replace(re=p.re[:, :1], im=p.im[:, :1]))
    centre = np.asarray(array.rx, dtype=np.float64).mean(axis=0)[None, :]
    return kernel_args(one, PingArray(array.tx, centre, array.bore, cos_tx, array.cos_rx),
                       axes, delays)


def add_ping(out: ImageSlice, kd: KernelData, array: PingArray, delays, plan: Factorisation,
             kernel, *, gating: bool = True) -> int:
    """Add one ping into ``out`` by the two stages; ``kernel`` is the imaging kernel's
    front door (:func:`~.cpu_kernel.run_ping`). Returns the first stage's
    voxel-channel updates."""
    axes, ia0, ia1 = out.axes, out.ia0, out.ia1
    if ia1 <= ia0:
        return 0
    along, cross, depth = (np.asarray(a, dtype=np.float64)
                           for a in (axes.along, axes.cross, axes.depth))
    h, hc, halo = plan.step_along_m, plan.step_across_m, plan.halo
    ca = coarse_axis(along[ia0], along[ia1 - 1], h, halo)
    cc = coarse_axis(cross[0], cross[-1], hc, halo)
    surf = coarse_surface(axes, ca, cc)
    coarse = VoxelAxes(ca, cc, depth, surf)
    # the cone widened by the stencil's reach at the tile's nearest depth (one kernel
    # call: bands of depths, each widened for its own top, cost more in calls than they
    # saved in columns)
    tx = np.asarray(array.tx, dtype=np.float64)
    rise = 0.0 if surf is None else min(0.0, float(surf.min()))   # the interface's highest
    nearest = max(float(depth[0]) + rise - float(tx[2]), 1e-3)
    half = math.acos(min(1.0, array.cos_tx)) + math.atan(halo * math.hypot(h, hc) / nearest)
    wide = array._replace(cos_tx=math.cos(min(half, math.pi / 2)))
    ft = kd.dtype.type
    shape = (ca.size, cc.size, depth.size)
    re = np.zeros(shape, dtype=ft)
    im = np.zeros(shape, dtype=ft)
    n = kernel(ImageSlice(re, im, coarse, 0, ca.size), kd, wide, delays, gating=gating)
    sig = float(kd.planes.theta) * float(kd.planes.inv_dt)   # REMODULATION_SIGN 2 pi f_c
    ref_c = _reference(kd, array, coarse, delays, array.cos_tx)
    _demodulate(re, im, ref_c.geometry, ref_c.delays, delays.code, sig)
    ja, wa = lanczos_weights(along[ia0:ia1], ca, plan.lanczos)
    jc, wc = lanczos_weights(cross, cc, plan.lanczos)
    ref = _reference(kd, array, axes, delays, array.cos_tx)
    _interpolate_add(re, im, ja, wa.astype(ft), jc, wc.astype(ft), out.re, out.im,
                     ref.geometry, ref.delays, ref.gate, delays.code, sig, ia0, bool(gating))
    return int(n)


@nb.njit(inline="always", cache=True)
def _column_times(mode, x, y, h_tx, ox, oy, h_o, dz, tt, tz, ez, kz, inv_drho, h_ref,
                  inv_cw, lo, hi, out, row, one):
    """tau_ref down one column (the projector's leg from offset (x, y) and height h_tx,
    the array centre's from (ox, oy) and h_o, as the kernels time them) for depths
    lo <= iz < hi, into ``out[row]``; a column's horizontal offsets, and so its table
    rows, are fixed. Arrays come in unpacked (see :func:`_interpolate_add`)."""
    if mode == TABLE:
        n_rho = tz.shape[0]
        i1, a1, d1 = _table_row(x, y, h_tx, inv_drho, n_rho, h_ref, one)
        i2, a2, d2 = _table_row(ox, oy, h_o, inv_drho, n_rho, h_ref, one)
        for iz in range(lo, hi):
            out[row, iz] = (_table_time(tz, ez, kz, True, i1, a1, d1, iz, one)
                            + _table_time(tz, ez, kz, True, i2, a2, d2, iz, one))
    elif mode == STRAIGHT:
        xy1 = x * x + y * y
        xy2 = ox * ox + oy * oy
        for iz in range(lo, hi):
            v1 = dz[iz] + h_tx
            v2 = dz[iz] + h_o
            out[row, iz] = (math.sqrt(xy1 + v1 * v1) + math.sqrt(xy2 + v2 * v2)) * inv_cw
    else:
        for iz in range(lo, hi):
            z = dz[iz]
            out[row, iz] = (_travel_time(mode, x, y, z, h_tx, tt)
                            + _travel_time(mode, ox, oy, z, h_o, tt))


@nb.njit(inline="always", cache=True)
def _column_phases(sig, t, row, lo, hi, c_out, s_out, one):
    """exp(j sig t[row, iz]) into c_out[row], s_out[row] for lo <= iz < hi: the column's
    first time's phase in float64, the rest relative to it in ``one``'s precision
    (reduced to [-pi, pi], the kernels' series after two halvings)."""
    if hi <= lo:
        return
    p0 = sig * np.float64(t[row, lo])
    c0 = cast_like(one, math.cos(p0))
    s0 = cast_like(one, math.sin(p0))
    sg = cast_like(one, sig)
    tw = cast_like(one, _TWO_PI)
    inv_tw = cast_like(one, 1.0 / _TWO_PI)
    half = cast_like(one, 0.5)
    t0k = t[row, lo]
    for iz in range(lo, hi):
        ph = sg * (t[row, iz] - t0k)
        ph -= tw * math.floor(ph * inv_tw + half)
        c, s = _cis(ph, 2, one)                    # |ph| <= pi: two halvings
        c_out[row, iz] = c * c0 - s * s0
        s_out[row, iz] = s * c0 + c * s0


@nb.njit(inline="always", cache=True)
def _inside(x, y, vz, b0, b1, b2, cos_tx):
    """A voxel at offset (x, y, vz) from the projector inside its cone: the kernels'
    float64 decision (``tx_inside64``)."""
    return x * b0 + y * b1 + vz * b2 >= math.sqrt(x * x + y * y + vz * vz) * cos_tx


@nb.njit(inline="always", cache=True)
def _cone_depths(x, y, h, dz, b0, b1, b2, cos_tx, gating):
    """The depth indices [lo, hi) of a column (offset (x, y) from the projector, which
    is h above the column's interface) inside the projector's cone, by the kernels'
    float64 decision; the whole column without gating. A line meets a cone in one
    interval; with the vertical inside the cone (b2 > cos_tx: a sonar looking down) it
    runs to the deepest voxel, and its top is found by bisection."""
    nd = dz.size
    if not gating:
        return 0, nd
    if b2 > cos_tx:
        if not _inside(x, y, dz[nd - 1] + h, b0, b1, b2, cos_tx):
            return nd, nd
        lo, hi = -1, nd - 1               # outside at lo (or above the column), inside at hi
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if _inside(x, y, dz[mid] + h, b0, b1, b2, cos_tx):
                hi = mid
            else:
                lo = mid
        return hi, nd
    lo = 0
    while lo < nd and not _inside(x, y, dz[lo] + h, b0, b1, b2, cos_tx):
        lo += 1
    hi = nd
    while hi > lo and not _inside(x, y, dz[hi - 1] + h, b0, b1, b2, cos_tx):
        hi -= 1
    return lo, hi


@nb.njit(inline="always", cache=True)
def _reference_arrays(g, tt):
    """The reference geometry's and travel times' arrays and numbers, one by one: the
    voxel axes and interface depths, the projector's height, the array centre's offsets
    and height, and the table's depth-interpolated times, slownesses and curvatures."""
    return (g.ax, g.cy, g.dz, g.surf, g.h_tx, g.rx_dx[0], g.rx_dy[0], g.rx_h[0], tt.tz,
            tt.ez, tt.kz, tt.inv_drho, tt.h_ref, tt.inv_cw)


@nb.njit(parallel=True, fastmath=True, cache=True)
def _demodulate(re, im, g, tt, mode, sig):
    """The coarse image times exp(-j sig tau_ref), in place."""
    na, nc, nd = re.shape
    one = cast_like(re[0, 0, 0], 1)
    ft = re.dtype
    # unpacked outside the parallel loop (as the imaging kernels do): the loop body sees
    # plain arrays, which numba knows do not alias, and its depth loops vectorise
    (ax, cy, dz, surf, h_tx0, odx, ody, oh0, tz, ez, kz, inv_drho, h_ref,
     inv_cw) = _reference_arrays(g, tt)
    tw = np.empty((na, nd), dtype=ft)
    cw = np.empty((na, nd), dtype=ft)
    sw = np.empty((na, nd), dtype=ft)
    for ia in nb.prange(na):
        x = ax[ia]
        for ic in range(nc):
            y = cy[ic]
            s = surf[ia, ic]
            _column_times(mode, x, y, h_tx0 + s, x - odx, y - ody, oh0 + s, dz, tt, tz, ez,
                          kz, inv_drho, h_ref, inv_cw, 0, nd, tw, ia, one)
            _column_phases(sig, tw, ia, 0, nd, cw, sw, one)
            for iz in range(nd):
                r = re[ia, ic, iz]
                i = im[ia, ic, iz]
                re[ia, ic, iz] = r * cw[ia, iz] + i * sw[ia, iz]
                im[ia, ic, iz] = i * cw[ia, iz] - r * sw[ia, iz]


def _make_interpolate_add(nt: int):
    """The second stage's kernel for a stencil of ``nt`` taps per axis (a compile-time
    constant: the tap loops unroll and the depth loop vectorises)."""

    @nb.njit(parallel=True, fastmath=True, cache=True)
    def interpolate_add(dre, dim, ja, wa, jc, wc, img_re, img_im, g, tt, gate, mode, sig,
                        ia0, gating):
        nk = ja.size
        ncc = dre.shape[1]
        nc = jc.size
        nd = dre.shape[2]
        one = cast_like(dre[0, 0, 0], 1)
        zero = one - one
        ft = dre.dtype
        (ax, cy, dz, surf, h_tx0, odx, ody, oh0, tz, ez, kz, inv_drho, h_ref,
         inv_cw) = _reference_arrays(g, tt)
        gax = gate.ax
        gcy = gate.cy
        gdz = gate.dz
        gsurf = gate.surf
        gh = gate.h_tx
        b0, b1, b2 = gate.bore[0], gate.bore[1], gate.bore[2]
        cos_tx = gate.cos_tx
        # the along pass, per slice, flat: rows addressed by unsigned offsets (no
        # negative-index wraparound in the depth loops, which then vectorise)
        row_re = np.empty(nk * ncc * nd, dtype=ft)
        row_im = np.empty(nk * ncc * nd, dtype=ft)
        und = np.uint64(nd)
        tw = np.empty((nk, nd), dtype=ft)               # a column's times and phases
        cw = np.empty((nk, nd), dtype=ft)
        sw = np.empty((nk, nd), dtype=ft)
        for k in nb.prange(nk):
            ia = ia0 + k
            j0 = ja[k]
            for icc in range(ncc):
                ob = np.uint64(k * ncc + icc) * und
                for iz in range(nd):
                    vr = zero
                    vi = zero
                    for m in range(nt):
                        vr += wa[k, m] * dre[j0 + m, icc, iz]
                        vi += wa[k, m] * dim[j0 + m, icc, iz]
                    row_re[ob + np.uint64(iz)] = vr
                    row_im[ob + np.uint64(iz)] = vi
            x = ax[ia]
            for ic in range(nc):
                lo, hi = _cone_depths(gax[ia], gcy[ic], gh + gsurf[ia, ic], gdz, b0, b1,
                                      b2, cos_tx, gating)
                if hi <= lo:
                    continue
                y = cy[ic]
                s = surf[ia, ic]
                # the whole column, the voxels outside the cone weighing 0: loops over
                # a fixed range vectorise where [lo, hi) did not (1.7x faster)
                _column_times(mode, x, y, h_tx0 + s, x - odx, y - ody, oh0 + s, dz, tt, tz,
                              ez, kz, inv_drho, h_ref, inv_cw, 0, nd, tw, k, one)
                _column_phases(sig, tw, k, 0, nd, cw, sw, one)
                ob = np.uint64(k * ncc + jc[ic]) * und
                for iz in range(nd):
                    u = np.uint64(iz)
                    vr = zero
                    vi = zero
                    for m in range(nt):
                        o = ob + np.uint64(m) * und + u
                        vr += wc[ic, m] * row_re[o]
                        vi += wc[ic, m] * row_im[o]
                    g_in = one if lo <= iz < hi else zero
                    c = cw[k, iz] * g_in
                    sn = sw[k, iz] * g_in
                    img_re[ia, ic, iz] += vr * c - vi * sn
                    img_im[ia, ic, iz] += vr * sn + vi * c

    return interpolate_add


_INTERPOLATE_ADD: dict = {}


def _interpolate_add(dre, dim, ja, wa, jc, wc, img_re, img_im, g, tt, gate, mode, sig,
                     ia0, gating):
    """Interpolate the demodulated lattice (along, then across), remodulate and add into
    the voxels ia0 + k (k < ja.size) inside the projector's cone. The kernel's arguments
    are unpacked before its parallel loop and work rows indexed in it, not taken as
    views (numba then knows they do not alias, and the depth loops vectorise)."""
    nt = wa.shape[1]
    kernel = _INTERPOLATE_ADD.get(nt)
    if kernel is None:
        kernel = _INTERPOLATE_ADD[nt] = _make_interpolate_add(nt)
    kernel(dre, dim, ja, wa, jc, wc, img_re, img_im, g, tt, gate, mode, sig, ia0, gating)
