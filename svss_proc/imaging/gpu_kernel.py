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

from .delays import build_refraction
from .kernel_args import DelayModel, KernelData, check_call, kernel_args
from .kernel_math import build, kernel_one

_dev = cuda.jit(device=True)
_math = build(_dev, build_refraction(_dev))
_voxel_sum = _math.voxel_sum
THREADS = 128

_KERNELS: dict = {}


def _make_kernel(interp: int, mode: int, gating: bool, halvings: int):
    @cuda.jit
    def kernel(img_re, img_im, args, ia0, ia1, counts):
        i = cuda.grid(1)
        nc = args.geometry.cy.size
        nd = args.geometry.dz.size
        if i >= (ia1 - ia0) * nc * nd:
            return
        ia = ia0 + i // (nc * nd)
        rem = i % (nc * nd)
        ic = rem // nd
        iz = rem % nd
        one = kernel_one(args.planes.re)           # the kernel precision
        sr, si, n = _voxel_sum(args.geometry.ax[ia], args.geometry.cy[ic],
                               args.geometry.dz[iz], interp, mode, gating, halvings, args, one)
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


def _to_device(bundle):
    """A named bundle with its arrays copied to the GPU (nested bundles too)."""
    return type(bundle)(*(cuda.to_device(v) if isinstance(v, np.ndarray)
                          else _to_device(v) if isinstance(v, tuple) else v
                          for v in bundle))


def run_ping_gpu(img_re, img_im, kd: KernelData, tx, rx, along, cross, depth, ia0, ia1, *,
                 bore, cos_tx, cos_rx, delays: DelayModel, gating=True, apod=None) -> int:
    """GPU counterpart of :func:`svss_proc.imaging.cpu_kernel.run_ping`;
    ``img_re``/``img_im`` are device arrays (``cuda.to_device``) that accumulate across
    pings."""
    if kd.dtype != img_re.dtype:
        raise ValueError(f"kernel data is {kd.dtype}, the image planes are {img_re.dtype}")
    check_call(img_re, img_im, along, cross, depth, ia0, ia1)
    args = kernel_args(kd, tx, rx, along, cross, depth, bore=bore, cos_tx=cos_tx,
                       cos_rx=cos_rx, apod=apod, delays=delays)
    n = (ia1 - ia0) * cross.size * depth.size
    if n <= 0:
        return 0
    counts = cuda.device_array(n, dtype=np.int64)
    kernel = kernel_for(kd.interp, delays.code, gating, kd.halvings)
    kernel[math.ceil(n / THREADS), THREADS](img_re, img_im, _to_device(args), ia0, ia1,
                                            counts)
    return int(counts.copy_to_host().sum())
