"""The backprojection kernel on an NVIDIA GPU (numba-cuda): one thread per voxel.

It computes the same sum as the CPU kernel (:mod:`svss_proc.imaging.cpu_kernel`) from the same
scalar building blocks (:mod:`svss_proc.imaging.kernel_math`, compiled as CUDA device functions).
Tile image planes stay on the device while a tile forms. On machines without a GPU it
runs under numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``), which the tests use on
small grids.
"""

from __future__ import annotations

import math

import numpy as np
from numba import cuda

from .cpu_kernel import DELAY, KernelData, geometry_args
from .kernel_math import build
from .delays import TravelTimeTable, build_refraction

_dev = cuda.jit(device=True)
_math = build(_dev, build_refraction(_dev))
_voxel_sum = _math.voxel_sum
THREADS = 128

_KERNELS: dict = {}


def _make_kernel(interp: int, mode: int, gating: bool, halvings: int):
    @cuda.jit
    def kernel(img_re, img_im, re, im, t0, inv_dt, theta, ax, cy, dz, h_tx, rx_dx, rx_dy,
               rx_h, apod, bore, cos_tx, cos_rx, inv_c, cw, cs, ttab, etab, inv_drho, tz0,
               inv_dz, h_ref, ia0, ia1, counts):
        i = cuda.grid(1)
        nc = cy.size
        nd = dz.size
        if i >= (ia1 - ia0) * nc * nd:
            return
        ia = ia0 + i // (nc * nd)
        rem = i % (nc * nd)
        ic = rem // nd
        iz = rem % nd
        one = re[0, 0, 0] * 0 + 1
        sr, si, n = _voxel_sum(ax[ia], cy[ic], dz[iz], interp, mode, gating, halvings, re, im,
                               t0, inv_dt, theta, h_tx, rx_dx, rx_dy, rx_h, apod, bore, cos_tx,
                               cos_rx, inv_c, cw, cs, ttab, etab, inv_drho, tz0, inv_dz, h_ref,
                               one)
        img_re[ia, ic, iz] += sr                   # each thread owns its voxel
        img_im[ia, ic, iz] += si
        counts[i] = n

    return kernel


def device_zeros(shape, dtype) -> "cuda.devicearray.DeviceNDArray":
    """A zeroed image plane on the GPU."""
    return cuda.to_device(np.zeros(shape, dtype=dtype))


def kernel_for(interp: int, mode: int, gating: bool, halvings: int):
    key = (interp, mode, bool(gating), int(halvings))
    if key not in _KERNELS:
        _KERNELS[key] = _make_kernel(*key)
    return _KERNELS[key]


def run_ping_gpu(img_re, img_im, kd: KernelData, tx, rx, along, cross, depth, ia0, ia1, *,
                 bore, cos_tx, cos_rx, gating=True, apod=None, mode="straight", c=1500.0,
                 cw=1500.0, cs=1500.0, table: TravelTimeTable | None = None) -> int:
    """GPU counterpart of :func:`svss_proc.imaging.cpu_kernel.run_ping`; ``img_re``/``img_im``
    are device arrays (``cuda.to_device``) that accumulate across pings."""
    args = geometry_args(img_re.dtype.type, kd, tx, rx, along, cross, depth, bore=bore,
                         cos_tx=cos_tx, cos_rx=cos_rx, apod=apod, mode=mode, c=c, cw=cw,
                         cs=cs, table=table)
    n = (ia1 - ia0) * cross.size * depth.size
    if n <= 0:
        return 0
    counts = cuda.device_array(n, dtype=np.int64)
    dev = [cuda.to_device(a) if isinstance(a, np.ndarray) else a for a in args]
    kernel = kernel_for(kd.interp, DELAY[mode], gating, kd.halvings)
    kernel[math.ceil(n / THREADS), THREADS](img_re, img_im, *dev, ia0, ia1, counts)
    return int(counts.copy_to_host().sum())
