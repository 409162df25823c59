"""Pass 2 of the point-scatterer synthesis on an NVIDIA GPU (numba-cuda).

The same echoes as :func:`sim_device.synthesis_fast.accumulate_fast`, from the same scalar
functions: :func:`sim_device.synthesis_legs.build` and :func:`sim_device.layered_rays.build`
compiled as CUDA device functions (the receive leg :func:`~sim_device.synthesis_legs.leg`,
the echo phase ``cis_cycles32``, the Lagrange weights ``lagrange4``), so the leg physics
is written once for both targets.

The kernel takes the bundles of :mod:`sim_device.synthesis_args`, :class:`GpuAccumulator`
pass 2's as one :class:`~sim_device.synthesis_args.Pass2`. One thread per
(scatterer, channel), channel fastest, so that a warp holds one scatterer's echoes on
neighbouring channels: each thread runs the echo loop of :mod:`sim_device.echo_loop` (the
reference CPU kernel's loop) for its scatterer and channel, adding every echo
A exp(-j 2 pi f_c tau) at its fractional delay (4-tap Lagrange) into float32 real and
imaginary baseband planes laid out (sample, channel), by atomic adds (neighbouring
channels: neighbouring addresses). The leg arithmetic is float64, as on the CPU; only
the accumulation is float32, as in the CPU fast path's complex64 buffers, so the two
agree to float32 rounding (tests/sim/test_gpu_synthesis.py, under numba's CUDA
simulator, ``NUMBA_ENABLE_CUDASIM=1``). Pass 1 (:func:`~sim_device.synthesis.transmit_legs`)
stays on the CPU; its results go up once per ping.

:class:`GpuAccumulator` keeps its device buffers from ping to ping (grown when a ping
needs more, never shrunk) and uploads the scene's fixed tables (refraction, reflection,
beam and scattering-strength tables) once per table object, and the echo count is reduced
per block on the device (one atomic add per block): the buffer cache and the block sum
of :mod:`svss_daq.gpu_shared`, which the imaging GPU kernel uses too (it sits below
both: the simulator imports nothing of the processing).
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import numba
import numpy as np
from numba import config, cuda

from svss_daq.gpu_shared import THREADS, DeviceBuffers, block_count_for

from . import echo_loop, layered_rays, synthesis_legs
from .synthesis_args import Pass2

_dev = cuda.jit(device=True)
_rays = layered_rays.build(_dev, _dev)
_math = synthesis_legs.build(_dev, _rays, math.floor)
_block_count = block_count_for(globals())

#: media a leg may cross (scratch arrays of the ray solver are this long, per thread)
MAX_MEDIA = 15
_HBUF = MAX_MEDIA + 1
#: blocks of the buffer-zeroing kernel (few under the CUDA simulator, a thread each)
ZERO_BLOCKS = 2 if config.ENABLE_CUDASIM else 512


class EchoPlanes(NamedTuple):
    """The baseband buffer on the device: float32 real and imaginary planes laid out
    (sample, channel)."""
    re: object
    im: object


@cuda.jit(device=True)
def _deposit(planes, ch, i1, e, w0, w1, w2, w3):
    """One echo into the planes by atomic adds (float32)."""
    er = e.real
    ei = e.imag
    cuda.atomic.add(planes.re, (i1 - 1, ch), np.float32(er * w0))
    cuda.atomic.add(planes.im, (i1 - 1, ch), np.float32(ei * w0))
    cuda.atomic.add(planes.re, (i1, ch), np.float32(er * w1))
    cuda.atomic.add(planes.im, (i1, ch), np.float32(ei * w1))
    cuda.atomic.add(planes.re, (i1 + 1, ch), np.float32(er * w2))
    cuda.atomic.add(planes.im, (i1 + 1, ch), np.float32(ei * w2))
    cuda.atomic.add(planes.re, (i1 + 2, ch), np.float32(er * w3))
    cuda.atomic.add(planes.im, (i1 + 2, ch), np.float32(ei * w3))


_echo = echo_loop.build(_dev, _math, _math.cis_cycles32, _deposit)
_fastest = _echo.fastest
_receive_needed = _echo.receive_needed
_image_echoes = _echo.image_echoes


def cuda_available() -> bool:
    """True where numba finds a CUDA GPU (or runs its CUDA simulator)."""
    try:
        return bool(cuda.is_available())
    except Exception:  # noqa: BLE001 (a broken driver reads as no GPU)
        return False


@cuda.jit
def _receive_kernel(pts, legs_t, paths, medium, beam, win, planes, count):
    """Receive legs and echoes of scatterer i // n_ch on channel i % n_ch (module
    docstring; the bundles of :mod:`sim_device.synthesis_args`, ``planes`` an
    :class:`EchoPlanes`); ``count[0]`` gains the echoes added."""
    i = cuda.grid(1)
    part = cuda.shared.array(THREADS, dtype=np.int64)
    # the bundles unpacked once, as in the CPU kernels (the echo loop takes arrays)
    sx, sy, sz, smed = pts
    tau_t, amp_t = legs_t
    img, allowed, zmax = paths
    c, rho_m, delta, alpha, z_top, tab, r_top, r_bot, sig = medium
    bore, g_front, g_back, lo_front, lo_back = beam
    nch = img.shape[0]
    n_add = 0
    if i < sx.size * nch:
        k = i // nch
        ch = i % nch
        hbuf = cuda.local.array(_HBUF, dtype=np.float64)
        cbuf = cuda.local.array(2, dtype=np.float64)
        xk = sx[k]
        yk = sy[k]
        zk = sz[k]
        mk = smed[k]
        tmin = math.inf
        for a in range(tau_t.shape[1]):
            if amp_t[k, a] != 0.0 and tau_t[k, a] < tmin:
                tmin = tau_t[k, a]
        cmax = _fastest(c)
        for b in range(img.shape[1]):
            if _receive_needed(amp_t, allowed, zmax, k, b, zk):
                n_add += _image_echoes(k, ch, b, (xk, yk, zk, mk), tmin, img, tau_t,
                                       amp_t, allowed, zmax, c, rho_m, delta, alpha, z_top,
                                       tab, r_top, r_bot, sig, bore, g_front, g_back,
                                       lo_front, lo_back, win, cmax, hbuf, cbuf, planes)
    _block_count(part, n_add, count)         # the block's echoes, one atomic add


@cuda.jit
def _zero(buf_re, buf_im, count):
    """Zero both planes (n_buf, n_ch) and the count (grid-stride loop)."""
    i = cuda.grid(1)
    stride = cuda.gridsize(1)
    n = buf_re.shape[1]
    for j in range(i, buf_re.size, stride):
        buf_re[j // n, j % n] = 0.0
        buf_im[j // n, j % n] = 0.0
    if i == 0:
        count[0] = 0


_F8, _C16 = np.float64, np.complex128
#: the kernel's dtype of each array of the bundles, by field name
_DTYPES = {"x": _F8, "y": _F8, "z": _F8, "med": np.int64, "tau": _F8, "amp": _C16,
           "img": _F8, "allowed": np.bool_, "zmax": _F8, "c": _F8, "rho": _F8,
           "delta": _F8, "alpha": _F8, "z_top": _F8, "tab": _F8, "r_top": _C16,
           "r_bot": _C16, "sig": _F8, "bore": _F8, "front": _F8, "back": _F8}
#: the scene's fixed tables: uploaded once per table object
_FIXED = frozenset({"tab", "r_top", "r_bot", "sig", "front", "back"})


def _converted(bundle, array):
    """``bundle`` (a NamedTuple) with each array field passed through
    ``array(role, field, host, dtype)`` and each scalar as a float."""
    kind = type(bundle)
    return kind(*(array(f"{kind.__name__}.{name}", name, v, _DTYPES[name])
                  if isinstance(v, np.ndarray) else float(v)
                  for name, v in zip(bundle._fields, bundle)))


class GpuAccumulator:
    """:func:`sim_device.synthesis_fast.accumulate_fast` on the GPU, with device buffers
    reused from ping to ping. Raises RuntimeError where no GPU is present."""

    def __init__(self, source: str = "scattering.device"):
        if not cuda_available():
            raise RuntimeError(f"{source} = 'cuda': no CUDA GPU is available to numba "
                               "(install the 'gpu' extra, numba-cuda, on a machine with an "
                               "NVIDIA GPU, or set it to 'cpu')")
        self._buffers = DeviceBuffers()
        self.last_times: dict[str, float] = {}

    def _device(self, role, name, host, dtype):
        if name in _FIXED:
            return self._buffers.table(host, dtype)
        return self._buffers.upload_rows(role, host, dtype)

    def __call__(self, p2: Pass2, n_buf: int):
        """Pass 2 of the bundles ``p2`` into a buffer of ``n_buf`` samples (as
        :func:`~sim_device.synthesis_fast.accumulate_fast`, no block count). Returns
        (buffer (n_channels, n_buf) complex128, echoes added (1,) int64)."""
        pts, paths, medium = p2.pts, p2.paths, p2.medium
        if medium.c.size > MAX_MEDIA:
            raise ValueError(f"{medium.c.size} media: the GPU synthesis handles at most "
                             f"{MAX_MEDIA}")
        t0 = time.perf_counter()
        dev = [_converted(b, self._device) for b in p2]
        nch = paths.img.shape[0]
        n_buf = int(n_buf)
        planes = EchoPlanes(self._buffers.array("planes.re", (n_buf, nch), np.float32),
                            self._buffers.array("planes.im", (n_buf, nch), np.float32))
        count = self._buffers.array("count", (1,), np.int64)
        _zero[ZERO_BLOCKS, THREADS](planes.re, planes.im, count)
        cuda.synchronize()
        t1 = time.perf_counter()
        n_threads = pts.x.size * nch
        if n_threads:
            _receive_kernel[(n_threads + THREADS - 1) // THREADS, THREADS](
                *dev, planes, count)
        cuda.synchronize()
        t2 = time.perf_counter()
        out = np.empty((nch, n_buf), dtype=np.complex128)
        out.real = planes.re.copy_to_host().T
        out.imag = planes.im.copy_to_host().T
        n = count.copy_to_host()
        #: seconds of the last call: uploads and zeroing, the receive kernel, read-back
        self.last_times = {"upload_s": t1 - t0, "kernel_s": t2 - t1,
                           "download_s": time.perf_counter() - t2}
        return out, n


def kernel_signature(p2: Pass2):
    """numba types of the receive kernel's arguments for pass 2's bundles ``p2`` (for
    ``cuda.compile_ptx``, which needs no GPU)."""
    host = [_converted(b, lambda role, name, v, dt: np.ascontiguousarray(v, dtype=dt))
            for b in p2]
    plane = np.empty((1, 1), dtype=np.float32)
    return (tuple(numba.typeof(b) for b in host)
            + (numba.typeof(EchoPlanes(plane, plane)),
               numba.types.Array(numba.types.int64, 1, "C")))
