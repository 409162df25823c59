"""Pass 2 of the point-scatterer synthesis on an NVIDIA GPU (numba-cuda).

The same echoes as :func:`sim_device.synthesis.accumulate_fast`, from the same scalar
functions: :func:`sim_device.synthesis.build` and :func:`sim_device.layered_rays.build`
compiled as CUDA device functions (the receive leg :func:`~sim_device.synthesis.leg`,
the echo phase ``cis_cycles32``, the Lagrange weights ``lagrange4``), so the leg physics
is written once for both targets.

One thread per (scatterer, channel), channel fastest, so that a warp holds one
scatterer's echoes on neighbouring channels: for each receive image some kept path needs
(``allowed[a, b]`` with a non-zero transmit leg and the scatterer above ``zmax[a, b]``)
the thread evaluates the receive leg (skipped when the straight line at the fastest
speed already puts the echo after the window), then adds every kept transmit image's
echo A exp(-j 2 pi f_c tau) at its fractional delay (4-tap Lagrange) into float32 real
and imaginary baseband planes laid out (sample, channel), by atomic adds (neighbouring
channels: neighbouring addresses). The leg arithmetic is float64, as on the CPU; only
the accumulation is float32, as in the CPU fast path's complex64 buffers, so the two
agree to float32 rounding (tests/sim/test_gpu_synthesis.py, under numba's CUDA
simulator, ``NUMBA_ENABLE_CUDASIM=1``). Pass 1 (:func:`~sim_device.synthesis.transmit_legs`)
stays on the CPU; its results go up once per ping.

:class:`GpuAccumulator` keeps its device buffers from ping to ping (grown when a ping
needs more, never shrunk) and uploads the scene's fixed tables (refraction, reflection,
beam and scattering-strength tables) once per table object. The echo count is reduced
per block on the device (one atomic add per block) by the imaging kernel's block sum
(:mod:`svss_proc.imaging.gpu_shared`: block size, block sum and device buffers written
once for both).
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np
from numba import config, cuda

from svss_daq.conventions import ECHO_PHASE_SIGN
from svss_proc.imaging.gpu_shared import THREADS, DeviceBuffers, block_count_for

from . import layered_rays, synthesis
from .synthesis import IMG_DIR, IMG_H, IMG_NB, IMG_RS, IMG_X, IMG_Y, MED_INTERFACE

log = logging.getLogger(__name__)

_dev = cuda.jit(device=True)
_rays = layered_rays.build(_dev, _dev)
_math = synthesis.build(_dev, _rays)
_leg = _math.leg
_interp = _math._interp
_cis = _math.cis_cycles32
_lagrange4 = _math.lagrange4
_greater = _rays._greater     # max(a, b) (numba.cuda cannot compile the builtin)

#: media a leg may cross (scratch arrays of the ray solver are this long, per thread)
MAX_MEDIA = 15
_HBUF = MAX_MEDIA + 1
#: the block sum of gpu_shared, compiled with this module's globals (simulator-safe)
block_count = block_count_for(globals())
#: blocks of the buffer-zeroing kernel (few under the CUDA simulator, a thread each)
ZERO_BLOCKS = 2 if config.ENABLE_CUDASIM else 512


def cuda_available() -> bool:
    """True where numba finds a CUDA GPU (or runs its CUDA simulator)."""
    try:
        return bool(cuda.is_available())
    except Exception:  # noqa: BLE001 (a broken driver reads as no GPU)
        return False


@cuda.jit
def _receive_kernel(sx, sy, sz, smed, tau_t, amp_t, img, allowed, zmax, c, rho_m, delta,
                    alpha, z_top, tab, r_top, r_bot, bore, g_front, g_back, sig, lo_front,
                    lo_back, sign, t_lo, t_hi, t_buf0, fs, cmax, buf_re, buf_im, count):
    """Receive legs and echoes of scatterer i // n_ch on channel i % n_ch (module
    docstring); ``count[0]`` gains the echoes added."""
    i = cuda.grid(1)
    part = cuda.shared.array(THREADS, dtype=np.int64)
    nch = img.shape[0]
    nr = img.shape[1]
    nt = tau_t.shape[1]
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
        for a in range(nt):
            if amp_t[k, a] != 0.0 and tau_t[k, a] < tmin:
                tmin = tau_t[k, a]
        for b in range(nr):
            need = False
            for a in range(nt):
                if allowed[a, b] and zk <= zmax[a, b] and amp_t[k, a] != 0.0:
                    need = True
            if not need:
                continue
            ex = img[ch, b, IMG_X]
            ey = img[ch, b, IMG_Y]
            hh = img[ch, b, IMG_H]
            # the straight line at the fastest speed bounds the receive delay
            dz = hh + _greater(zk, 0.0)
            dmin = math.sqrt((xk - ex) * (xk - ex) + (yk - ey) * (yk - ey) + dz * dz)
            if tmin + dmin / cmax >= t_hi:
                continue
            tau_r, a_r, cg = _leg(ex, ey, hh, img[ch, b, IMG_DIR], img[ch, b, IMG_RS],
                                  int(img[ch, b, IMG_NB]), xk, yk, zk, mk, True, c, rho_m,
                                  delta, alpha, z_top, tab, r_top, r_bot, bore, g_front,
                                  g_back, lo_front, lo_back, hbuf, cbuf)
            if a_r == 0.0:
                continue
            if mk == MED_INTERFACE:
                a_r *= _interp(sig, cg)
            for a in range(nt):
                if not allowed[a, b] or zk > zmax[a, b]:
                    continue
                a_t = amp_t[k, a]
                if a_t == 0.0:
                    continue
                tau = tau_t[k, a] + tau_r
                if tau <= t_lo or tau >= t_hi:
                    continue
                co, si = _cis(sign * tau)
                e = a_t * a_r * complex(co, si)
                u = (tau - t_buf0) * fs
                i1 = int(u)
                w0, w1, w2, w3 = _lagrange4(u - i1)
                er = e.real
                ei = e.imag
                cuda.atomic.add(buf_re, (i1 - 1, ch), np.float32(er * w0))
                cuda.atomic.add(buf_im, (i1 - 1, ch), np.float32(ei * w0))
                cuda.atomic.add(buf_re, (i1, ch), np.float32(er * w1))
                cuda.atomic.add(buf_im, (i1, ch), np.float32(ei * w1))
                cuda.atomic.add(buf_re, (i1 + 1, ch), np.float32(er * w2))
                cuda.atomic.add(buf_im, (i1 + 1, ch), np.float32(ei * w2))
                cuda.atomic.add(buf_re, (i1 + 2, ch), np.float32(er * w3))
                cuda.atomic.add(buf_im, (i1 + 2, ch), np.float32(ei * w3))
                n_add += 1
    block_count(part, n_add, count)                # the block's echoes, one atomic add


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


class GpuAccumulator:
    """:func:`sim_device.synthesis.accumulate_fast` on the GPU, with device buffers
    reused from ping to ping. Raises RuntimeError where no GPU is present."""

    def __init__(self, source: str = "scattering.device"):
        if not cuda_available():
            raise RuntimeError(f"{source} = 'cuda': no CUDA GPU is available to numba "
                               "(install the 'gpu' extra, numba-cuda, on a machine with an "
                               "NVIDIA GPU, or set it to 'cpu')")
        self._buffers: dict[str, object] = {}
        self._rows = DeviceBuffers()     # the per-scatterer inputs, by role
        self._tables: dict[str, tuple[np.ndarray, object]] = {}
        self.last_times: dict[str, float] = {}

    def _upload(self, role: str, host: np.ndarray, dtype) -> object:
        """``host`` in the device buffer of ``role`` (grown to 5/4 of the need when too
        small); returns the device view of its shape."""
        return self._rows.upload_rows(role, host, dtype)

    def _table(self, role: str, host: np.ndarray, dtype) -> object:
        """A scene table on the device, uploaded again only for another table object."""
        held = self._tables.get(role)
        if held is not None and held[0] is host:
            return held[1]
        d = cuda.to_device(np.ascontiguousarray(host, dtype=dtype))
        self._tables[role] = (host, d)
        return d

    def _planes(self, n_buf: int, nch: int):
        d = self._buffers.get("planes")
        if d is None or d[0].shape != (n_buf, nch):
            d = (cuda.device_array((n_buf, nch), np.float32),
                 cuda.device_array((n_buf, nch), np.float32),
                 cuda.device_array(1, np.int64))
            self._buffers["planes"] = d
        return d

    def __call__(self, sx, sy, sz, smed, tau_t, amp_t, img, allowed, c, rho_m, delta,
                 alpha, z_top, tab, r_top, r_bot, bore, g_front, g_back, lo_front, lo_back,
                 sig, fc, t_lo, t_hi, t_buf0, fs, n_buf, zmax):
        """Arguments as :func:`~sim_device.synthesis.accumulate_fast` (no block count).
        Returns (buffer (n_channels, n_buf) complex128, echoes added (1,) int64)."""
        if c.size > MAX_MEDIA:
            raise ValueError(f"{c.size} media: the GPU synthesis handles at most {MAX_MEDIA}")
        arrays, scalars = kernel_inputs(sx, sy, sz, smed, tau_t, amp_t, img, allowed, c,
                                        rho_m, delta, alpha, z_top, tab, r_top, r_bot, bore,
                                        g_front, g_back, lo_front, lo_back, sig, fc, t_lo,
                                        t_hi, t_buf0, fs, zmax)
        t0 = time.perf_counter()
        dev = [self._table(role, host, dtype) if fixed else self._upload(role, host, dtype)
               for role, host, dtype, fixed in arrays]
        nch = img.shape[0]
        buf_re, buf_im, count = self._planes(int(n_buf), nch)
        _zero[ZERO_BLOCKS, THREADS](buf_re, buf_im, count)
        cuda.synchronize()
        t1 = time.perf_counter()
        n_threads = sx.size * nch
        if n_threads:
            _receive_kernel[(n_threads + THREADS - 1) // THREADS, THREADS](
                *dev, *scalars, buf_re, buf_im, count)
        cuda.synchronize()
        t2 = time.perf_counter()
        out = np.empty((nch, int(n_buf)), dtype=np.complex128)
        out.real = buf_re.copy_to_host().T
        out.imag = buf_im.copy_to_host().T
        n = count.copy_to_host()
        #: seconds of the last call: uploads and zeroing, the receive kernel, read-back
        self.last_times = {"upload_s": t1 - t0, "kernel_s": t2 - t1,
                           "download_s": time.perf_counter() - t2}
        return out, n


def kernel_inputs(sx, sy, sz, smed, tau_t, amp_t, img, allowed, c, rho_m, delta, alpha,
                  z_top, tab, r_top, r_bot, bore, g_front, g_back, lo_front, lo_back, sig,
                  fc, t_lo, t_hi, t_buf0, fs, zmax):
    """The receive kernel's inputs from :func:`~sim_device.synthesis.accumulate_fast`'s:
    (role, host array, kernel dtype, fixed scene table?) of its arrays in order, and its
    scalars (float64), before the output planes."""
    f8, c16 = np.float64, np.complex128
    arrays = [("sx", sx, f8, False), ("sy", sy, f8, False), ("sz", sz, f8, False),
              ("smed", smed, np.int64, False), ("tau_t", tau_t, f8, False),
              ("amp_t", amp_t, c16, False), ("img", img, f8, False),
              ("allowed", allowed, np.bool_, False), ("zmax", zmax, f8, False),
              ("c", c, f8, False), ("rho_m", rho_m, f8, False), ("delta", delta, f8, False),
              ("alpha", alpha, f8, False), ("z_top", z_top, f8, False),
              ("tab", tab, f8, True), ("r_top", r_top, c16, True),
              ("r_bot", r_bot, c16, True), ("bore", bore, f8, False),
              ("g_front", g_front, f8, True), ("g_back", g_back, f8, True),
              ("sig", sig, f8, True)]
    scalars = tuple(float(v) for v in (lo_front, lo_back, ECHO_PHASE_SIGN * fc, t_lo, t_hi,
                                       t_buf0, fs, np.max(c)))
    return arrays, scalars


def kernel_signature(*args):
    """numba types of the receive kernel's arguments for :func:`kernel_inputs`'s
    arguments (for ``cuda.compile_ptx``, which needs no GPU)."""
    import numba
    arrays, scalars = kernel_inputs(*args)
    plane = numba.types.Array(numba.types.float32, 2, "C")
    return (tuple(numba.types.Array(numba.from_dtype(np.dtype(dt)), np.ndim(h), "C")
                  for _, h, dt, _ in arrays)
            + (numba.types.float64,) * len(scalars)
            + (plane, plane, numba.types.Array(numba.types.int64, 1, "C")))
