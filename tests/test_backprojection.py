"""The backprojection kernels against a plain float64 summation (tests/references.py),
for every interpolation, precision and delay option."""

from __future__ import annotations

import math

import numpy as np
import pytest

from svss_daq.ping import SampleAxis
from svss_proc.conditioning import Conditioned
from svss_proc.imaging.cpu_kernel import COLUMN_BLOCK, _make_kernel, run_ping
from svss_proc.imaging.delays import build_table
from svss_proc.imaging.schedule import along_reach
from svss_proc.imaging.kernel_args import (DelayModel, ImageSlice, PingArray, VoxelAxes,
                                          kernel_args, prepare)
from tests.references import direct_sum

CW, CS = 1500.0, 1767.0


def scene(rng, nch=6, nt=300, dt=16e-6):
    # smooth (band-limited) random data, as a matched-filter output would be
    raw = rng.normal(size=(nch, nt)) + 1j * rng.normal(size=(nch, nt))
    spec = np.fft.fft(raw, axis=1)
    f = np.fft.fftfreq(nt, dt)
    spec[:, np.abs(f) > 8e3] = 0
    data = np.fft.ifft(spec, axis=1).astype(np.complex64)
    tx = np.array([0.3, -0.2, -2.0])
    rx = np.column_stack([rng.uniform(-0.4, 0.4, nch), rng.uniform(-0.5, 0.5, nch),
                          -2.0 + rng.uniform(-0.02, 0.02, nch)])
    return data, tx, rx


#: the default run: every delay model with the default interpolation and precision,
#: every interpolation once, float64 once; the other combinations (each a kernel
#: specialisation numba compiles anew on a cold cache) are `extended`
DEFAULT_CASES = {("linear", "float32", "straight"), ("linear", "float32", "exact"),
                 ("linear", "float32", "table"), ("nearest", "float32", "straight"),
                 ("cubic", "float32", "straight"), ("cubic", "float64", "exact")}
CASES = [(interp, prec, mode) for interp in ("nearest", "linear", "cubic")
         for prec in ("float32", "float64") for mode in ("straight", "exact")]
CASES += [("linear", "float64", "table"), ("linear", "float32", "table")]
CASES = [c if c in DEFAULT_CASES else pytest.param(*c, marks=pytest.mark.extended)
         for c in CASES]


@pytest.mark.parametrize("interp, precision, mode", CASES)
def test_kernel_matches_direct_sum(interp, precision, mode):
    rng = np.random.default_rng(3)
    dt = 16e-6
    data, tx, rx = scene(rng, dt=dt)
    t0, fc = 1.0e-3, 27.5e3
    bore = np.array([0.0, 0.0, 1.0])
    along = np.linspace(-1.0, 1.4, 6)
    cross = np.linspace(-0.6, 0.6, 4)
    depth = np.linspace(-0.1, 0.9, 4)
    apod = rng.uniform(0.5, 1.5, rx.shape[0])
    cos_tx, cos_rx = math.cos(math.radians(25)), math.cos(math.radians(50))
    ref, n_ref = direct_sum(data.astype(np.complex128), t0, dt, fc, tx, rx, bore, cos_tx,
                            cos_rx, along, cross, depth, True, interp, mode, apod, CW, CS,
                            count=True)
    ft = np.float32 if precision == "float32" else np.float64
    cond = Conditioned.from_baseband(data, SampleAxis(t0, dt, data.shape[1]), fc)
    kd = prepare(cond, interp, ft)
    re, im = np.zeros(ref.shape, ft), np.zeros(ref.shape, ft)
    table = (build_table(2.0, 4.0, -0.2, 1.0, 0.005, CW, CS) if mode == "table" else None)
    n = run_ping(ImageSlice(re, im, VoxelAxes(along, cross, depth), 0, along.size), kd,
                 PingArray(tx, rx, bore, cos_tx, cos_rx, apod),
                 DelayModel(mode, CW, CS, table), gating=True)
    assert n == n_ref > 0                          # every (voxel, element) term summed
    assert np.count_nonzero(ref == 0) > 0          # the cones really exclude voxels
    err = np.abs(re + 1j * im - ref).max() / np.abs(ref).max()
    # float32: delays carry ~3e-5 of a sample at 250 samples (phase ~5e-5 rad); the table's bilinear look-up adds a small delay error
    tol = {"float64": 1e-6, "float32": 1e-4}[precision] + (3e-3 if mode == "table" else 0)
    assert err < tol, err


@pytest.mark.parametrize("interp, mode", [
    (i, m) if i == "linear" or m == "straight"
    else pytest.param(i, m, marks=pytest.mark.extended)
    for i in ("nearest", "linear", "cubic") for m in ("straight", "table")])
def test_window_path_matches_direct_sum(interp, mode):
    """2 cm depth voxels: 16 consecutive depths read samples within a 32-sample window,
    so the float32 kernel takes the window-permute path (the coarse grids above take the
    lane-by-lane one)."""
    rng = np.random.default_rng(11)
    dt, t0, fc = 16e-6, 1.0e-3, 27.5e3
    data, tx, rx = scene(rng, dt=dt)
    bore = np.array([0.0, 0.0, 1.0])
    along, cross = np.array([0.2, 0.3, 0.45]), np.array([-0.25, 0.0])
    depth = 0.3 + 0.02 * np.arange(40)
    cos_tx, cos_rx = math.cos(math.radians(25)), math.cos(math.radians(50))
    # the premise: two-way delays over 16 depths span fewer than 31 samples
    v = np.stack(np.meshgrid(along, cross, depth, indexing="ij"), -1)
    two_way = (np.linalg.norm(v - tx, axis=-1)[..., None]
               + np.linalg.norm(v[..., None, :] - rx, axis=-1)) / CW / dt
    assert np.abs(two_way[:, :, 16:] - two_way[:, :, :-16]).max() < 30
    ref, n_ref = direct_sum(data.astype(np.complex128), t0, dt, fc, tx, rx, bore, cos_tx,
                            cos_rx, along, cross, depth, True, interp, mode,
                            np.ones(rx.shape[0]), CW, CS, count=True)
    cond = Conditioned.from_baseband(data, SampleAxis(t0, dt, data.shape[1]), fc)
    kd = prepare(cond, interp, np.float32)
    re, im = np.zeros(ref.shape, np.float32), np.zeros(ref.shape, np.float32)
    table = build_table(2.0, 4.0, -0.2, 1.2, 0.005, CW, CS) if mode == "table" else None
    n = run_ping(ImageSlice(re, im, VoxelAxes(along, cross, depth), 0, along.size), kd,
                 PingArray(tx, rx, bore, cos_tx, cos_rx),
                 DelayModel(mode, CW, CS, table), gating=True)
    assert np.count_nonzero(ref) > 0.5 * ref.size
    assert n == n_ref
    err = np.abs(re + 1j * im - ref).max() / np.abs(ref).max()
    assert err < 1e-4 + (3e-3 if mode == "table" else 0), err


def test_partial_along_range_and_no_gating():
    """float32, as the shipped precision (the kernel the sampler's ungated tiles use,
    tests/micronav/test_sampler_reach.py: no specialisation of its own to compile)."""
    rng = np.random.default_rng(5)
    data, tx, rx = scene(rng)
    cond = Conditioned.from_baseband(data, SampleAxis(1e-3, 16e-6, data.shape[1]), 27.5e3)
    kd = prepare(cond, "linear", np.float32)
    along, cross, depth = np.linspace(-1, 1, 7), np.linspace(-0.5, 0.5, 3), np.linspace(0, 1, 3)
    bore = np.array([0.0, 0.0, 1.0])
    full = [np.zeros((7, 3, 3), np.float32), np.zeros((7, 3, 3), np.float32)]
    part = [np.zeros((7, 3, 3), np.float32), np.zeros((7, 3, 3), np.float32)]
    axes = VoxelAxes(along, cross, depth)
    array = PingArray(tx, rx, bore, 0.9, 0.6)
    delays = DelayModel("straight", CW, CW)
    run_ping(ImageSlice(*full, axes, 0, 7), kd, array, delays, gating=False)
    run_ping(ImageSlice(*part, axes, 2, 5), kd, array, delays, gating=False)
    assert not part[0][:2].any() and not part[0][5:].any()
    assert np.array_equal(part[0][2:5], full[0][2:5]) and np.array_equal(part[1][2:5],
                                                                          full[1][2:5])
    ref = direct_sum(data.astype(np.complex128), 1e-3, 16e-6, 27.5e3, tx, rx, bore, 0.9, 0.6,
                     along, cross, depth, False, "linear", "straight", np.ones(rx.shape[0]),
                     CW, CW)
    err = np.abs(full[0] + 1j * full[1] - ref).max() / np.abs(ref).max()
    assert err < 1e-4, err                       # float32 (test_kernel_matches_direct_sum)


def test_along_reach_bounds_the_projector_cone():
    tx = np.array([0.0, 0.0, -2.0])
    bore = np.array([0.0, 0.0, 1.0])
    reach = along_reach(tx, bore, math.radians(25), 1.0)
    np.testing.assert_allclose(reach, 3.0 * math.tan(math.radians(25)))
    tilted = np.array([math.sin(0.1), 0.0, math.cos(0.1)])
    assert along_reach(tx, tilted, math.radians(25), 1.0) > reach


#: the block loop is the same code in both delay models; each block size is a kernel
#: numba compiles anew on a cold cache, so straight rays' are `extended` (issue 50)
@pytest.mark.parametrize("mode", ["table", pytest.param("straight", marks=pytest.mark.extended)])
def test_column_blocks_sum_as_one_column(mode):
    """The column kernel sweeps each channel over blocks of cross-track columns (issue
    32): the shipped block size gives the one-column order's image bit for bit, its
    partial block (11 columns: 8 + 3) included, and the direct sum's; the one-column
    order's first block is empty. Far from the origin, 2 cm depths (the window-gather
    path), 11 columns of which the outer ones lie outside the projector's cone at every
    depth. (Each block size is a kernel of its own, compiled anew on a cold cache; the
    shipped one is warmed before the tests start, so one more size is compiled here.)"""
    rng = np.random.default_rng(17)
    dt, t0, fc = 16e-6, 1.0e-3, 27.5e3
    data, tx, rx = scene(rng, dt=dt)
    origin = np.array([300.0, -40.0, 0.0])
    tx, rx = tx + origin, rx + origin
    bore = np.array([0.0, 0.0, 1.0])
    along = origin[0] + np.array([0.2, 0.3, 0.45])
    cross = origin[1] + np.linspace(-1.8, 1.4, 11)
    depth = 0.3 + 0.02 * np.arange(40)
    cos_tx, cos_rx = math.cos(math.radians(25)), math.cos(math.radians(50))
    axes = VoxelAxes(along, cross, depth)
    cond = Conditioned.from_baseband(data, SampleAxis(t0, dt, data.shape[1]), fc)
    kd = prepare(cond, "linear", np.float32)
    table = build_table(2.0, 4.0, -0.2, 1.2, 0.005, CW, CS) if mode == "table" else None
    delays = DelayModel(mode, CW, CS, table)
    args = kernel_args(kd, PingArray(tx, rx, bore, cos_tx, cos_rx), axes, delays)
    shape = (along.size, cross.size, depth.size)
    images, counts = {}, {}
    assert cross.size % COLUMN_BLOCK                       # a partial block
    for block in (1, COLUMN_BLOCK):
        kernel = _make_kernel(kd.interp, delays.code, True, kd.halvings, block=block)
        re, im = np.zeros(shape, np.float32), np.zeros(shape, np.float32)
        counts[block] = kernel(re, im, args, 0, along.size)
        images[block] = re + 1j * im
    ref, n_ref = direct_sum(data.astype(np.complex128), t0, dt, fc, tx, rx, bore, cos_tx,
                            cos_rx, along, cross, depth, True, "linear", mode,
                            np.ones(rx.shape[0]), CW, CS, count=True)
    assert not ref[:, 0].any() and ref[:, 1:-1].any()      # an empty column, live ones
    for block in images:
        assert counts[block] == n_ref, block
        assert np.array_equal(images[block], images[1]), block
    err = np.abs(images[COLUMN_BLOCK] - ref).max() / np.abs(ref).max()
    assert err < 1e-4 + (3e-3 if mode == "table" else 0), err
