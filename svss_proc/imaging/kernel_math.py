"""Scalar building blocks of the backprojection kernels, defined once for the CPU and
the GPU: :func:`build` compiles them with a given decorator (numba's ``njit`` for the CPU
kernels, a CUDA device decorator for the GPU kernel).

Phase factor: (cos x, sin x) by a Taylor series for |x| <= 1.4 rad, after ``halvings``
halvings of the angle, squared back. Interpolation weights: nearest, linear, and Keys'
cubic convolution (a = -1/2). Travel times: straight rays, a refraction table with a
first-order height correction (interpolated at the voxel depths beforehand for the voxel
sum: :func:`~svss_proc.imaging.kernel_args.depth_table`), or the exact Fermat path.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
from numba import types
from numba.extending import overload

from .kernel_args import CUBIC, GATE_BAND, LINEAR, NEAREST, STRAIGHT, TABLE


def cast_like(ref, x):
    """``x`` converted to the floating type of ``ref`` (float32 or float64)."""
    return np.asarray(ref).dtype.type(x)


@overload(cast_like, inline="always", target="generic")
def _cast_like(ref, x):
    if ref == types.float32:
        return lambda ref, x: np.float32(x)
    return lambda ref, x: np.float64(x)


def kernel_one(planes_re):
    """1 in the kernel precision, the dtype of the tap planes. Kernels must take it from
    here: ``re[0, 0, 0] * 0 + 1`` types as float64 in numba (float32 times an integer),
    which silently ran the float32 GPU kernel's interpolation, phase and sums in float64
    (mixed with float32 geometry) while the CUDA simulator (numpy scalars) ran them in
    float32: the simulator did not test the arithmetic the GPU ran."""
    return cast_like(planes_re[0, 0, 0], 1)


@overload(kernel_one, inline="always", target="generic")
def _kernel_one(planes_re):
    if planes_re.dtype == types.float32:
        return lambda planes_re: np.float32(1)
    return lambda planes_re: np.float64(1)


def build(jit, refr):
    """The scalar functions compiled with ``jit``; ``refr`` holds the matching
    refraction functions (:func:`svss_proc.imaging.delays.build_refraction`)."""
    one_way_time = refr.one_way_time

    @jit
    def cis(x, halvings, one):
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


    @jit
    def weights(interp, w, one):
        """Interpolation weights (up to four taps) at fractional position w."""
        zero = one - one
        if interp == NEAREST:
            return one, zero, zero, zero
        if interp == LINEAR:
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


    @jit
    def sample(re, im, ch, u, interp, halvings, theta, nt, one):
        """Remodulated, interpolated sample of channel ``ch`` at fractional index u, branch
        free so that the channel loop vectorises. Returns (re, im, valid as 0/1 weight)."""
        zero = one - one
        half = cast_like(one, 0.5)
        if interp == NEAREST:
            lo = zero
            hi = cast_like(one, nt - 1)
            uc = min(max(u, lo), hi)
            i0 = np.int32(uc + half)
            shift = zero
        elif interp == LINEAR:
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
        c0, c1, c2, c3 = weights(interp, w, one)
        sr = c0 * re[0, ch, i0]
        si = c0 * im[0, ch, i0]
        if interp != NEAREST:
            sr += c1 * re[1, ch, i0]
            si += c1 * im[1, ch, i0]
        if interp == CUBIC:
            sr += c2 * re[2, ch, i0] + c3 * re[3, ch, i0]
            si += c2 * im[2, ch, i0] + c3 * im[3, ch, i0]
        cr, ci = cis(theta * (w - shift), halvings, one)
        return sr * cr - si * ci, sr * ci + si * cr, valid


    @jit
    def travel_time(mode, dx, dy, z, h, tt):
        """One-way travel time from an element at height h above the interface
        (horizontal offset (dx, dy) to the voxel at depth z below the interface), with
        the travel-time model ``tt`` (:class:`~svss_proc.imaging.kernel_args.TravelTimes`)."""
        if mode == STRAIGHT:
            dz = z + h
            return math.sqrt(dx * dx + dy * dy + dz * dz) * tt.inv_cw
        one = cast_like(tt.inv_cw, 1)        # kernel precision (`x * 0 + 1` is float64)
        rho = math.sqrt(np.float64(dx) * dx + np.float64(dy) * dy)
        if mode == TABLE:
            ttab = tt.time
            etab = tt.eta
            n_rho, n_z = ttab.shape
            u = min(max(rho * tt.inv_drho, 0.0), n_rho - 1.001)
            v = min(max((z - tt.z0) * tt.inv_dz, 0.0), n_z - 1.001)
            i = int(u)
            j = int(v)
            a = u - i
            b = v - j
            t = ((1 - a) * ((1 - b) * ttab[i, j] + b * ttab[i, j + 1])
                 + a * ((1 - b) * ttab[i + 1, j] + b * ttab[i + 1, j + 1]))
            e = ((1 - a) * ((1 - b) * etab[i, j] + b * etab[i, j + 1])
                 + a * ((1 - b) * etab[i + 1, j] + b * etab[i + 1, j + 1]))
            dh = h - tt.h_ref
            ktab = tt.kappa
            if ktab.shape[0] == n_rho and ktab.shape[1] == n_z:
                e += 0.5 * dh * ((1 - a) * ((1 - b) * ktab[i, j] + b * ktab[i, j + 1])
                                 + a * ((1 - b) * ktab[i + 1, j] + b * ktab[i + 1, j + 1]))
            return cast_like(one, t + dh * e)
        return cast_like(one, one_way_time(np.float64(h), rho, np.float64(z), tt.cw, tt.cs))

    @jit
    def depth_table_time(dx, dy, iz, h, tt, one):
        """One-way time from the refraction table interpolated at the voxel depth index
        ``iz`` (``tt.tz``, ``tt.ez``, ``tt.kz``): the offset's row and weight in float64
        (as the CPU column kernel's ``_table_row``), then linear in offset and to second
        order in the element height ``h`` (``kz`` zeros over a level interface: the
        first order) in the kernel precision."""
        tz = tt.tz
        ez = tt.ez
        kz = tt.kz
        rho = math.sqrt(np.float64(dx) * dx + np.float64(dy) * dy)
        ur = min(max(rho * tt.inv_drho, 0.0), tz.shape[0] - 1.001)
        ir = int(ur)
        a = cast_like(one, ur - ir)
        dh = cast_like(one, h - tt.h_ref)
        hh = cast_like(one, 0.5) * dh
        return ((one - a) * (tz[ir, iz] + dh * (ez[ir, iz] + hh * kz[ir, iz]))
                + a * (tz[ir + 1, iz] + dh * (ez[ir + 1, iz] + hh * kz[ir + 1, iz])))

    @jit
    def tx_inside64(c, ia, ic, iz):
        """Voxel (ia, ic, iz) inside the projector's cone, decided in float64 from the
        float64 geometry ``c`` (:class:`~svss_proc.imaging.kernel_args.ConeGate`), as the
        float64 kernels decide it."""
        x = c.ax[ia]
        y = c.cy[ic]
        vz = c.dz[iz] + c.h_tx + c.surf[ia, ic]
        r = math.sqrt(x * x + y * y + vz * vz)
        return x * c.bore[0] + y * c.bore[1] + vz * c.bore[2] >= r * c.cos_tx

    @jit
    def rx_inside64(c, ia, ic, iz, ch):
        """Voxel (ia, ic, iz) inside receiver ``ch``'s cone, in float64 (as
        :func:`tx_inside64`)."""
        ex = c.ax[ia] - c.rx_dx[ch]
        ey = c.cy[ic] - c.rx_dy[ch]
        ez = c.dz[iz] + c.rx_h[ch] + c.surf[ia, ic]
        r = math.sqrt(ex * ex + ey * ey + ez * ez)
        return ex * c.bore[0] + ey * c.bore[1] + ez * c.bore[2] >= r * c.cos_rx

    @jit
    def voxel_sum(ia, ic, iz, interp, mode, gating, halvings, args, one):
        """One ping's coherent sum at voxel (ia, ic, iz) of the geometry's axes (offsets
        from the projector, depth below the interface of its column, ``surf[ia, ic]``
        below the level the element heights are measured from: each leg is refracted
        at that depth, the interface taken as level about the column); ``args`` a
        :class:`~svss_proc.imaging.kernel_args.KernelArgs`. Returns (re, im, updates); no
        update when the voxel is outside the projector's cone (with gating). Cone
        decisions within GATE_BAND of an edge are made in float64 (``args.gate``)."""
        zero = one - one
        p = args.planes
        g = args.geometry
        tt = args.delays
        x = g.ax[ia]
        y = g.cy[ic]
        z = g.dz[iz]
        s = g.surf[ia, ic]                           # this column's interface depth
        band = cast_like(one, GATE_BAND)
        re = p.re
        im = p.im
        rx_dx = g.rx_dx
        rx_dy = g.rx_dy
        rx_h = g.rx_h
        apod = g.apod
        b0 = g.bore[0]
        b1 = g.bore[1]
        b2 = g.bore[2]
        nch = re.shape[1]
        nt = re.shape[2]
        h_tx = g.h_tx + s                            # the projector above this column's
        vz = z + h_tx                                # interface; the voxel below it
        r1 = math.sqrt(x * x + y * y + vz * vz)
        if gating:
            m1 = x * b0 + y * b1 + vz * b2 - r1 * g.cos_tx
            if abs(m1) <= band * r1:                 # at the edge: as in float64
                if not tx_inside64(args.gate, ia, ic, iz):
                    return zero, zero, 0
            elif m1 < zero:
                return zero, zero, 0
        # the projector leg in samples after the window start, once per voxel; each
        # channel adds its own leg (relative quantities only: no absolute time is
        # formed and differenced)
        inv_dt = p.inv_dt
        if mode == TABLE:
            u1 = (depth_table_time(x, y, iz, h_tx, tt, one) - p.t0) * inv_dt
        else:
            u1 = (travel_time(mode, x, y, z, h_tx, tt) - p.t0) * inv_dt
        acc_re = zero
        acc_im = zero
        n_upd = 0
        for ch in range(nch):
            ex = x - rx_dx[ch]
            ey = y - rx_dy[ch]
            h = rx_h[ch] + s
            ez = z + h
            w = apod[ch]
            if gating:
                r2 = math.sqrt(ex * ex + ey * ey + ez * ez)
                m2 = ex * b0 + ey * b1 + ez * b2 - r2 * g.cos_rx
                if abs(m2) <= band * r2:             # at the edge: as in float64
                    w = w if rx_inside64(args.gate, ia, ic, iz, ch) else zero
                else:
                    w = w if m2 >= zero else zero
            if mode == TABLE:
                u = u1 + depth_table_time(ex, ey, iz, h, tt, one) * inv_dt
            else:
                u = u1 + travel_time(mode, ex, ey, z, h, tt) * inv_dt
            sr, si, valid = sample(re, im, ch, u, interp, halvings, p.theta, nt, one)
            w = w * valid
            acc_re += w * sr
            acc_im += w * si
            n_upd += np.int64(w != zero)
        return acc_re, acc_im, n_upd

    return SimpleNamespace(cis=cis, weights=weights, sample=sample, travel_time=travel_time,
                           depth_table_time=depth_table_time,
                           tx_inside64=tx_inside64, rx_inside64=rx_inside64,
                           voxel_sum=voxel_sum)
