"""Gather 16 samples of a tap plane from a window of nearby samples with permutes (numba).

The backprojection's depth loop reads, for one channel and 16 consecutive voxel depths,
16 samples whose indices lie within a few tens of samples of each other (the two-way
delay grows by about 2 dz / c per voxel: ~1.7 samples at 2 cm and 16 us). Hardware
gathers cost one load per lane; here the lanes are served from contiguous loads and
register permutes when the indices allow, by the widest path the *target* CPU has:

- ``avx512``: the 16 lanes from two 16-float loads and one ``vpermt2ps`` when every index
  lies in ``[i_0, i_0 + 32)`` (``i_0`` the first lane's index);
- ``avx2``: each half of 8 lanes from two 8-float loads, two ``vpermps`` and a blend when
  its indices lie in ``[j_0, j_0 + 16)`` (``j_0`` the half's first index), both halves;
- ``loads``: one load per lane (float64 planes always; a window past the row's end; indices
  that do not fit; CPUs with neither).

The result never depends on the path taken. The target is numba's: the host CPU, or
``NUMBA_CPU_NAME`` / ``NUMBA_CPU_FEATURES`` where set (a cache built for another machine);
``SVSS_WINDOW_GATHER`` = ``avx512``, ``avx2`` or ``loads`` forces a narrower path for
benchmarks (``benchmarks/bench_isa.py``); it must be set before the kernels compile, and
with a cache folder of its own (numba's cache does not know it). :data:`PATH` says which
path the kernels were built with.

:func:`window_gather_1`, :func:`window_gather_2` and :func:`window_gather_4` handle tap
planes with 1, 2 and 4 taps (nearest, linear, cubic). Each has the signature

    window_gather_k(re, im, ch, idx, ioff, dst, doff, stride) -> 1 (permutes) or 0 (loads)

and writes, for each tap k and lane l < 16,

    dst[doff + k * stride + l]          = re[k, ch, idx[ioff + l]]
    dst[doff + (taps + k) * stride + l] = im[k, ch, idx[ioff + l]]

``re``/``im`` are C-contiguous (taps, channels, n) float32 or float64 arrays (float64
always takes the lane-by-lane path), ``idx`` a uint32 array, ``dst`` a 1-D array of the
planes' dtype. Indices are not bounds-checked: the caller keeps them in ``[0, n)``.
"""

from __future__ import annotations

import os

from llvmlite import ir
from numba import types
from numba.core import cgutils, config
from numba.core.codegen import get_host_cpu_features
from numba.extending import intrinsic

LANES = 16                  # lanes per call (one zmm of float32)
WINDOW = 2 * LANES          # samples reachable by one two-register AVX-512 permute
HALF = LANES // 2           # lanes per AVX2 half (one ymm of float32)
HALF_WINDOW = 2 * HALF      # samples reachable by a half's two-register AVX2 permute
PATHS = ("avx512", "avx2", "loads")
#: the environment variable that forces a narrower path (benchmarks)
PATH_VARIABLE = "SVSS_WINDOW_GATHER"


def target_features() -> frozenset[str]:
    """The CPU features numba compiles for: ``NUMBA_CPU_FEATURES`` where set, else the
    host's (LLVM's names: ``avx512f``, ``avx2``, ``fma``, ...)."""
    numba_features = config.CPU_FEATURES        # numba's setting, not this project's:
    if numba_features is None:                  # numba then compiles for the host's
        numba_features = get_host_cpu_features()
    return frozenset(f[1:] for f in str(numba_features).split(",") if f.startswith("+"))


def choose_path(features: frozenset[str], forced: str | None) -> str:
    """The widest path ``features`` allow, or ``forced`` (one of :data:`PATHS`, which
    the features must allow)."""
    best = "avx512" if "avx512f" in features else "avx2" if "avx2" in features else "loads"
    if forced in (None, "", "auto"):
        return best
    if forced not in PATHS:
        raise ValueError(f"{PATH_VARIABLE}={forced!r}: expected auto or one of "
                         f"{', '.join(PATHS)}")
    if PATHS.index(forced) < PATHS.index(best):
        target = f"NUMBA_CPU_NAME={config.CPU_NAME}" if config.CPU_NAME else "the host"
        raise ValueError(f"{PATH_VARIABLE}={forced!r}: the target CPU ({target}) lacks "
                         f"it; widest is {best!r}")
    return forced


#: numba's environment for an AVX2-only target (Haswell and later, AMD Zen 1-3: AVX2 and
#: FMA, no AVX-512), for tests and benchmarks on a machine that has AVX-512. Name the
#: features too: without NUMBA_CPU_FEATURES numba adds the host's, AVX-512 included.
AVX2_TARGET = {"NUMBA_CPU_NAME": "haswell",
               "NUMBA_CPU_FEATURES": "+64bit,+avx,+avx2,+bmi,+bmi2,+cmov,+cx16,+cx8,+f16c,"
                                     "+fma,+fxsr,+lzcnt,+mmx,+movbe,+pclmul,+popcnt,+sse,"
                                     "+sse2,+sse3,+sse4.1,+sse4.2,+ssse3,+xsave"}

#: the path compiled into the kernels of this process
PATH = choose_path(target_features(), os.environ.get(PATH_VARIABLE))
HAS_AVX512 = PATH == "avx512"

_I1, _I32, _I64 = ir.IntType(1), ir.IntType(32), ir.IntType(64)
_V_I32 = ir.VectorType(_I32, LANES)
_V8_I32 = ir.VectorType(_I32, HALF)


def _splat(builder, value, vtype):
    """A vector of ``vtype`` with every lane ``value``."""
    n = vtype.count
    first = builder.insert_element(ir.Constant(vtype, ir.Undefined), value, _I32(0))
    return builder.shuffle_vector(first, ir.Constant(vtype, ir.Undefined),
                                  ir.Constant(ir.VectorType(_I32, n), [0] * n))


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

        def avx2_halves():
            """Each half of 8 lanes from a 16-sample window: two 8-float loads, two
            ``vpermps`` (the index's low 3 bits) and a blend on its bit 3."""
            v8 = ir.VectorType(elem, HALF)
            halves = []
            fits = ir.Constant(_I1, 1)
            all_of = cgutils.get_or_insert_function(
                builder.module, ir.FunctionType(_I1, [ir.VectorType(_I1, HALF)]),
                "llvm.vector.reduce.and.v8i1")
            for h in range(2):
                ivh = builder.shuffle_vector(iv, ir.Constant(_V_I32, ir.Undefined),
                                             ir.Constant(_V8_I32, list(range(h * HALF,
                                                                             (h + 1) * HALF))))
                b = builder.extract_element(ivh, _I32(0))
                relh = builder.sub(ivh, _splat(builder, b, _V8_I32))
                inside = builder.icmp_unsigned("<", relh,
                                               ir.Constant(_V8_I32, [HALF_WINDOW] * HALF))
                b64 = builder.zext(b, _I64)
                fits = builder.and_(fits, builder.and_(
                    builder.call(all_of, [inside]),
                    builder.icmp_signed("<=", builder.add(b64, _I64(HALF_WINDOW)), nt)))
                upper = builder.icmp_unsigned(">=", relh, ir.Constant(_V8_I32, [HALF] * HALF))
                halves.append((b64, relh, upper))
            permute = cgutils.get_or_insert_function(
                builder.module, ir.FunctionType(v8, [v8, _V8_I32]), "llvm.x86.avx2.permps")
            vptr = v8.as_pointer()
            with builder.if_else(fits, likely=True) as (window, loads):
                with window:
                    for part, arr in enumerate((a_re, a_im)):
                        for p_row, p_dst in rows(part, arr):
                            for h, (b64, relh, upper) in enumerate(halves):
                                p0 = builder.gep(p_row, [b64])
                                lo = builder.load(builder.bitcast(p0, vptr), align=4)
                                hi = builder.load(builder.bitcast(
                                    builder.gep(p0, [_I64(HALF)]), vptr), align=4)
                                out = builder.select(upper, builder.call(permute, [hi, relh]),
                                                     builder.call(permute, [lo, relh]))
                                builder.store(out, builder.bitcast(
                                    builder.gep(p_dst, [_I64(h * HALF)]), vptr), align=4)
                with loads:
                    lane_by_lane()
            return builder.zext(fits, _I64)

        if not is_f32 or PATH == "loads":
            lane_by_lane()
            return _I64(0)
        if PATH == "avx2":
            return avx2_halves()
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
