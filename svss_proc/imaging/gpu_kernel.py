"""The backprojection kernel on an NVIDIA GPU (numba-cuda): one thread per voxel.

It computes the same sum as the CPU kernel (:mod:`svss_proc.imaging.cpu_kernel`) from the same
scalar building blocks (:mod:`svss_proc.imaging.kernel_math`, compiled as CUDA device functions).
Tile image planes stay on the device while a tile forms. On machines without a GPU it
runs under numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``), which the tests use on
small grids.

Per ping (issue 16): the tap planes go up in one copy when they share one buffer (as
:func:`~svss_proc.imaging.kernel_args.prepare` makes them) and the voxel and element
geometry in one more, both into device buffers reused from ping to ping (no allocation
per ping); the refraction table is uploaded once per table. The launch covers only the
voxel columns the projector cone can reach (the along-track range the imager gives and
the cross-track range of the cone at the tile's deepest voxel); the update count is
reduced on the device (a block sum, one atomic add per block) into a counter that the
imager reads once per tile, so that no ping waits for its kernel (``count=``). With
table delays the kernel reads the table already interpolated at the tile's voxel depths
(:func:`~svss_proc.imaging.kernel_args.depth_table`, uploaded once per table): per
channel a linear look-up in offset, in the kernel precision, from neighbouring addresses
for neighbouring threads (the table is C order, depth fastest).
Float32 planes keep every operation in float32 (:func:`~svss_proc.imaging.kernel_math.kernel_one`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import cuda

from svss_daq.geometry import cone_reach

from .delays import build_refraction
from .kernel_args import (ConeGate, DelayModel, ImageSlice, KernelArgs, KernelData,
                          PingArray, TapPlanes, TravelTimes, VoxelGeometry, check_call,
                          kernel_args)
from .kernel_math import build, kernel_one
from .gpu_shared import THREADS, DeviceBuffers, block_count_for
from .gpu_staging import on_device

_dev = cuda.jit(device=True)
_math = build(_dev, build_refraction(_dev))
_voxel_sum = _math.voxel_sum
block_count = block_count_for(globals())     # the block sum (gpu_shared)

_KERNELS: dict = {}


def _make_kernel(interp: int, mode: int, gating: bool, halvings: int):
    @cuda.jit
    def kernel(img_re, img_im, args, ia0, ia1, ic0, ic1, count):
        i = cuda.grid(1)
        nc = ic1 - ic0
        nd = args.geometry.dz.size
        part = cuda.shared.array(THREADS, dtype=np.int64)
        n = 0
        if i < (ia1 - ia0) * nc * nd:
            ia = ia0 + i // (nc * nd)
            rem = i % (nc * nd)
            ic = ic0 + rem // nd
            iz = rem % nd
            one = kernel_one(args.planes.re)       # the kernel precision
            sr, si, n = _voxel_sum(ia, ic, iz, interp, mode, gating, halvings, args, one)
            img_re[ia, ic, iz] += sr               # each thread owns its voxel
            img_im[ia, ic, iz] += si
        block_count(part, n, count)                # the block's updates, one atomic add

    return kernel


@cuda.jit
def _zero(flat):
    i = cuda.grid(1)
    if i < flat.size:
        flat[i] = 0


def device_zeros(shape, dtype) -> "cuda.devicearray.DeviceNDArray":
    """A zeroed array on the GPU (a tile's image plane or coverage volume), zeroed
    there: no host array is made or uploaded (a tile's four volumes are 90 MB)."""
    d = cuda.device_array(shape, dtype=dtype)
    if d.size:
        _zero[math.ceil(d.size / THREADS), THREADS](d.reshape(d.size))
    return d


def kernel_for(interp: int, mode: int, gating: bool, halvings: int):
    key = (interp, mode, bool(gating), int(halvings))
    if key not in _KERNELS:
        _KERNELS[key] = _make_kernel(*key)
    return _KERNELS[key]


_BUFFERS = DeviceBuffers()


def _planes_to_device(p: TapPlanes) -> TapPlanes:
    """Tap planes on the device: one copy when re and im are the two halves of one
    buffer, two otherwise."""
    if on_device(p.re):                 # made on the device
        return p
    base = p.re.base
    if (base is not None and base is p.im.base and base.flags.c_contiguous
            and base.shape == (2,) + p.re.shape and np.shares_memory(base[0], p.re)
            and np.shares_memory(base[1], p.im)):
        dev = _BUFFERS.upload("planes", base)
        cached = _BUFFERS.views.get("planes")
        if cached is None:
            cached = _BUFFERS.views["planes"] = (None, [dev[0], dev[1]])
        re, im = cached[1]
    else:
        re, im = _BUFFERS.upload("planes_re", p.re), _BUFFERS.upload("planes_im", p.im)
    return TapPlanes(re, im, p.t0, p.inv_dt, p.theta)


def _geometry_to_device(g: VoxelGeometry) -> VoxelGeometry:
    """The voxel and element arrays on the device in one copy (one host buffer, device
    views of it)."""
    ax, cy, dz, rx_dx, rx_dy, rx_h, apod, bore = _BUFFERS.upload_parts(
        "geometry", (g.ax, g.cy, g.dz, g.rx_dx, g.rx_dy, g.rx_h, g.apod, g.bore))
    return VoxelGeometry(ax, cy, dz, g.h_tx, rx_dx, rx_dy, rx_h, apod, bore, g.cos_tx,
                         g.cos_rx, _BUFFERS.table(g.surf))


def _gate_to_device(c: ConeGate) -> ConeGate:
    """The float64 cone geometry on the device in one copy."""
    ax, cy, dz, rx_dx, rx_dy, rx_h, bore = _BUFFERS.upload_parts(
        "gate", (c.ax, c.cy, c.dz, c.rx_dx, c.rx_dy, c.rx_h, c.bore))
    return ConeGate(ax, cy, dz, c.h_tx, rx_dx, rx_dy, rx_h, bore, c.cos_tx, c.cos_rx,
                    _BUFFERS.table(c.surf))


def _delays_to_device(d: TravelTimes) -> TravelTimes:
    """The travel-time model with its tables on the device (each uploaded once)."""
    return TravelTimes(d.inv_cw, d.cw, d.cs, _BUFFERS.table(d.time),
                       _BUFFERS.table(d.eta), d.inv_drho, d.z0, d.inv_dz, d.h_ref,
                       _BUFFERS.table(d.tz), _BUFFERS.table(d.ez), _BUFFERS.table(d.kappa),
                       _BUFFERS.table(d.kz))


def _to_device(args: KernelArgs) -> KernelArgs:
    return KernelArgs(_planes_to_device(args.planes), _geometry_to_device(args.geometry),
                      _delays_to_device(args.delays), _gate_to_device(args.gate))


def cross_range(args: KernelArgs, gating: bool) -> tuple[int, int]:
    """The cross-track voxel range ic0..ic1 the projector cone can reach at the tile's
    deepest voxel (all of it without gating), one voxel to spare on either side."""
    g = args.geometry
    nc = g.cy.size
    if not gating or nc == 0:
        return 0, nc
    cy = np.asarray(g.cy, dtype=np.float64)
    bore = np.asarray(g.bore, dtype=np.float64)
    half = math.acos(min(1.0, max(-1.0, float(g.cos_tx))))
    tilt = math.acos(min(1.0, max(-1.0, float(bore[2]))))
    if half + tilt >= math.radians(89.0):           # past the cone's flattest edge
        return 0, nc
    reach = cone_reach(float(np.max(g.dz)) + float(g.h_tx), float(bore[2]), half)
    inside = np.flatnonzero(np.abs(cy) <= reach)
    if inside.size == 0:
        return 0, 0
    return max(int(inside[0]) - 1, 0), min(int(inside[-1]) + 2, nc)


def device_counter() -> "cuda.devicearray.DeviceNDArray":
    """A zeroed int64 update counter on the GPU, for ``run_ping_gpu(count=)``."""
    return cuda.to_device(np.zeros(1, dtype=np.int64))


def run_ping_gpu(out: ImageSlice, kd: KernelData, array: PingArray, delays: DelayModel, *,
                 gating: bool = True, count=None) -> int | None:
    """GPU counterpart of :func:`svss_proc.imaging.cpu_kernel.run_ping`; the image planes
    of ``out`` are device arrays (:func:`device_zeros`) that accumulate across pings.
    ``count``: a device counter (:func:`device_counter`) the updates are added into, and
    the call returns None without waiting for the kernel; None: the call waits and
    returns the updates."""
    if kd.dtype != out.re.dtype:
        raise ValueError(f"kernel data is {kd.dtype}, the image planes are {out.re.dtype}")
    check_call(out)
    args = kernel_args(kd, array, out.axes, delays)
    ic0, ic1 = cross_range(args, gating)
    ia0, ia1 = out.ia0, out.ia1
    n = (ia1 - ia0) * (ic1 - ic0) * len(out.axes.depth)
    deferred = count is not None
    if n <= 0:
        return None if deferred else 0
    if not deferred:
        count = _BUFFERS.upload("count", np.zeros(1, dtype=np.int64))
    kernel = kernel_for(kd.interp, delays.code, gating, kd.halvings)
    kernel[math.ceil(n / THREADS), THREADS](out.re, out.im, _to_device(args), ia0, ia1,
                                            ic0, ic1, count)
    return None if deferred else int(count.copy_to_host()[0])
