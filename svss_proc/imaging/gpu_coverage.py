"""A tile's coverage counted on the GPU (issue 52): the CPU's counting code
(:mod:`svss_proc.imaging.coverage`: ``_column`` and what it calls) compiled as CUDA
device functions, one thread per voxel column, into the tile's coverage volumes kept
on the device while it forms (brought back with its image planes).

One source: the device functions are the CPU functions' own Python code, given a
namespace in which the functions they call are the device versions. A column is one
thread's alone, so the counts need no atomics. They equal the CPU's except where the
GPU's fused multiply-adds round a voxel lying on a cone's or the window's edge the other
way (the simulator, which runs the Python, gives the CPU's exactly).
"""

from __future__ import annotations

import math
import types

import numpy as np
from numba import cuda

from . import coverage as _cpu
from .gpu_shared import THREADS, DeviceBuffers
from .gpu_staging import StagedRows

#: the rows a :class:`DeviceCounter` stages, used in turn
STAGED_ROWS = 8


def _device_functions() -> dict:
    """The counting code as CUDA device functions, by name."""
    ns = {"math": math, "np": np, "SATURATE": _cpu.SATURATE}
    for name in ("_leg_time", "_rx_time", "_count", "_add", "_column"):
        py = getattr(_cpu, name).py_func
        ns[name] = cuda.jit(device=True)(types.FunctionType(py.__code__, ns, name))
    return ns


_column = _device_functions()["_column"]


#: the placed row's layout (:func:`placed_row`): projector, boresight, the ping's scalars,
#: then the receivers (x, y, z each)
_TX, _BORE, _SCALARS, _RX = 0, 3, 6, 15


@cuda.jit
def _accumulate(pings, channels, ax, cy, dz, surf, corners, ia0, ia1, row):
    i = cuda.grid(1)
    nc = cy.size
    if i < (ia1 - ia0) * nc:
        nch = (row.size - _RX) // 3
        rx = row[_RX:_RX + 3 * nch].reshape((nch, 3))
        tx = row[_TX:_TX + 3]
        s = _SCALARS
        _column(pings, channels, ia0 + i // nc, i % nc, ax, cy, dz, surf, tx, rx, corners,
                row[_BORE], row[_BORE + 1], row[_BORE + 2], -tx[2], row[s + 8], row[s],
                row[s + 1], row[s + 2] != 0.0, row[s + 3], row[s + 4], row[s + 5],
                row[s + 6], row[s + 7])


def placed_row(a: _cpu.CoverageArgs) -> np.ndarray:
    """The ping's array and scalars in one float64 row, the one upload a ping's coverage
    needs (and few launch arguments): projector, boresight, cos_tx, cos_rx, gating,
    t_lo, t_hi, 1/c_w, 1/c_s, rho_max, h_min, receivers."""
    return np.concatenate([a.tx, a.bore, [a.cos_tx, a.cos_rx, float(a.gating), a.t_lo,
                                          a.t_hi, a.inv_cw, a.inv_cs, a.rho_max, a.h_min],
                           a.rx.ravel()])


def add_ping_device(pings, channels, a: _cpu.CoverageArgs, ia0: int, ia1: int, row,
                    buffers, stream) -> None:
    """:func:`~svss_proc.imaging.coverage.add_ping` on the device: ``pings`` and
    ``channels`` device volumes, ``a`` the ping's
    :func:`~svss_proc.imaging.coverage.coverage_args`, ``row`` its :func:`placed_row`
    on the device; the tile's axes, surface and aperture corners from ``buffers``
    (:class:`~svss_daq.gpu_shared.DeviceBuffers`, uploaded once per array)."""
    n = (int(ia1) - int(ia0)) * a.cy.size
    if n <= 0:
        return
    _accumulate[math.ceil(n / THREADS), THREADS, stream](
        pings, channels, buffers.table(a.ax), buffers.table(a.cy), buffers.table(a.dz),
        buffers.table(a.surf), buffers.table(a.corners), int(ia0), int(ia1), row)


class DeviceCounter:
    """Counts coverage on the device (the ``counter`` of
    :meth:`~svss_proc.imaging.coverage.Coverage.add`): each ping's placed array goes up
    from page-locked staging, asynchronously, and the count is a launch, both on
    ``stream``; the tile's axes go up once."""

    def __init__(self, stream):
        self.stream = stream
        self.buffers = DeviceBuffers()
        self._staged: StagedRows | None = None
        self._turn = 0

    def __call__(self, pings, channels, a: _cpu.CoverageArgs, ia0: int, ia1: int) -> None:
        row = placed_row(a)
        st = self._staged
        if st is None or not st.fits(row.shape, np.float64):
            st = self._staged = StagedRows(STAGED_ROWS, row.shape, np.float64, self.stream)
        self._turn = (self._turn + 1) % st.capacity
        add_ping_device(pings, channels, a, ia0, ia1, st.put(self._turn, row),
                        self.buffers, self.stream)
