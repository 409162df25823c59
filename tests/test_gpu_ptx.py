"""The GPU path's new kernels (the conditioning, the coverage count, the zeroing of a
tile's volumes) compile for an H100 (sm_90) with the argument types the imager gives
them: numba's CUDA typing and lowering, which the CUDA simulator (it runs the kernels as
Python) never exercises. Needs NVVM (libnvvm, found here through the CUDA toolkit), not a
GPU or its driver; skipped where there is no NVVM. In a subprocess without the
simulator. (The backprojection kernels call min() and max(), whose CUDA overloads
numba compiles only with a driver: their PTX is checked on a GPU,
tests/test_gpu_float32.py, and their batch path by tests/test_gpu_batch.py there.)"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

from tests.test_gpu_kernel import ROOT, subprocess_env

SCRIPT = textwrap.dedent("""
    import json, re, sys
    from collections import Counter
    from numba import cuda
    from numba.core import types
    try:
        cuda.compile_ptx(lambda a: None, (types.float64[::1],), cc=(9, 0))
    except Exception as exc:                     # no NVVM here
        print(json.dumps({"skip": f"{type(exc).__name__}: {exc}"[:300]}))
        sys.exit(0)
    # numba compiles each device function a kernel calls for the current device's
    # compute capability, which asks the driver: there is none here, so name the H100's
    import types as _t
    import numba.cuda.dispatcher as _disp
    _disp.get_current_device = lambda: _t.SimpleNamespace(compute_capability=(9, 0))
    from svss_proc.imaging import gpu_conditioning, gpu_coverage, gpu_kernel
    i64, f64, f32, u16 = types.int64, types.float64, types.float32, types.uint16
    out = {}

    def ptx(name, fn, sig):
        text, _ = cuda.compile_ptx(fn.py_func, sig, cc=(9, 0))
        ops = Counter(re.findall(r"^\\s+([a-z]+(?:\\.[a-z0-9]+)*)", text, re.M))
        out[name] = {"lines": text.count("\\n"),
                     "f64": sum(v for k, v in ops.items() if "f64" in k),
                     "f32": sum(v for k, v in ops.items() if "f32" in k)}

    for ring_t, tag in ((f32, "float32"), (f64, "float64")):
        ptx("condition_" + tag, gpu_conditioning._condition,
            (types.Array(types.int32, 2, "C"), i64, types.Array(f64, 2, "C"),
             types.Array(f64, 2, "C"), types.Array(i64, 1, "C"), types.Array(f64, 1, "C"),
             types.Array(f64, 1, "C"), types.Array(ring_t, 5, "C"), i64))
    ptx("coverage", gpu_coverage._accumulate,
        (types.Array(u16, 3, "C"), types.Array(u16, 3, "C"), types.Array(f64, 1, "C"),
         types.Array(f64, 1, "C"), types.Array(f64, 1, "C"), types.Array(f64, 2, "C"),
         types.Array(i64, 1, "C"), i64, i64, types.Array(f64, 1, "C")))
    for t, tag in ((f32, "float32"), (u16, "uint16")):
        ptx("zero_" + tag, gpu_kernel._zero, (types.Array(t, 1, "C"),))
    print(json.dumps(out))
""")


def test_the_gpu_paths_kernels_compile_for_sm90():
    res = subprocess.run([sys.executable, "-c", SCRIPT], cwd=ROOT,
                         env=subprocess_env(False), capture_output=True, text=True,
                         timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    out = json.loads(res.stdout.strip().splitlines()[-1])
    if "skip" in out:
        pytest.skip(f"no NVVM to compile PTX: {out['skip']}")
    for name in ("condition_float32", "condition_float64", "coverage", "zero_float32",
                 "zero_uint16"):
        assert out[name]["lines"] > 20, (name, out[name])
    # the conditioning sums in float64 whatever the ring's precision; a float32 ring
    # gets its planes converted once (cvt.rn.f32.f64), not summed in float32
    assert out["condition_float32"]["f64"] > 0 and out["condition_float64"]["f64"] > 0
