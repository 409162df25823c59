"""Voxels on a cone edge are gated alike by every kernel, precision and device.

The reference tile imaged on an H100 in float32 lost whole pings at dozens of voxels
(up to 8.6 % of the tile's peak) that the CPU kernels kept: on a straight track at a
steady speed the voxel lattice repeats relative to the array from ping to ping, and
voxels lie within 1e-8 of the projector cone's edge at every ping. Float32 geometry
(~6e-8 of a coordinate) cannot decide such voxels; the GPU's fused multiply-adds rounded
them outward and the CPU's rounding inward. The kernels now decide every voxel within
GATE_BAND of an edge in float64 from the float64 geometry.

Here voxels are placed 2e-9 rad inside and outside the projector's cone and a receiver's
cone (real array, real cone angles; the receiver cone narrowed for its case so that its
edge lies inside the projector's cone), 300 m from the origin with a rolled boresight,
and imaged one voxel per call by the float64 CPU kernel, the float32 CPU kernels (column
order, voxel order) and the float32 GPU kernel under the CUDA simulator: every kernel
must count the same voxel-channel updates as the float64 one, which must follow the
side of the edge each voxel was put on.
"""

from __future__ import annotations

import functools
import math
import pickle
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from svss_daq.geometry import array_geometry
from svss_daq.ping import SampleAxis
from svss_proc.conditioning import Conditioned
from svss_proc.imaging import cpu_kernel
from svss_proc.imaging.kernel_args import (EXACT, DelayModel, ImageSlice, PingArray,
                                          VoxelAxes, kernel_args, prepare)
from tests.test_gpu_kernel import ROOT, subprocess_env

EPS = 2e-9          # rad off the edge: f32 geometry can't see it, f64 arithmetic can
N_DIRECTIONS = 24   # azimuths around each cone
SIMULATOR_STRIDE = 3   # the GPU kernel (CUDA simulator) checked at every third of them
TX = np.array([300.0, 2.0, -2.2])      # far from the origin, 2.2 m above the interface


def _basis(bore):
    e1 = np.cross(bore, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(bore, e1)


def _on_cone(apex, bore, half, sign, rng):
    """Voxels at 3-5 m from ``apex`` on the cone of half angle half + sign * EPS."""
    e1, e2 = _basis(bore)
    th = half + sign * EPS
    out = []
    for phi in np.linspace(0, 2 * np.pi, N_DIRECTIONS, endpoint=False):
        d = math.cos(th) * bore + math.sin(th) * (math.cos(phi) * e1 + math.sin(phi) * e2)
        out.append(apex + rng.uniform(3.0, 5.0) * d)
    return np.array(out)


@pytest.fixture(scope="module")
def cases(hardware):
    """(name, voxel positions, receivers, kwargs): voxels inside (+) and outside (-)
    each edge, at the same azimuths and ranges."""
    geo = array_geometry(hardware.value)
    roll = math.radians(3.0)
    bore = np.array([0.0, -math.sin(roll), math.cos(roll)])
    rx = TX + geo.receivers - geo.projectors[0]
    cos_tx = math.cos(geo.projector_half_angle)
    out = []
    for side, sign in (("inside", -1), ("outside", +1)):
        vox = _on_cone(TX, bore, geo.projector_half_angle, sign, np.random.default_rng(1))
        out.append((f"projector-{side}", vox, rx,
                    dict(bore=bore, cos_tx=cos_tx, cos_rx=math.cos(geo.receiver_half_angle))))
        # receiver 7's cone, narrowed to 10 deg so that its edge is inside the projector's
        half = math.radians(10.0)
        vox = _on_cone(rx[7], bore, half, sign, np.random.default_rng(2))
        out.append((f"receiver-{side}", vox, rx,
                    dict(bore=bore, cos_tx=cos_tx, cos_rx=math.cos(half))))
    return out


def _planes(nch, dtype):
    rng = np.random.default_rng(5)
    nt = 1500                                    # 15 ms at 10 us: every delay in range
    data = (rng.normal(size=(nch, nt)) + 1j * rng.normal(size=(nch, nt))).astype(np.complex64)
    return prepare(Conditioned.from_baseband(data, SampleAxis(0.0, 1e-5, nt), 27.5e3),
                   "linear", dtype)


DELAYS = DelayModel("straight", 1500.0, 1500.0)


def _one(v):
    return VoxelAxes(np.array([v[0]]), np.array([v[1]]), np.array([v[2]]))


def _column(kd, rx, vox, kw):
    """Counts and values from the CPU column-order kernel (run_ping), one voxel a call."""
    n, val = [], []
    for v in vox:
        re = np.zeros((1, 1, 1), kd.dtype)
        im = np.zeros((1, 1, 1), kd.dtype)
        n.append(cpu_kernel.run_ping(ImageSlice(re, im, _one(v), 0, 1), kd,
                                     PingArray(TX, rx, **kw), DELAYS, gating=True))
        val.append(complex(re[0, 0, 0], im[0, 0, 0]))
    return np.array(n), np.array(val)


#: one compiled voxel-order kernel per setting for the module (each build compiles anew)
_voxel_kernel = functools.cache(cpu_kernel._make_voxel_kernel)


#: the voxel-order kernel's delays: exact, the specialisation the exact-delay tests
#: compile anyway (no kernel of its own on a cold cache); equal sound speeds, so the same
#: straight rays as DELAYS
EXACT_DELAYS = DelayModel("exact", 1500.0, 1500.0)


def _voxel_order(kd, rx, vox, kw):
    """Counts from the CPU voxel-order kernel (the GPU kernel's sum, kernel_math)."""
    kern = _voxel_kernel(kd.interp, EXACT, True, kd.halvings)
    n = []
    for v in vox:
        re = np.zeros((1, 1, 1), kd.dtype)
        im = np.zeros((1, 1, 1), kd.dtype)
        args = kernel_args(kd, PingArray(TX, rx, **kw), _one(v), EXACT_DELAYS)
        n.append(kern(re, im, args, 0, 1))
    return np.array(n)


GPU_SCRIPT = textwrap.dedent("""
    import pickle, sys, numpy as np
    from numba import cuda
    from svss_proc.imaging.gpu_kernel import run_ping_gpu
    from svss_proc.imaging.kernel_args import ImageSlice, VoxelAxes
    with open(sys.argv[1], "rb") as fh:
        jobs = pickle.load(fh)
    out = []
    for kd, array, vox, delays in jobs:
        counts = []
        for v in vox:
            re = cuda.to_device(np.zeros((1, 1, 1), kd.dtype))
            im = cuda.to_device(np.zeros((1, 1, 1), kd.dtype))
            axes = VoxelAxes(np.array([v[0]]), np.array([v[1]]), np.array([v[2]]))
            counts.append(run_ping_gpu(ImageSlice(re, im, axes, 0, 1), kd, array, delays,
                                       gating=True))
        out.append(counts)
    with open(sys.argv[2], "wb") as fh:
        pickle.dump(out, fh)
""")


def test_premise_the_voxels_are_at_the_edges_for_float64(cases):
    """The float64 kernel puts each voxel on the side it was placed: all or nothing at
    the projector's edge, receiver 7 alone at the receiver's."""
    kd = _planes(cases[0][2].shape[0], np.float64)
    counts = {name: _column(kd, rx, vox, kw)[0] for name, vox, rx, kw in cases}
    assert (counts["projector-inside"] > 70).all() and (counts["projector-outside"] == 0).all()
    assert (counts["receiver-inside"] - counts["receiver-outside"] == 1).all()
    assert (counts["receiver-outside"] > 0).all()       # inside the projector cone


@pytest.mark.slow
def test_float32_kernels_gate_edge_voxels_as_float64(cases, tmp_path):
    nch = cases[0][2].shape[0]
    kd64, kd32 = _planes(nch, np.float64), _planes(nch, np.float32)
    jobs = []
    for name, vox, rx, kw in cases:
        n64, v64 = _column(kd64, rx, vox, kw)
        n32, v32 = _column(kd32, rx, vox, kw)
        assert (n32 == n64).all(), (name, "column f32", n32 - n64)
        scale = np.abs(v64).max()
        assert np.abs(v32 - v64).max() <= 1e-3 * scale, name   # a channel is ~10 %
        assert (_voxel_order(kd32, rx, vox, kw) == n64).all(), (name, "voxel order f32")
        # the CUDA simulator launches a 128-thread block per voxel in Python threads
        # (~0.3 s each): every third azimuth of each edge, both sides
        jobs.append((kd32, PingArray(TX, rx, **kw), vox[::SIMULATOR_STRIDE], DELAYS,
                     n64[::SIMULATOR_STRIDE]))
    job = tmp_path / "jobs.pkl"
    with open(job, "wb") as fh:
        pickle.dump([j[:4] for j in jobs], fh)
    res = subprocess.run([sys.executable, "-c", GPU_SCRIPT, str(job), str(tmp_path / "out")],
                         cwd=ROOT, env=subprocess_env(True), capture_output=True, text=True,
                         timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    with open(tmp_path / "out", "rb") as fh:
        gpu = pickle.load(fh)
    for (name, *_), counts, j in zip(cases, gpu, jobs):
        assert (np.array(counts) == j[4]).all(), (name, "GPU (simulator) f32",
                                                  np.array(counts) - j[4])
