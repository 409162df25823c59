"""Uploads that do not stop the host (issue 52): host data is copied into a page-locked
staging row and from there onto the device asynchronously, on the imager's CUDA stream,
so that the host goes on (conditioning, geometry, the next ping) while the copy and the
kernels before it run.

:class:`StagedRows` keeps ``capacity`` rows of one shape and dtype, in page-locked host
memory and on the device, each row with a CUDA event recorded after its copy: a row's
staging memory is written again only once that copy has been made (the event waited
for, almost always long past). Work on one stream runs in the order it was enqueued, so
a kernel enqueued after a row's copy reads the copied data, and a copy enqueued after a
kernel does not overwrite what the kernel reads.

What runs on the legacy default stream (a tile's volumes zeroed, its update counter
made, the tables uploaded once each, the tile's planes, counts and coverage read back)
is ordered against the batcher's stream because numba makes that stream a blocking one:
the legacy default stream waits for its work, and it for the default stream's. Per-thread
default streams (``NUMBA_CUDA_PER_THREAD_DEFAULT_STREAM=1``) would break that ordering,
and the imager does not support them. Each such call also drains the batcher's stream,
so a new tile or a new refraction table (one per centimetre of array height) costs one
wait for the GPU.
"""

from __future__ import annotations

import numpy as np
from numba import cuda


class StagedRows:
    """``capacity`` rows of ``shape`` and ``dtype`` staged for upload (module
    docstring); :meth:`put` copies host data into a row and enqueues its upload on
    ``stream``, returning the device row."""

    def __init__(self, capacity: int, shape: tuple, dtype, stream):
        self.capacity = int(capacity)
        self.shape = tuple(int(n) for n in shape)
        self.dtype = np.dtype(dtype)
        self.stream = stream
        self._host = None
        self.device = cuda.device_array((self.capacity,) + self.shape, dtype=self.dtype)
        self._events: list = [None] * self.capacity
        self._rows = [self.device[i] for i in range(self.capacity)]
        #: the row a caller that alternates between rows last used
        self.turn = 0

    @property
    def host(self) -> np.ndarray:
        """The page-locked staging rows, made when first used (a ring whose planes are
        all made on the device never stages any)."""
        if self._host is None:
            self._host = cuda.pinned_array((self.capacity,) + self.shape, dtype=self.dtype)
        return self._host

    def fits(self, shape: tuple, dtype) -> bool:
        return tuple(shape) == self.shape and np.dtype(dtype) == self.dtype

    def host_row(self, row: int) -> np.ndarray:
        """The staging memory of row ``row``, to be written (its previous copy waited
        for), then sent with :meth:`send`."""
        ev = self._events[row]
        if ev is not None:
            ev.synchronize()                 # the row's previous copy has been made
            self._events[row] = None
        return self.host[row]

    def send(self, row: int):
        """Enqueue row ``row``'s copy onto the device on the stream; the device row."""
        self._rows[row].copy_to_device(self.host[row], stream=self.stream)
        ev = self._events[row] = cuda.event()
        ev.record(self.stream)
        return self._rows[row]

    def put(self, row: int, data: np.ndarray):
        """``data`` (of this shape; cast to this dtype) into row ``row`` and onto the
        device, asynchronously on the stream; the device row."""
        self.host_row(row)[...] = data
        return self.send(row)


def on_device(a) -> bool:
    """Whether ``a`` is a device array (numba's, or the CUDA simulator's stand-in)."""
    return hasattr(a, "copy_to_host")
