"""Gather 16 samples of a tap plane from a 32-sample window with one permute (numba).

The backprojection's depth loop reads, for one channel and 16 consecutive voxel depths,
16 samples whose indices lie within a few tens of samples of each other (the two-way
delay grows by about 2 dz / c per voxel). Hardware gathers cost one load per lane; here
the 16 lanes are served from two contiguous 16-float loads and one AVX-512
``vpermt2ps`` whenever every index lies in ``[i_0, i_0 + 32)`` (``i_0`` the first lane's
index) and the window is inside the row. Otherwise, and on CPUs without AVX-512, the
lanes are loaded one by one, so the result never depends on the path taken.

:func:`window_gather_1`, :func:`window_gather_2` and :func:`window_gather_4` handle tap
planes with 1, 2 and 4 taps (nearest, linear, cubic). Each has the signature

    window_gather_k(re, im, ch, idx, ioff, dst, doff, stride) -> 1 (window) or 0 (loads)

and writes, for each tap k and lane l < 16,

    dst[doff + k * stride + l]          = re[k, ch, idx[ioff + l]]
    dst[doff + (taps + k) * stride + l] = im[k, ch, idx[ioff + l]]

``re``/``im`` are C-contiguous (taps, channels, n) float32 or float64 arrays (float64
always takes the lane-by-lane path), ``idx`` a uint32 array, ``dst`` a 1-D array of the
planes' dtype. Indices are not bounds-checked: the caller keeps them in ``[0, n)``.
"""

from __future__ import annotations

import llvmlite.binding as llvm_binding
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

LANES = 16                  # lanes per call (one zmm of float32)
WINDOW = 2 * LANES          # samples reachable by one two-register permute
HAS_AVX512 = bool(llvm_binding.get_host_cpu_features().get("avx512f", False))

_I1, _I32, _I64 = ir.IntType(1), ir.IntType(32), ir.IntType(64)
_V_I32 = ir.VectorType(_I32, LANES)


def _splat(builder, value, vtype):
    """A vector of ``vtype`` with every lane ``value``."""
    first = builder.insert_element(ir.Constant(vtype, ir.Undefined), value, _I32(0))
    return builder.shuffle_vector(first, ir.Constant(vtype, ir.Undefined),
                                  ir.Constant(_V_I32, [0] * LANES))


def _valid(re, im, idx, dst):
    return (isinstance(re, types.Array) and re.ndim == 3 and re.layout == "C"
            and re.dtype in (types.float32, types.float64) and im == re
            and isinstance(idx, types.Array) and idx.ndim == 1 and idx.dtype == types.uint32
            and isinstance(dst, types.Array) and dst.ndim == 1 and dst.dtype == re.dtype)


def _codegen(ntaps):
    def codegen(context, builder, sig, args):
        a_re, a_im = (context.make_array(sig.args[i])(context, builder, args[i]) for i in (0, 1))
        a_idx = context.make_array(sig.args[3])(context, builder, args[3])
        a_dst = context.make_array(sig.args[5])(context, builder, args[5])
        ch, ioff, doff, stride = (context.cast(builder, args[i], sig.args[i], types.int64)
                                  for i in (2, 4, 6, 7))
        _, nch, nt = cgutils.unpack_tuple(builder, a_re.shape, 3)
        is_f32 = sig.args[0].dtype == types.float32
        elem = ir.FloatType() if is_f32 else ir.DoubleType()
        v_elem = ir.VectorType(elem, LANES)
        p_idx = builder.gep(a_idx.data, [ioff])
        iv = builder.load(builder.bitcast(p_idx, _V_I32.as_pointer()), align=4)
        base = builder.extract_element(iv, _I32(0))
        base64 = builder.zext(base, _I64)
        rel = builder.sub(iv, _splat(builder, base, _V_I32))

        def rows(part, arr):
            """(tap k, source row pointer, destination pointer) for one plane set."""
            for k in range(ntaps):
                row = builder.mul(builder.add(builder.mul(_I64(k), nch), ch), nt)
                dst_at = builder.add(builder.mul(_I64(part * ntaps + k), stride), doff)
                yield builder.gep(arr.data, [row]), builder.gep(a_dst.data, [dst_at])

        def lane_by_lane():
            for part, arr in enumerate((a_re, a_im)):
                for p_row, p_dst in rows(part, arr):
                    for lane in range(LANES):
                        j = builder.zext(builder.extract_element(iv, _I32(lane)), _I64)
                        builder.store(builder.load(builder.gep(p_row, [j])),
                                      builder.gep(p_dst, [_I64(lane)]))

        if not (is_f32 and HAS_AVX512):
            lane_by_lane()
            return _I64(0)
        in_window = builder.icmp_unsigned("<", rel, ir.Constant(_V_I32, [WINDOW] * LANES))
        all_of = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(_I1, [ir.VectorType(_I1, LANES)]),
            "llvm.vector.reduce.and.v16i1")
        fits = builder.and_(builder.call(all_of, [in_window]),
                            builder.icmp_signed("<=", builder.add(base64, _I64(WINDOW)), nt))
        permute = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(v_elem, [v_elem, _V_I32, v_elem]),
            "llvm.x86.avx512.vpermi2var.ps.512")
        vptr = v_elem.as_pointer()
        with builder.if_else(fits, likely=True) as (window, loads):
            with window:
                for part, arr in enumerate((a_re, a_im)):
                    for p_row, p_dst in rows(part, arr):
                        p0 = builder.gep(p_row, [base64])
                        lo = builder.load(builder.bitcast(p0, vptr), align=4)
                        hi = builder.load(builder.bitcast(builder.gep(p0, [_I64(LANES)]), vptr),
                                          align=4)
                        builder.store(builder.call(permute, [lo, rel, hi]),
                                      builder.bitcast(p_dst, vptr), align=4)
            with loads:
                lane_by_lane()
        return builder.zext(fits, _I64)
    return codegen


def _make(ntaps):
    @intrinsic
    def window_gather(typingctx, re, im, ch, idx, ioff, dst, doff, stride):
        if not _valid(re, im, idx, dst):
            return None
        return types.int64(re, im, ch, idx, ioff, dst, doff, stride), _codegen(ntaps)
    window_gather.__doc__ = f"Window gather for tap planes with {ntaps} tap(s) (module doc)."
    return window_gather


window_gather_1 = _make(1)
window_gather_2 = _make(2)
window_gather_4 = _make(4)
