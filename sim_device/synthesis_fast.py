"""The fast path of the point-scatterer synthesis (``[scattering] synthesis = "fast"``,
the default): pass 1 with the legs of first-sediment scatterers vectorised across
scatterers (:func:`transmit_fast_kernel`) and pass 2 scatterer-parallel into per-thread
float32 buffers, one scatterer's receive legs vectorised across channels
(:func:`accumulate_fast_kernel`; :func:`accumulate_fast_serial_kernel`, the same without
threads, for pings with few scatterers in view). The vector legs are
:mod:`sim_device.synthesis_fast_legs`'; the legs they do not cover go through the
reference's scalar leg (:func:`sim_device.synthesis_legs.leg_body`).

The kernels take the bundles of :mod:`sim_device.synthesis_args`; :func:`accumulate_fast`
and :func:`accumulate_fast_serial` take pass 2's as one
:class:`~sim_device.synthesis_args.Pass2`.

The reference pass 2 (:func:`sim_device.synthesis_reference.accumulate_kernel`) runs
channels in parallel and, for each channel, every scatterer through the echo loop of
:mod:`sim_device.echo_loop` (the GPU kernel's loop): the scatterer arrays are streamed
once per channel and the per-scatterer bookkeeping (earliest transmit delay, receive
images needed) is kept in ping-sized arrays. :func:`accumulate_fast_kernel` turns the
loops round: threads take interleaved chunks of scatterers; for each scatterer the
bookkeeping is done once, each receive image's legs are evaluated for all channels in one
inner loop (the reference's scalar leg, ``leg_body``, where the vectorised forms do not
apply; element-image rows transposed so the channel loop reads contiguous memory), then
every kept transmit image's echoes for all channels are formed (vectorised) and added to
the thread's own float32 buffer, laid out (channel, sample) with each sample's real and
imaginary parts side by side, so that an echo's four Lagrange taps are eight neighbouring
floats, added as one vector multiply-add (:func:`_add_taps`). The threads' buffers are
summed at the end. It does not share the echo loop: a loop over one channel's echoes
cannot be vectorised across channels, which is this kernel's speed. The echoes and their
delays, amplitudes and phases are those of the reference to float64 rounding; only the
accumulation is float32, so the two paths agree to float32 rounding.

Every kernel unpacks its bundles at its top and its loops see plain arrays only: a
bundle passed on into the functions the loops call costs an atomic reference count per
array per call and the loop unswitching LLVM does otherwise (docs/simulator.md,
"Bundled kernels and speed").
"""

from __future__ import annotations

import numba as nb
import numpy as np
from llvmlite import ir as llvm_ir
from numba import types as nbtypes
from numba.core import cgutils
from numba.extending import intrinsic

from .synthesis_args import IMG_DIR, IMG_H, IMG_NB, IMG_RS, IMG_X, IMG_Y, MED_INTERFACE, Pass2
from .synthesis_fast_legs import (_beam_scalars, _beam_table, _interface_tables,
                                  _receive_legs, _receive_scalars, _transmit_image)
from .synthesis_legs import _interp, cis_cycles32, lagrange4, leg_body, renamed
from .synthesis_reference import transmit_leg

#: below this many scatterers in view the serial kernel is used
SERIAL_BELOW = 2048


@intrinsic
def _add_taps(typingctx, buf, row, col, re, im, w0, w1, w2, w3):
    """buf[row, col:col + 8] += (re w0, im w0, re w1, im w1, re w2, im w2, re w3, im w3)
    for a C-contiguous float32 ``buf`` (an echo's four Lagrange taps, real and imaginary
    parts interleaved), as one <8 x float> multiply-add: numba leaves LLVM's SLP
    vectoriser off and the eight scalar adds unvectorised. Generic LLVM vector IR (on
    AVX: one 256-bit load, fused multiply-add and store; split on narrower targets);
    no bounds or negative-index checks (the caller's index is in the buffer)."""
    sig = nbtypes.void(buf, row, col, re, im, w0, w1, w2, w3)

    def codegen(context, builder, signature, args):
        arrty = signature.args[0]
        ary = context.make_array(arrty)(context, builder, args[0])
        inds = [context.cast(builder, v, t, nbtypes.intp)
                for v, t in zip(args[1:3], signature.args[1:3])]
        ptr = cgutils.get_item_pointer2(context, builder, data=ary.data,
                                        shape=cgutils.unpack_tuple(builder, ary.shape),
                                        strides=cgutils.unpack_tuple(builder, ary.strides),
                                        layout=arrty.layout, inds=inds, wraparound=False,
                                        boundscheck=False)
        v8 = llvm_ir.VectorType(llvm_ir.FloatType(), 8)
        re_, im_, *w = (context.cast(builder, v, t, nbtypes.float32)
                        for v, t in zip(args[3:], signature.args[3:]))
        x = llvm_ir.Constant(v8, llvm_ir.Undefined)
        y = llvm_ir.Constant(v8, llvm_ir.Undefined)
        for j in range(8):
            lane = llvm_ir.Constant(llvm_ir.IntType(32), j)
            x = builder.insert_element(x, re_ if j % 2 == 0 else im_, lane)
            y = builder.insert_element(y, w[j // 2], lane)
        vptr = builder.bitcast(ptr, v8.as_pointer())
        fmuladd = cgutils.get_or_insert_function(
            builder.module, llvm_ir.FunctionType(v8, [v8, v8, v8]), "llvm.fmuladd.v8f32")
        builder.store(builder.call(fmuladd, [x, y, builder.load(vptr, align=4)]), vptr,
                      align=4)
        return context.get_dummy_value()

    if not (isinstance(buf, nbtypes.Array) and buf.dtype == nbtypes.float32
            and buf.ndim == 2 and buf.layout == "C"):
        return None
    return sig, codegen


@nb.njit(parallel=True, cache=True, fastmath=True, error_model="numpy")
def transmit_fast_kernel(pts, samp, img, medium, beam, out):
    """Pass 1 as :func:`~sim_device.synthesis_reference.transmit_kernel` (the same legs:
    delays and amplitudes to float64 rounding, the attenuation's exponential to < 1e-12
    relative for realistic paths), the legs of scatterers in the first sediment
    vectorised across scatterers
    (:func:`~sim_device.synthesis_fast_legs._transmit_image`, chunks of 256 per thread),
    the others by the scalar leg (:func:`~sim_device.echo_loop.build`'s
    ``transmit_leg``)."""
    sx, sy, sz, smed = pts
    c, rho_m, delta, alpha, z_top, tab, r_top, r_bot, sig = medium
    bore, g_front, g_back, lo_front, lo_back = beam
    tau_out, amp_out = out
    ns = sx.size
    nt = img.shape[0]
    nmed = c.size
    rt_re = np.ascontiguousarray(r_top.real)
    rt_im = np.ascontiguousarray(r_top.imag)
    rb_re = np.ascontiguousarray(r_bot.real)
    rb_im = np.ascontiguousarray(r_bot.imag)
    tabf = np.ascontiguousarray(tab).reshape(-1)
    nv = tab.shape[1]
    gtab = _beam_table(g_front, g_back)
    ng, ilf, nbk, ilb, lob = _beam_scalars(g_front, g_back, lo_front, lo_back)
    chunk = 256
    for q in nb.prange((ns + chunk - 1) // chunk):
        k0 = q * chunk
        n = min(ns, k0 + chunk) - k0
        hbuf = np.empty(nmed + 1)
        cbuf = np.empty(2)
        fix = np.zeros(n, dtype=np.bool_)
        wk = np.empty((10, n))
        for m in range(nt):
            if not _transmit_image(k0, sx, sy, sz, smed, samp, m, img, c, alpha, tabf, nv,
                                   rt_re, rt_im, rb_re, rb_im, bore, gtab, lo_front, lob,
                                   ilf, ilb, ng, nbk, tau_out, amp_out, fix, wk):
                continue
            for j in range(n):
                if not fix[j]:
                    continue
                k = k0 + j
                transmit_leg(k, m, img, sx, sy, sz, smed, samp, c, rho_m, delta, alpha,
                             z_top, tab, r_top, r_bot, sig, bore, g_front, g_back,
                             lo_front, lo_back, hbuf, cbuf, tau_out, amp_out)


@nb.njit(parallel=True, cache=True, fastmath=True, error_model="numpy")
def accumulate_fast_kernel(pts, legs_t, paths, medium, beam, win, n_buf, n_blocks):
    """Pass 2 as :func:`~sim_device.synthesis_reference.accumulate_kernel` (same echoes,
    same delays, amplitudes and phases to float64 rounding), scatterer-parallel into
    per-thread float32 buffers (module docstring).

    ``paths.zmax[a, b]``: deepest scatterer (m below the interface) for which path (a, b)
    is synthesised (finite: the kernel is compiled with fastmath; the level cut-off of
    :mod:`sim_device.fidelity`). Returns (buffer (n_channels, n_buf) complex128, echoes
    added per block)."""
    # the bundles unpacked here, outside the loops, which see plain arrays only
    # (docs/simulator.md, "Bundled kernels and speed")
    sx, sy, sz, smed = pts
    tau_t, amp_t = legs_t
    img, allowed, zmax = paths
    c, rho_m, delta, alpha, z_top, tab, r_top, r_bot, sig = medium
    bore, g_front, g_back, lo_front, lo_back = beam
    sign, t_lo, t_hi, t_buf0, fs = win
    nch = img.shape[0]
    nr = img.shape[1]
    nt = tau_t.shape[1]
    ns = sx.size
    nmed = c.size
    # element-image rows transposed: imt[b, column, ch]
    imt = np.empty((nr, 6, nch))
    for ch in range(nch):
        for b in range(nr):
            for j in range(6):
                imt[b, j, ch] = img[ch, b, j]
    itab = _interface_tables(r_top, r_bot)
    ms = _receive_scalars(c, alpha, bore, g_front, g_back, lo_front, lo_back)
    # the two-medium table flattened, and one beam table: the main lobe, the back lobe
    # (if any) and a pair of zeros (no gain)
    tabf = np.ascontiguousarray(tab).reshape(-1)
    nv = tab.shape[1]
    gtab = _beam_table(g_front, g_back)
    # per block: (channel, sample) with the real and imaginary parts interleaved, so
    # that an echo's four taps are eight neighbouring floats
    bufs = np.zeros((n_blocks, nch, 2 * n_buf), dtype=np.float32)
    counts = np.zeros(n_blocks, dtype=np.int64)
    chunk = 64
    n_chunks = (ns + chunk - 1) // chunk
    for blk in nb.prange(n_blocks):
        hbuf = np.empty(nmed + 1)
        cbuf = np.empty(2)
        need = np.zeros(nr, dtype=np.bool_)
        fix = np.zeros(nch, dtype=np.bool_)
        wk = np.empty((11, nch))
        tr = wk[8]              # the receive legs: delay, amplitude (re, im)
        ar_re = wk[9]
        ar_im = wk[10]
        e_i = np.empty(nch, dtype=np.int32)
        e_w = np.empty((nch, 4), dtype=np.float32)
        e_re = np.empty(nch, dtype=np.float32)
        e_im = np.empty(nch, dtype=np.float32)
        e_ok = np.empty(nch, dtype=np.bool_)
        buf = bufs[blk]
        n_add = 0
        for q in range(blk, n_chunks, n_blocks):
            for k in range(q * chunk, min(ns, (q + 1) * chunk)):
                any_need = False
                zk = sz[k]
                for b in range(nr):
                    need[b] = False
                for a in range(nt):
                    if amp_t[k, a] != 0.0:
                        for b in range(nr):
                            if allowed[a, b] and zk <= zmax[a, b]:
                                need[b] = True
                                any_need = True
                if not any_need:
                    continue
                xk = sx[k]
                yk = sy[k]
                mk = smed[k]
                for b in range(nr):
                    if not need[b]:
                        continue
                    if _receive_legs(xk, yk, zk, mk, b, imt, ms, tabf, nv, itab, gtab,
                                     sig, fix, wk):
                        for ch in range(nch):
                            if not fix[ch]:
                                continue
                            tau_r, a_r, cg = leg_body(
                                imt[b, IMG_X, ch], imt[b, IMG_Y, ch], imt[b, IMG_H, ch],
                                imt[b, IMG_DIR, ch], imt[b, IMG_RS, ch],
                                int(imt[b, IMG_NB, ch]), xk, yk, zk, mk, True, c, rho_m,
                                delta, alpha, z_top, tab, r_top, r_bot, bore, g_front,
                                g_back, lo_front, lo_back, hbuf, cbuf)
                            if mk == MED_INTERFACE and a_r != 0.0:
                                a_r *= _interp(sig, cg)
                            tr[ch] = tau_r
                            ar_re[ch] = a_r.real
                            ar_im[ch] = a_r.imag
                    for a in range(nt):
                        if not allowed[a, b] or zk > zmax[a, b]:
                            continue
                        a_t = amp_t[k, a]
                        if a_t == 0.0:
                            continue
                        t_t = tau_t[k, a]
                        at_re = a_t.real
                        at_im = a_t.imag
                        # echoes of all channels (vectorisable) ...
                        for ch in range(nch):
                            tau = t_t + tr[ch]
                            co, si = cis_cycles32(sign * tau)
                            pr = at_re * ar_re[ch] - at_im * ar_im[ch]
                            pi = at_re * ar_im[ch] + at_im * ar_re[ch]
                            u = (tau - t_buf0) * fs
                            u = min(max(u, 1.0), n_buf - 3.0)
                            u1 = np.floor(u)          # a float: the loop vectorises
                            w0, w1, w2, w3 = lagrange4(u - u1)
                            e_i[ch] = u1
                            e_w[ch, 0] = w0
                            e_w[ch, 1] = w1
                            e_w[ch, 2] = w2
                            e_w[ch, 3] = w3
                            e_re[ch] = pr * co - pi * si
                            e_im[ch] = pr * si + pi * co
                            e_ok[ch] = ((tau > t_lo) & (tau < t_hi)
                                        & ((ar_re[ch] != 0.0) | (ar_im[ch] != 0.0)))
                        # ... added at their fractional delays
                        for ch in range(nch):
                            if not e_ok[ch]:
                                continue
                            re = e_re[ch]
                            im = e_im[ch]
                            _add_taps(buf, ch, 2 * e_i[ch] - 2, re, im, e_w[ch, 0],
                                      e_w[ch, 1], e_w[ch, 2], e_w[ch, 3])
                            n_add += 1
        counts[blk] = n_add
    out = np.zeros((nch, n_buf), dtype=np.complex128)
    for ch in nb.prange(nch):
        for blk in range(n_blocks):
            for j in range(n_buf):
                out[ch, j] += complex(bufs[blk, ch, 2 * j], bufs[blk, ch, 2 * j + 1])
    return out, counts


#: :func:`accumulate_fast_kernel` compiled without threads, for pings with few scatterers
#: (a scene of points in water): a parallel region's start costs more than their echoes
accumulate_fast_serial_kernel = nb.njit(cache=True, fastmath=True, error_model="numpy")(
    renamed(accumulate_fast_kernel.py_func, "accumulate_fast_serial_kernel"))


def accumulate_fast(p2: Pass2, n_buf: int, n_blocks: int):
    """:func:`accumulate_fast_kernel` of pass 2's bundles into ``n_blocks`` per-thread
    buffers of ``n_buf`` samples. Returns (buffer (n_channels, n_buf) complex128, echoes
    added per block)."""
    return accumulate_fast_kernel(*p2, n_buf, n_blocks)


def accumulate_fast_serial(p2: Pass2, n_buf: int, n_blocks: int = 1):
    """:func:`accumulate_fast` without threads (:data:`SERIAL_BELOW`)."""
    return accumulate_fast_serial_kernel(*p2, n_buf, n_blocks)
