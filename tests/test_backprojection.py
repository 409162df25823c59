"""The numba backprojection kernel against a plain float64 summation written here."""

from __future__ import annotations

import math

import numpy as np
import pytest

from svss_proc.backprojection import along_reach, backproject_ping, prepare
from svss_proc.conditioning import Conditioned


def direct_sum(data, t0, dt, fc, c, tx, rx, bore, cos_tx, cos_rx, along, cross, depth, gating):
    img = np.zeros((along.size, cross.size, depth.size), dtype=np.complex128)
    tgrid = t0 + dt * np.arange(data.shape[1])
    for i, x in enumerate(along):
        for j, y in enumerate(cross):
            for k, z in enumerate(depth):
                v = np.array([x, y, z])
                r1 = np.linalg.norm(v - tx)
                if gating and (v - tx) @ bore < r1 * cos_tx:
                    continue
                for ch in range(rx.shape[0]):
                    r2 = np.linalg.norm(v - rx[ch])
                    if gating and (v - rx[ch]) @ bore < r2 * cos_rx:
                        continue
                    tau = (r1 + r2) / c
                    if not tgrid[0] <= tau < tgrid[-1]:
                        continue
                    s = (np.interp(tau, tgrid, data[ch].real)
                         + 1j * np.interp(tau, tgrid, data[ch].imag))
                    img[i, j, k] += s * np.exp(2j * np.pi * fc * tau)
    return img


@pytest.mark.parametrize("dt", [8e-6, 16e-6, 32e-6, 64e-6])
def test_kernel_matches_direct_sum(dt):
    rng = np.random.default_rng(3)
    nch, nt = 7, 400
    data = (rng.normal(size=(nch, nt)) + 1j * rng.normal(size=(nch, nt))).astype(np.complex64)
    t0, fc, c = 1.0e-3, 27.5e3, 1500.0
    tx = np.array([0.3, -0.2, -2.0])
    rx = np.column_stack([rng.uniform(-0.4, 0.4, nch), rng.uniform(-0.5, 0.5, nch),
                          np.full(nch, -2.0)])
    bore = np.array([0.0, 0.0, 1.0])
    along = np.linspace(-1.2, 1.2, 9)
    cross = np.linspace(-0.8, 0.8, 6)
    depth = np.linspace(0.0, 1.0, 5)
    for gating in (True, False):
        cos_tx, cos_rx = math.cos(math.radians(25)), math.cos(math.radians(50))
        ref = direct_sum(data.astype(np.complex128), t0, dt, fc, c, tx, rx, bore, cos_tx,
                         cos_rx, along, cross, depth, gating)
        img = np.zeros(ref.shape, dtype=np.complex64)
        kd = prepare(Conditioned(data, t0, dt, fc))
        n = backproject_ping(img, kd.d, kd.f, kd.t0, kd.dt, kd.theta, kd.halvings, c, tx, rx,
                             bore, cos_tx, cos_rx, along, cross, depth, 0, along.size, gating)
        assert n > 0
        np.testing.assert_allclose(img, ref, rtol=0, atol=2e-6 * np.abs(ref).max())
        if gating:
            assert np.count_nonzero(ref == 0) > 0       # the cones really exclude voxels
            # a partial along-track range leaves the other slices untouched
            part = np.zeros(ref.shape, dtype=np.complex64)
            backproject_ping(part, kd.d, kd.f, kd.t0, kd.dt, kd.theta, kd.halvings, c, tx,
                             rx, bore, cos_tx, cos_rx, along, cross, depth, 2, 5, gating)
            assert not part[:2].any() and not part[5:].any()
            np.testing.assert_allclose(part[2:5], ref[2:5], atol=2e-6 * np.abs(ref).max())


def test_along_reach_bounds_the_projector_cone():
    tx = np.array([0.0, 0.0, -2.0])
    bore = np.array([0.0, 0.0, 1.0])
    reach = along_reach(tx, bore, math.radians(25), 1.0)
    np.testing.assert_allclose(reach, 3.0 * math.tan(math.radians(25)))
    tilted = np.array([math.sin(0.1), 0.0, math.cos(0.1)])
    assert along_reach(tx, tilted, math.radians(25), 1.0) > reach
