"""The numba-cuda kernel computes the backprojection sum: against the float64 direct sum
of tests/references.py (independent of the kernels: the CPU and GPU kernels compile the
same scalar functions from kernel_math, so agreeing with each other cannot catch an
error there, e.g. in the exact Fermat solve) and against the CPU kernel. Under numba's
CUDA simulator on every machine (small grids, in a subprocess because the simulator
must be chosen before numba.cuda is imported), and on a real GPU where one is present."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
CW, CS = 1500.0, 1767.0          # water and sediment sound speeds, m/s

SCRIPT = textwrap.dedent("""
    import sys, numpy as np
    from numba import cuda
    from tests.test_gpu_kernel import case_inputs, kernel_call
    from svss_proc.imaging.gpu_kernel import run_ping_gpu
    out = {}
    for name, (kd, geo, kw) in case_inputs().items():
        re = cuda.to_device(np.zeros(geo["shape"], kd.dtype))
        im = cuda.to_device(np.zeros(geo["shape"], kd.dtype))
        args, gating = kernel_call(re, im, kd, geo, kw)
        n = run_ping_gpu(*args, gating=gating)
        out[name] = re.copy_to_host() + 1j * im.copy_to_host()
        out[name + "_n"] = np.array(n)
    np.savez(sys.argv[1], **out)
""")


def case_inputs():
    """Small random problems, one per option combination."""
    from svss_daq.ping import SampleAxis
    from svss_proc.conditioning import Conditioned
    from svss_proc.imaging.delays import build_table
    from svss_proc.imaging.kernel_args import DelayModel, prepare
    rng = np.random.default_rng(11)
    nch, nt = 6, 260
    data = (rng.normal(size=(nch, nt)) + 1j * rng.normal(size=(nch, nt))).astype(np.complex64)
    geo = {"tx": np.array([0.1, -0.1, -2.0]),
           "rx": np.column_stack([rng.uniform(-0.4, 0.4, nch), rng.uniform(-0.5, 0.5, nch),
                                  np.full(nch, -2.0)]),
           "along": np.linspace(-0.8, 0.8, 4), "cross": np.linspace(-0.4, 0.4, 3),
           "depth": np.linspace(0.0, 0.8, 3)}
    geo["shape"] = (4, 3, 3)
    geo["data"], geo["t0"], geo["dt"], geo["fc"] = data, 1e-3, 16e-6, 27.5e3
    table = build_table(2.0, 3.0, -0.1, 1.0, 0.01, CW, CS)
    cases = {}
    for interp in ("nearest", "linear", "cubic"):
        for prec in (np.float32, np.float64):
            for mode in ("straight", "table", "exact"):
                cond = Conditioned.from_baseband(data, SampleAxis(geo["t0"], geo["dt"], nt),
                                                 geo["fc"])
                kd = prepare(cond, interp, prec)
                kw = dict(bore=np.array([0.0, 0.0, 1.0]), cos_tx=0.9, cos_rx=0.64,
                          gating=True, apod=rng.uniform(0.5, 1.5, nch),
                          delays=DelayModel(mode, CW, CS, table))
                cases[f"{interp}-{prec.__name__}-{mode}"] = (kd, geo, kw)
    return cases


def kernel_call(re, im, kd, geo, kw):
    """A case as the kernel front doors take it: ((image slice, tap planes, array,
    delays), gating)."""
    from svss_proc.imaging.kernel_args import ImageSlice, PingArray, VoxelAxes
    axes = VoxelAxes(geo["along"], geo["cross"], geo["depth"])
    array = PingArray(geo["tx"], geo["rx"], kw["bore"], kw["cos_tx"], kw["cos_rx"],
                      kw["apod"])
    return (ImageSlice(re, im, axes, 0, geo["shape"][0]), kd, array, kw["delays"]), \
        kw["gating"]


def cpu_results():
    from svss_proc.imaging.cpu_kernel import run_ping
    out = {}
    for name, (kd, geo, kw) in case_inputs().items():
        re = np.zeros(geo["shape"], kd.dtype)
        im = np.zeros(geo["shape"], kd.dtype)
        args, gating = kernel_call(re, im, kd, geo, kw)
        n = run_ping(*args, gating=gating)
        out[name] = (re + 1j * im, n)
    return out


def reference_results():
    """The same problems summed by the float64 direct sum: (image, terms summed)."""
    from tests.references import direct_sum
    out = {}
    for name, (_, geo, kw) in case_inputs().items():
        interp, _, mode = name.split("-")
        out[name] = direct_sum(geo["data"].astype(np.complex128), geo["t0"], geo["dt"],
                               geo["fc"], geo["tx"], geo["rx"], kw["bore"], kw["cos_tx"],
                               kw["cos_rx"], geo["along"], geo["cross"], geo["depth"],
                               kw["gating"], interp, mode, kw["apod"], CW, CS, count=True)
    return out


def subprocess_env(simulator: bool, environ=None) -> dict:
    """The environment of a GPU subprocess: the project root prepended to PYTHONPATH
    (never replacing it: on the GPU machine the packages live on PYTHONPATH), and the
    CUDA simulator chosen when asked."""
    env = dict(os.environ if environ is None else environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + ([env["PYTHONPATH"]]
                                                       if env.get("PYTHONPATH") else []))
    if simulator:
        env["NUMBA_ENABLE_CUDASIM"] = "1"
    return env


def test_subprocess_env_prepends_the_project_root():
    env = subprocess_env(False, {"PYTHONPATH": "/opt/site"})
    assert env["PYTHONPATH"] == os.pathsep.join([str(ROOT), "/opt/site"])
    assert subprocess_env(True, {})["PYTHONPATH"] == str(ROOT)
    assert subprocess_env(True, {})["NUMBA_ENABLE_CUDASIM"] == "1"


def _run_gpu(tmp_path, simulator: bool):
    env = subprocess_env(simulator)
    out = tmp_path / "gpu.npz"
    res = subprocess.run([sys.executable, "-c", SCRIPT, str(out)], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    return np.load(out)


def _compare(gpu):
    refs = reference_results()
    for name, (img, n) in cpu_results().items():
        ref, n_ref = refs[name]
        scale = np.abs(ref).max()
        # the cones keep most voxels and exclude some; every kept term is counted
        assert 0 < np.count_nonzero(ref) < ref.size and n_ref > ref.size, name
        # against the independent sum: float32 delays and phases carry ~1e-5 of a sample,
        # the table's bilinear look-up a small delay error (as in test_backprojection)
        tol = (1e-4 if "float32" in name else 1e-6) + (3e-3 if "table" in name else 0)
        np.testing.assert_allclose(gpu[name], ref, rtol=0, atol=tol * scale, err_msg=name)
        assert int(gpu[name + "_n"]) == n_ref, name
        # and against the CPU kernel, which shares the GPU's arithmetic
        tol = 1e-4 if "float32" in name else 1e-9
        np.testing.assert_allclose(gpu[name], img, rtol=0, atol=tol * np.abs(img).max(),
                                   err_msg=name)
        assert int(gpu[name + "_n"]) == n == n_ref, name


@pytest.mark.extended     # tests/test_gpu_float32.py runs the realistic case by default
def test_gpu_simulator_matches_direct_sum_and_cpu(tmp_path):
    _compare(_run_gpu(tmp_path, simulator=True))


def _has_gpu() -> bool:
    res = subprocess.run([sys.executable, "-c",
                          "from numba import cuda; print(cuda.is_available())"],
                         capture_output=True, text=True, timeout=120)
    return res.stdout.strip().endswith("True")


requires_cuda = pytest.mark.skipif(not _has_gpu(), reason="no CUDA GPU on this machine")


@requires_cuda
def test_real_gpu_matches_direct_sum_and_cpu(tmp_path):
    _compare(_run_gpu(tmp_path, simulator=False))
