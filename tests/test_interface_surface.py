"""The kernels over a sloping interface (``surf``: the interface's depth at each voxel
column below the level the element heights are from): every column is refracted at its
own interface, taken as level about the column. Checked against the plain float64
summation (tests/references.py) made column by column with the elements raised by that
column's depth, for each delay model; and the coverage the same way."""

from __future__ import annotations

import math

import numpy as np
import pytest

from svss_daq.ping import SampleAxis
from svss_proc.conditioning import Conditioned
from svss_proc.imaging.coverage import add_ping, aperture_corners, new_coverage
from svss_proc.imaging.cpu_kernel import run_ping
from svss_proc.imaging.delays import build_table
from svss_proc.imaging.kernel_args import (DelayModel, ImageSlice, PingArray, VoxelAxes,
                                          prepare)
from tests.references import direct_sum
from tests.test_backprojection import CS, CW, scene


def _plane(along, cross, ga=math.tan(math.radians(3)), gc=math.tan(math.radians(5))):
    return ga * along[:, None] + gc * cross[None, :]


#: exact delays in float32 by default, the kernel the other exact tests compile (float64's
#: voxel-order kernel, compiled anew on a cold cache, is `extended`)
@pytest.mark.parametrize("mode, precision", [
    ("straight", "float64"), ("exact", "float32"), ("table", "float32"),
    pytest.param("exact", "float64", marks=pytest.mark.extended)])
def test_each_column_refracts_at_its_own_interface(mode, precision):
    rng = np.random.default_rng(46)
    dt = 16e-6
    data, tx, rx = scene(rng, dt=dt)
    t0, fc = 1.0e-3, 27.5e3
    bore = np.array([0.0, 0.0, 1.0])
    along = np.linspace(-1.0, 1.4, 5)
    cross = np.linspace(-0.9, 0.9, 4)
    depth = np.linspace(0.05, 0.9, 4)
    surf = _plane(along, cross)              # +-0.1 m: 5 deg across, 3 deg along
    apod = rng.uniform(0.5, 1.5, rx.shape[0])
    cos_tx, cos_rx = math.cos(math.radians(30)), math.cos(math.radians(50))
    ft = np.float32 if precision == "float32" else np.float64
    cond = Conditioned.from_baseband(data, SampleAxis(t0, dt, data.shape[1]), fc)
    kd = prepare(cond, "linear", ft)
    re, im = (np.zeros((along.size, cross.size, depth.size), ft) for _ in range(2))
    table = build_table(2.0, 4.0, -0.2, 1.2, 0.005, CW, CS) if mode == "table" else None
    n = run_ping(ImageSlice(re, im, VoxelAxes(along, cross, depth, surf), 0, along.size),
                 kd, PingArray(tx, rx, bore, cos_tx, cos_rx, apod),
                 DelayModel(mode, CW, CS, table), gating=True)
    got = re + 1j * im
    ref = np.zeros_like(got, dtype=np.complex128)
    n_ref = 0
    for i in range(along.size):
        for j in range(cross.size):
            lift = np.array([0.0, 0.0, surf[i, j]])
            col, nc = direct_sum(data.astype(np.complex128), t0, dt, fc, tx - lift,
                                 rx - lift, bore, cos_tx, cos_rx, along[i:i + 1],
                                 cross[j:j + 1], depth, True, "linear", mode, apod, CW, CS,
                                 count=True)
            ref[i, j] = col[0, 0]
            n_ref += nc
    assert n == n_ref > 0
    # the table: its bilinear look-up (3e-3, as on a level bed), and its height
    # expansion to second order about the ping's mean height, whose third-order remainder
    # over +-0.12 m of column depth is 5e-3 of the peak here (the first order alone: 0.14)
    tol = {"float64": 1e-6, "float32": 1e-4}[precision] + (1e-2 if mode == "table" else 0)
    assert np.abs(got - ref).max() / np.abs(ref).max() < tol
    # and the slope matters: the level image differs by far more than that
    flat = np.zeros_like(ref)
    for i in range(along.size):
        for j in range(cross.size):
            flat[i, j] = direct_sum(data.astype(np.complex128), t0, dt, fc, tx, rx, bore,
                                    cos_tx, cos_rx, along[i:i + 1], cross[j:j + 1], depth,
                                    True, "linear", mode, apod, CW, CS)[0, 0]
    assert np.abs(flat - ref).max() / np.abs(ref).max() > 0.1


def test_coverage_counts_each_column_below_its_own_interface():
    rng = np.random.default_rng(7)
    _, tx, rx = scene(rng, nch=8)
    bore = np.array([0.0, 0.0, 1.0])
    along = np.linspace(-1.5, 1.5, 13)
    cross = np.linspace(-1.2, 1.2, 9)
    depth = np.linspace(0.0, 1.5, 16)
    surf = _plane(along, cross, 0.05, 0.2)
    corners = aperture_corners(rx)
    args = (corners, bore, math.radians(25), math.radians(50), True, (2.4e-3, 4.6e-3),
            CW, CS)
    pings, chans = new_coverage((along.size, cross.size, depth.size))
    add_ping(pings, chans, along, cross, depth, 0, along.size, tx, rx, *args, surface=surf)
    for i in range(along.size):
        for j in range(cross.size):
            p1, c1 = new_coverage((1, 1, depth.size))
            lift = np.array([0.0, 0.0, surf[i, j]])
            add_ping(p1, c1, along[i:i + 1], cross[j:j + 1], depth, 0, 1, tx - lift,
                     rx - lift, *args)
            assert np.array_equal(pings[i, j], p1[0, 0]) and np.array_equal(chans[i, j],
                                                                              c1[0, 0])
    assert pings.any() and not pings.all()        # the cone and the window both cut
