"""The CPU kernels' work split (issue 16): along-track slices run in a spread order so
that numba's contiguous per-thread blocks of the parallel loop each get slices from the
whole projector cone; the images do not depend on the order or the thread count."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest

from svss_daq.ping import SampleAxis
from svss_proc.conditioning import Conditioned
from svss_proc.imaging.cpu_kernel import _make_kernel, spread_step
from svss_proc.imaging.kernel_args import (DELAY, INTERP, DelayModel, PingArray, VoxelAxes,
                                          kernel_args, prepare)

CW = 1500.0


def _blocks(n, parts):
    """numba's static split of n iterations into ``parts`` contiguous blocks."""
    edges = np.linspace(0, n, parts + 1).round().astype(int)
    return [range(a, b) for a, b in zip(edges[:-1], edges[1:])]


def test_spread_order_is_a_permutation():
    for n in range(1, 500):
        step = spread_step(n)
        assert sorted((j * step) % n for j in range(n)) == list(range(n)), n


@pytest.mark.parametrize("n", [40, 97, 190, 240, 751])
def test_spread_order_balances_the_cone(n):
    """Work per slice as under the projector cone (no work at its edges); with 10 slices
    or more per thread (a reference-tile ping has ~190 slices) the most loaded thread
    carries at most 15 % over the mean in the spread order, where contiguous blocks load
    the middle threads 1.4-1.7x (the edges' threads idle)."""
    x = (np.arange(n) + 0.5) / n * 2 - 1
    work = np.maximum(1 - x * x, 0)
    step = spread_step(n)
    for threads in (2, 4, 8, 16):
        if n < 2 * threads:
            continue
        spread = [sum(work[(j * step) % n] for j in b) for b in _blocks(n, threads)]
        contiguous = [work[b.start:b.stop].sum() for b in _blocks(n, threads)]
        mean = work.sum() / threads
        if n >= 10 * threads:                  # whole slices: granularity allows it
            assert max(spread) / mean < 1.15, (n, threads, max(spread) / mean)
        if threads >= 4:
            assert max(contiguous) / mean > 1.3          # the premise: contiguous is not
            assert max(spread) < max(contiguous)


def _ping(rng, nch=12, nt=400, dt=16e-6):
    raw = rng.normal(size=(nch, nt)) + 1j * rng.normal(size=(nch, nt))
    data = raw.astype(np.complex64)
    tx = np.array([0.31, -0.02, -2.0])
    rx = np.column_stack([rng.uniform(-0.4, 0.4, nch), rng.uniform(-0.3, 0.3, nch),
                          np.full(nch, -2.0)])
    cond = Conditioned.from_baseband(data, SampleAxis(1e-3, dt, nt), 27.5e3)
    return cond, tx, rx


@pytest.mark.parametrize("interp, mode, precision", [("linear", "straight", np.float32),
                                                     pytest.param("cubic", "straight",
                                                                  np.float64,
                                                                  marks=pytest.mark.extended),
                                                     ("linear", "exact", np.float32)])
def test_images_identical_in_any_order_and_thread_count(interp, mode, precision):
    rng = np.random.default_rng(4)
    cond, tx, rx = _ping(rng)
    kd = prepare(cond, interp, precision)
    along = np.arange(-1.2, 1.8, 0.02)
    cross = np.arange(-0.3, 0.3, 0.04)
    depth = np.arange(0.0, 0.6, 0.02)
    array = PingArray(tx, rx, np.array([0.0, 0.0, 1.0]), math.cos(math.radians(25)),
                      math.cos(math.radians(50)))
    args = kernel_args(kd, array, VoxelAxes(along, cross, depth), DelayModel(mode, CW, CW))
    shape = (along.size, cross.size, depth.size)
    images = []
    threads = numba.get_num_threads()
    try:
        for spread in (False, True):
            kernel = _make_kernel(INTERP[interp], DELAY[mode], True, kd.halvings, spread)
            for n_threads in sorted({1, threads}):
                numba.set_num_threads(n_threads)
                re, im = np.zeros(shape, precision), np.zeros(shape, precision)
                n = kernel(re, im, args, 3, along.size - 2)
                images.append((re, im, n))
    finally:
        numba.set_num_threads(threads)
    re0, im0, n0 = images[0]
    assert n0 > 0 and np.count_nonzero(re0) > 0.2 * re0.size
    assert not re0[:3].any() and not re0[-2:].any()
    for re, im, n in images[1:]:
        assert n == n0
        np.testing.assert_array_equal(re, re0)
        np.testing.assert_array_equal(im, im0)
