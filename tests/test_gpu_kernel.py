"""The numba-cuda kernel computes the same sum as the CPU kernel: under numba's CUDA
simulator on every machine (small grids, in a subprocess because the simulator must be
chosen before numba.cuda is imported), and on a real GPU where one is present."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = textwrap.dedent("""
    import sys, numpy as np
    from numba import cuda
    from tests.test_gpu_kernel import case_inputs
    from svss_proc.imaging.gpu_kernel import run_ping_gpu
    out = {}
    for name, (kd, geo, kw) in case_inputs().items():
        re = cuda.to_device(np.zeros(geo["shape"], kd.dtype))
        im = cuda.to_device(np.zeros(geo["shape"], kd.dtype))
        n = run_ping_gpu(re, im, kd, geo["tx"], geo["rx"], geo["along"], geo["cross"],
                         geo["depth"], 0, geo["shape"][0], **kw)
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
    table = build_table(2.0, 3.0, -0.1, 1.0, 0.01, 1500.0, 1767.0)
    cases = {}
    for interp in ("nearest", "linear", "cubic"):
        for prec in (np.float32, np.float64):
            for mode in ("straight", "table", "exact"):
                cond = Conditioned.from_baseband(data, SampleAxis(1e-3, 16e-6, nt), 27.5e3)
                kd = prepare(cond, interp, prec)
                kw = dict(bore=np.array([0.0, 0.0, 1.0]), cos_tx=0.9, cos_rx=0.64,
                          gating=True, apod=rng.uniform(0.5, 1.5, nch),
                          delays=DelayModel(mode, 1500.0, 1767.0, table))
                cases[f"{interp}-{prec.__name__}-{mode}"] = (kd, geo, kw)
    return cases


def cpu_results():
    from svss_proc.imaging.cpu_kernel import run_ping
    out = {}
    for name, (kd, geo, kw) in case_inputs().items():
        re = np.zeros(geo["shape"], kd.dtype)
        im = np.zeros(geo["shape"], kd.dtype)
        n = run_ping(re, im, kd, geo["tx"], geo["rx"], geo["along"], geo["cross"],
                     geo["depth"], 0, geo["shape"][0], **kw)
        out[name] = (re + 1j * im, n)
    return out


def _run_gpu(tmp_path, simulator: bool):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    if simulator:
        env["NUMBA_ENABLE_CUDASIM"] = "1"
    out = tmp_path / "gpu.npz"
    res = subprocess.run([sys.executable, "-c", SCRIPT, str(out)], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    return np.load(out)


def _compare(gpu):
    for name, (img, n) in cpu_results().items():
        scale = np.abs(img).max()
        assert scale > 0 and n > 0
        tol = 1e-4 if "float32" in name else 1e-9
        np.testing.assert_allclose(gpu[name], img, rtol=0, atol=tol * scale, err_msg=name)
        assert int(gpu[name + "_n"]) == n, name


def test_gpu_simulator_matches_cpu(tmp_path):
    _compare(_run_gpu(tmp_path, simulator=True))


def _has_gpu() -> bool:
    res = subprocess.run([sys.executable, "-c",
                          "from numba import cuda; print(cuda.is_available())"],
                         capture_output=True, text=True, timeout=120)
    return res.stdout.strip().endswith("True")


requires_cuda = pytest.mark.skipif(not _has_gpu(), reason="no CUDA GPU on this machine")


@requires_cuda
def test_real_gpu_matches_cpu(tmp_path):
    _compare(_run_gpu(tmp_path, simulator=False))
