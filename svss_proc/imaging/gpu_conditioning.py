"""Conditioning on the GPU (issue 52): a ping's ADC codes go up (a quarter of the bytes
of its tap planes) and the device makes the tap planes the kernel reads.

Conditioning (:class:`~svss_proc.conditioning.Conditioner`: matched filter, band kept
around the carrier, decimation, the carrier's shift) and the tap planes
(:func:`~svss_proc.imaging.kernel_args.prepare`: each tap's shift and phase) are linear
in the codes. The conditioning is therefore one matrix, ``Conditioner.operator()``,
made once from the CPU conditioner itself (its response to each unit sample: one
definition of the conditioning, the CPU's), and on the device each ping is

    a[ch, m] = sum_n codes[ch, n] op[n, m],      P_i[ch, j] = a[ch, j + k_i] exp(-j theta (k_i - s))

in float64 (the same sums as the CPU's FFTs to rounding, ~1e-15 of the peak), the
planes then written in the kernel precision into the ping's slot of the batcher's
device ring (:mod:`~svss_proc.imaging.gpu_batch`). The operator is dense (the kept
band's sharp edges spread every output over the whole window): 1500 x 750 complex
values for the shipped digitiser, 18 MB on the device, 1.8e8 multiply-adds a ping.

Each block makes ``THREADS`` output samples of :data:`CHANNELS_PER_THREAD` channels,
reading a chunk of the codes once into shared memory and the operator's rows once per
channel group, neighbouring threads from neighbouring addresses.
"""

from __future__ import annotations

import math

import numpy as np
from numba import cuda

from svss_daq.ping import SampleAxis

from ..conditioning import Conditioner
from .gpu_shared import THREADS
from .kernel_args import (INTERP, TAPS, KernelData, TapPlanes, phase_halvings, tap_phases,
                          tap_theta)

#: channels each thread sums its output sample for
CHANNELS_PER_THREAD = 8


@cuda.jit
def _condition(codes, n_codes, op_re, op_im, taps, ph_re, ph_im, ring, slot):
    t = cuda.threadIdx.x
    m = cuda.blockIdx.x * THREADS + t
    c0 = cuda.blockIdx.y * CHANNELS_PER_THREAD
    nch = codes.shape[0]
    n_out = op_re.shape[1]
    buf = cuda.shared.array((CHANNELS_PER_THREAD, THREADS), dtype=np.float64)
    acc_re = cuda.local.array(CHANNELS_PER_THREAD, dtype=np.float64)
    acc_im = cuda.local.array(CHANNELS_PER_THREAD, dtype=np.float64)
    for c in range(CHANNELS_PER_THREAD):
        acc_re[c] = 0.0
        acc_im[c] = 0.0
    for n0 in range(0, n_codes, THREADS):
        n = n0 + t
        for c in range(CHANNELS_PER_THREAD):
            v = 0.0
            if n < n_codes and c0 + c < nch:
                v = 1.0 * codes[c0 + c, n]
            buf[c, t] = v
        cuda.syncthreads()
        top = n_codes - n0                  # (no min(): its CUDA overload is compiled
        if top > THREADS:                   # for the current device, which PTX checks
            top = THREADS                   # without a GPU do not have)
        if m < n_out:
            for j in range(top):
                mr = op_re[n0 + j, m]
                mi = op_im[n0 + j, m]
                for c in range(CHANNELS_PER_THREAD):
                    x = buf[c, j]
                    acc_re[c] += x * mr
                    acc_im[c] += x * mi
        cuda.syncthreads()
    if m < n_out:
        for c in range(CHANNELS_PER_THREAD):
            ch = c0 + c
            if ch < nch:
                ar = acc_re[c]
                ai = acc_im[c]
                for i in range(taps.size):
                    k = taps[i]
                    j = m - k                      # plane i's sample j holds a[j + k]
                    if 0 <= j < n_out:
                        ring[slot, 0, i, ch, j] = ar * ph_re[i] - ai * ph_im[i]
                        ring[slot, 1, i, ch, j] = ar * ph_im[i] + ai * ph_re[i]
                    if m + k < 0 or m + k >= n_out:      # sample m of plane i: no a there
                        ring[slot, 0, i, ch, m] = 0.0
                        ring[slot, 1, i, ch, m] = 0.0


class DeviceConditioner:
    """A :class:`~svss_proc.conditioning.Conditioner` run on the device for
    interpolation ``interp`` in precision ``dtype``: :meth:`__call__` makes a ping's
    tap planes in a slot of a device ring."""

    def __init__(self, conditioner: Conditioner, interp: str, dtype):
        self.conditioner = conditioner
        op = conditioner.operator()
        self.n_in, self.n_out = op.shape
        self._op_re = cuda.to_device(np.ascontiguousarray(op.real))
        self._op_im = cuda.to_device(np.ascontiguousarray(op.imag))
        self.code = INTERP[interp]
        self.step_s = conditioner.output_axis().step_s
        self.theta = tap_theta(conditioner.fc, self.step_s)
        self.halvings = phase_halvings(self.theta)
        ph = tap_phases(self.code, self.theta)
        self._taps = cuda.to_device(np.asarray(TAPS[self.code], dtype=np.int64))
        self._ph_re = cuda.to_device(np.ascontiguousarray(ph.real))
        self._ph_im = cuda.to_device(np.ascontiguousarray(ph.imag))
        self.dtype = np.dtype(dtype)

    def plane_shape(self, n_channels: int) -> tuple[int, int, int]:
        """(taps, channels, samples) of a ping's planes."""
        return len(TAPS[self.code]), int(n_channels), self.n_out

    def accepts(self, samples: np.ndarray) -> bool:
        """Whether codes of this shape condition on the device (no longer than the
        configured window; a longer window conditions on the host)."""
        return samples.ndim == 2 and 0 < samples.shape[1] <= self.n_in

    def __call__(self, codes, n_codes: int, axis: SampleAxis | None, ring, slot: int,
                 stream) -> KernelData:
        """The tap planes of ``codes`` (a device array, channels x samples, the first
        ``n_codes`` samples used, on ``axis``: None for the configured window) made in
        ``ring[slot]`` by a launch on ``stream``; the kernel data naming them."""
        out = self.conditioner.output_axis(self.conditioner.checked_axis(axis))
        nch = codes.shape[0]
        grid = (math.ceil(self.n_out / THREADS), math.ceil(nch / CHANNELS_PER_THREAD))
        _condition[grid, THREADS, stream](codes, int(n_codes), self._op_re, self._op_im,
                                          self._taps, self._ph_re, self._ph_im, ring,
                                          int(slot))
        ft = self.dtype.type
        return KernelData(TapPlanes(ring[slot, 0], ring[slot, 1], ft(out.start_s),
                                    ft(1.0 / out.step_s), ft(self.theta)),
                          self.code, self.halvings)
