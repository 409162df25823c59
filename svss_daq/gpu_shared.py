"""GPU pieces shared by the backprojection kernels (:mod:`svss_proc.imaging.gpu_kernel`,
:mod:`svss_proc.imaging.gpu_batch`) and the simulator's GPU synthesis
(:mod:`sim_device.synthesis_gpu`): the block size, the per-block sum of a count with one
atomic add per block (:func:`block_count_for`), and the cache of device buffers kept
from call to call (per-role buffers refilled in place, scene tables uploaded once per
table object). Here, in the base package, because both sides use it and the simulator
imports nothing of the processing (docs/architecture.md, "Dependency rules");
``svss_proc.imaging.gpu_shared`` re-exports it.
"""

from __future__ import annotations

import logging
import types

import numpy as np
from numba import cuda

log = logging.getLogger(__name__)

#: threads per block; the block sum assumes a power of two
THREADS = 128


def _block_count(part, n, count):
    """Adds every thread's ``n`` of the block to ``count[0]`` by one atomic add:
    ``part`` is the block's shared int64 array of :data:`THREADS` entries. Every thread
    of the block must call it (it synchronises the block)."""
    t = cuda.threadIdx.x
    part[t] = n
    cuda.syncthreads()
    s = part.shape[0] // 2
    while s > 0:
        if t < s:
            part[t] += part[t + s]
        cuda.syncthreads()
        s //= 2
    if t == 0 and part[0] != 0:
        cuda.atomic.add(count, 0, part[0])


def block_count_for(namespace: dict):
    """The block sum (:func:`_block_count`) as a CUDA device function whose globals are
    ``namespace``, the ``globals()`` of the module that defines the kernels calling it
    (which names ``numba.cuda`` ``cuda``). Under numba's CUDA simulator a launch swaps
    ``numba.cuda`` for its per-launch stand-in in the kernel module's globals only; a
    device function of another module swaps its own module's globals per call, and the
    first simulated thread to return undoes that swap for the threads still waiting at
    the block's barrier (they then fail on ``cuda.atomic``)."""
    fn = types.FunctionType(_block_count.__code__, namespace, "block_count")
    fn.__doc__ = _block_count.__doc__
    return cuda.jit(device=True)(fn)


class DeviceBuffers:
    """Device buffers reused from call to call, one per role, and device copies of
    tables by identity (a caller that keeps its tables uploads each once)."""

    def __init__(self):
        self.buffers: dict = {}
        self.tables: dict = {}
        self.views: dict = {}

    def upload(self, role: str, host: np.ndarray):
        """``host`` in the buffer of ``role``, replaced (the old one freed) when its shape
        or dtype changes; returns the device array."""
        dev = self.buffers.get(role)
        if dev is None or dev.shape != host.shape or dev.dtype != host.dtype:
            dev = self.buffers[role] = cuda.to_device(host)   # the old one is freed
            self.views.pop(role, None)
        else:
            dev.copy_to_device(host)
        return dev

    def upload_parts(self, role: str, arrays) -> list:
        """``arrays`` (1-D, one dtype) uploaded in one copy into one buffer; device views
        of the parts, kept from call to call while the buffer and the part sizes stay
        (slicing a device array costs tens of microseconds)."""
        sizes = tuple(a.size for a in arrays)
        dev = self.upload(role, np.concatenate(arrays))
        cached = self.views.get(role)
        if cached is None or cached[0] != sizes:
            edges = np.cumsum((0,) + sizes)
            cached = self.views[role] = (sizes, [dev[edges[k]:edges[k + 1]]
                                                 for k in range(len(sizes))])
        return cached[1]

    def upload_rows(self, role: str, host: np.ndarray, dtype):
        """``host`` as ``dtype`` in the buffer of ``role``, which holds a varying number
        of rows: grown to 5/4 of the need when too small, never shrunk; returns the
        device view of ``host``'s shape."""
        host = np.ascontiguousarray(host, dtype=dtype)
        n = host.shape[0]
        d = self.buffers.get(role)
        if d is None or d.shape[0] < n or d.shape[1:] != host.shape[1:] or d.dtype != dtype:
            cap = max(n + n // 4, 1)
            log.debug("GPU buffer %s: %s %s", role, (cap, *host.shape[1:]), np.dtype(dtype))
            d = cuda.device_array((cap, *host.shape[1:]), dtype=dtype)
            self.buffers[role] = d
        view = d[:n]
        if n:
            view.copy_to_device(host)
        return view

    def array(self, role: str, shape: tuple, dtype):
        """An uninitialised device array of ``role``, kept while its shape and dtype
        stay."""
        d = self.buffers.get(role)
        if d is None or d.shape != tuple(shape) or d.dtype != np.dtype(dtype):
            d = self.buffers[role] = cuda.device_array(shape, dtype)
        return d

    def table(self, host: np.ndarray, dtype=None):
        """A device copy of the table ``host`` (as ``dtype``, contiguous, where given),
        uploaded again only for another table object."""
        key = (id(host), None if dtype is None else np.dtype(dtype))
        entry = self.tables.get(key)
        if entry is None or entry[0] is not host:
            if len(self.tables) > 64:
                self.tables.clear()
            data = host if dtype is None else np.ascontiguousarray(host, dtype=dtype)
            entry = self.tables[key] = (host, cuda.to_device(data))
        return entry[1]
