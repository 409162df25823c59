"""The reference path of the point-scatterer synthesis (``[scattering] synthesis =
"reference"``): pass 1 by the scalar leg per scatterer and projector image
(:func:`transmit_kernel`) and pass 2 parallel over channels (:func:`accumulate_kernel`),
each channel streaming every scatterer through :mod:`sim_device.echo_loop`'s loop (the
GPU kernel's) into a complex128 buffer, so that no two threads write the same buffer.

The kernels take the bundles of :mod:`sim_device.synthesis_args`; :func:`accumulate`
takes pass 2's bundles as one :class:`~sim_device.synthesis_args.Pass2`. The same
kernels over another leg function (the undulating interface's,
:mod:`sim_device.synthesis_curved`) are :func:`kernels_over`'s.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from . import echo_loop
from .synthesis_args import Pass2
from .synthesis_legs import _cpu, cis_cycles, renamed


@nb.njit(cache=True, inline="always")
def _deposit(buf, ch, i1, e, w0, w1, w2, w3):
    """One echo into the reference kernel's complex buffer (channel, sample)."""
    buf[ch, i1 - 1] += e * w0
    buf[ch, i1] += e * w1
    buf[ch, i1 + 1] += e * w2
    buf[ch, i1 + 2] += e * w3


_echo = echo_loop.build(nb.njit(cache=True, inline="always"), _cpu, cis_cycles, _deposit)
receive_needed = _echo.receive_needed
path_kept = _echo.path_kept
transmit_leg = _echo.transmit_leg
_fastest = _echo.fastest
_image_echoes = _echo.image_echoes


@nb.njit(parallel=True, cache=True)
def transmit_kernel(pts, samp, img, medium, beam, out):
    """Pass 1: every scatterer's transmit legs (``pts``: :class:`Points`), one per
    projector image (rows of ``img``), into ``out`` (:class:`TransmitLegs`). ``samp``:
    scatterer strengths (source level, xi, sqrt(sigma dV) or the point's amplitude);
    ``medium.sig``: sigma^(1/4) of the interface over cos(grazing)."""
    # the bundles unpacked here, outside the loops (docs/simulator.md, "Bundled kernels
    # and speed"); the outputs as locals: numba's parallel loops do not write through a
    # tuple's arrays
    sx, sy, sz, smed = pts
    c, rho_m, delta, alpha, z_top, tab, r_top, r_bot, sig = medium
    bore, g_front, g_back, lo_front, lo_back = beam
    tau_out, amp_out = out
    ns = sx.size
    nt = img.shape[0]
    nmed = c.size
    chunk = 1024
    for q in nb.prange((ns + chunk - 1) // chunk):
        hbuf = np.empty(nmed + 1)
        cbuf = np.empty(2)
        for k in range(q * chunk, min(ns, (q + 1) * chunk)):
            for m in range(nt):
                transmit_leg(k, m, img, sx, sy, sz, smed, samp, c, rho_m, delta, alpha,
                             z_top, tab, r_top, r_bot, sig, bore, g_front, g_back,
                             lo_front, lo_back, hbuf, cbuf, tau_out, amp_out)


@nb.njit(cache=True)
def receive_plan(tau_t, amp_t, allowed, zmax, sz, nr):
    """Per scatterer, once for all channels (the reference kernels' pass 2): its earliest
    transmit delay (inf: no transmit leg) and the receive images (``nr`` of them) some
    kept path needs."""
    ns = sz.size
    tmin = np.full(ns, math.inf)
    need = np.zeros((ns, nr), dtype=np.bool_)
    for k in range(ns):
        for a in range(tau_t.shape[1]):
            if amp_t[k, a] != 0.0:
                tmin[k] = min(tmin[k], tau_t[k, a])
        for b in range(nr):
            need[k, b] = receive_needed(amp_t, allowed, zmax, k, b, sz[k])
    return tmin, need


@nb.njit(parallel=True, cache=True)
def accumulate_kernel(pts, legs_t, paths, medium, beam, win, buf):
    """Pass 2: for each channel (in parallel), every scatterer's receive legs (rows
    ``paths.img[ch]``) combined with its transmit legs (``legs_t``) on the kept paths;
    echoes with delay in (t_lo, t_hi) of ``win`` are added to ``buf[ch]`` (complex
    baseband, sample 0 at ``win.t_buf0``, rate ``win.fs``) as A exp(-j 2 pi fc tau) at
    their fractional delay (cubic Lagrange): :mod:`sim_device.echo_loop`'s loop, as on
    the GPU. Returns the number of echoes added per channel."""
    # the bundles unpacked here, outside the loops (docs/simulator.md, "Bundled kernels
    # and speed")
    sx, sy, sz, smed = pts
    tau_t, amp_t = legs_t
    img, allowed, zmax = paths
    c, rho_m, delta, alpha, z_top, tab, r_top, r_bot, sig = medium
    bore, g_front, g_back, lo_front, lo_back = beam
    nch = img.shape[0]
    nr = img.shape[1]
    ns = sx.size
    nmed = c.size
    cmax = _fastest(c)
    tmin, need = receive_plan(tau_t, amp_t, allowed, zmax, sz, nr)
    counts = np.zeros(nch, dtype=np.int64)
    for ch in nb.prange(nch):
        hbuf = np.empty(nmed + 1)
        cbuf = np.empty(2)
        n_add = 0
        for k in range(ns):
            if tmin[k] == math.inf:
                continue
            for b in range(nr):
                if need[k, b]:
                    n_add += _image_echoes(k, ch, b, (sx[k], sy[k], sz[k], smed[k]),
                                           tmin[k], img, tau_t, amp_t, allowed, zmax, c,
                                           rho_m, delta, alpha, z_top, tab, r_top, r_bot,
                                           sig, bore, g_front, g_back, lo_front, lo_back,
                                           win, cmax, hbuf, cbuf, buf)
        counts[ch] = n_add
    return counts


def accumulate(p2: Pass2, buf: np.ndarray) -> np.ndarray:
    """:func:`accumulate_kernel` of pass 2's bundles into ``buf`` (complex, channels by
    samples). Returns the echoes added per channel."""
    return accumulate_kernel(*p2, buf)


def kernels_over(echo, prefix: str):
    """:func:`transmit_kernel` and :func:`accumulate_kernel` compiled over another leg
    function: ``echo``, :func:`sim_device.echo_loop.build`'s namespace for it (its
    ``transmit_leg``, ``image_echoes`` and ``fastest`` in place of this module's), named
    ``prefix_transmit_kernel`` and ``prefix_accumulate_kernel`` (their own entries in
    numba's cache)."""
    over = {"transmit_leg": echo.transmit_leg, "_image_echoes": echo.image_echoes,
            "_fastest": echo.fastest}
    return tuple(nb.njit(parallel=True, cache=True)(
                     renamed(k.py_func, f"{prefix}_{k.py_func.__name__}", **over))
                 for k in (transmit_kernel, accumulate_kernel))
