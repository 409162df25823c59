"""Several pings per GPU launch (svss_proc.imaging.gpu_batch) add what the one-ping
kernels add: for every option combination of tests/test_gpu_kernel.py (interpolation,
precision, delay model), three pings from three projector positions, each into its own
along-track range of the tile (one range the whole tile, two cutting through it), two
pings per launch (a full batch, then the rest launched by ``flush``), against the CPU
kernel called ping by ping: images and update counts. Under numba's CUDA simulator on
every machine, and on a real GPU where one is present."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest

from tests.test_gpu_kernel import ROOT, case_inputs, kernel_call, requires_cuda, subprocess_env

#: (projector along-track shift in m, along-track range ia0..ia1 of the 4 planes)
PINGS = ((0.0, 0, 4), (0.25, 1, 3), (-0.3, 2, 4))

SCRIPT = textwrap.dedent("""
    import sys, numpy as np
    from numba import cuda
    from tests.test_gpu_batch import calls
    from tests.test_gpu_kernel import case_inputs
    from svss_proc.imaging.gpu_batch import PingBatcher
    from svss_proc.imaging.gpu_kernel import device_counter
    out = {}
    batcher = PingBatcher(int(sys.argv[2]))
    only = sys.argv[3].split(",") if len(sys.argv) > 3 else None
    for name, (kd, geo, kw) in case_inputs().items():
        if only is not None and name not in only:
            continue
        re = cuda.to_device(np.zeros(geo["shape"], kd.dtype))
        im = cuda.to_device(np.zeros(geo["shape"], kd.dtype))
        count = device_counter()
        # a ring slot held with other planes (a constant), so that no ping's slot is
        # its place in the launch: the kernel must read the planes through the slot
        held = batcher._claim(kd.planes.re.shape, kd.dtype)
        ring = batcher._ring
        ring.staged.put(held, np.full((2,) + kd.planes.re.shape, 1e3, kd.dtype))
        for args, gating in calls(re, im, kd, geo, kw):
            assert batcher.run_ping(*args, gating=gating, count=count) is None
        batcher.flush(re)
        ring.drop(held)
        out[name] = re.copy_to_host() + 1j * im.copy_to_host()
        out[name + "_n"] = count.copy_to_host()
    out["launches"] = np.array([batcher.launches, batcher.pings])
    np.savez(sys.argv[1], **out)
""")


def calls(re, im, kd, geo, kw):
    """The case's three pings as kernel front-door calls."""
    from svss_proc.imaging.kernel_args import ImageSlice
    for shift, ia0, ia1 in PINGS:
        g = dict(geo, tx=geo["tx"] + [shift, 0.0, 0.0], rx=geo["rx"] + [shift, 0.0, 0.0])
        (out, kd_, array, delays), gating = kernel_call(re, im, kd, g, kw)
        yield (ImageSlice(out.re, out.im, out.axes, ia0, ia1), kd_, array, delays), gating


def _cpu(only=None):
    """The CPU kernel's images and counts of the cases (``only`` these: each
    combination is a kernel of its own to compile, a minute or more on a cold cache)."""
    from svss_proc.imaging.cpu_kernel import run_ping
    res = {}
    for name, (kd, geo, kw) in case_inputs().items():
        if only is not None and name not in only:
            continue
        re = np.zeros(geo["shape"], kd.dtype)
        im = np.zeros(geo["shape"], kd.dtype)
        n = sum(run_ping(*args, gating=gating) for args, gating in calls(re, im, kd, geo, kw))
        res[name] = (re + 1j * im, n)
    return res


#: the combinations compiled on a real GPU (each a kernel of its own, compiled in seconds):
#: the default setting, and the other interpolations, precision and delay models once
REAL_GPU_CASES = ("linear-float32-table", "cubic-float64-exact", "nearest-float32-straight")


def _run(tmp_path, simulator: bool, per_launch: int = 2, only=None):
    out = tmp_path / "batch.npz"
    extra = [] if only is None else [",".join(only)]
    r = subprocess.run([sys.executable, "-c", SCRIPT, str(out), str(per_launch), *extra],
                       cwd=ROOT,
                       env=subprocess_env(simulator), capture_output=True, text=True,
                       timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    return np.load(out)


def _compare(got, per_launch: int, only=None):
    cpu = _cpu(only)
    n_cases = len(cpu)
    # two launches per case (a full batch of 2, then the third ping by flush)
    assert got["launches"].tolist() == [n_cases * -(-len(PINGS) // per_launch),
                                        n_cases * len(PINGS)]
    for name, (img, n) in cpu.items():
        assert n > 0, name
        assert int(got[name + "_n"][0]) == n, name
        tol = 1e-4 if "float32" in name else 1e-9     # as test_gpu_kernel
        np.testing.assert_allclose(got[name], img, rtol=0, atol=tol * np.abs(img).max(),
                                   err_msg=name)


#: under the simulator (minutes a combination on two loaded cores): the shipped setting
SIMULATOR_CASES = ("linear-float32-table",)


@pytest.mark.slow
def test_gpu_batches_under_the_simulator_add_what_the_cpu_kernel_adds(tmp_path):
    """The shipped combination. Batching is the same code for all of them; the others
    differ only in the kernel's compile-time branches, which tests/test_gpu_kernel.py
    runs for every combination one ping at a time, a real GPU batched in the three of
    REAL_GPU_CASES and the extended test below batched in all."""
    _compare(_run(tmp_path, simulator=True, only=SIMULATOR_CASES), 2, SIMULATOR_CASES)


@pytest.mark.extended        # every combination: eight minutes under the simulator
def test_gpu_batches_under_the_simulator_in_every_combination(tmp_path):
    _compare(_run(tmp_path, simulator=True), 2)


@requires_cuda
def test_real_gpu_batches_add_what_the_cpu_kernel_adds(tmp_path):
    _compare(_run(tmp_path, simulator=False, only=REAL_GPU_CASES), 2, REAL_GPU_CASES)
