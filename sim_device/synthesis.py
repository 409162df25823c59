"""Element-level synthesis of point-scatterer echoes (numba kernels).

For every scatterer k, transmit leg image a and receive leg image b of channel ch, the
received pressure is (PHYSICS.md section 5)

    p_ch(t) = Re{ sum A_t(k, a) A_r(k, b, ch) s_a(t - tau_t(k, a) - tau_r(k, b, ch)) },

with s_a the analytic transmit pulse and A_t, A_r the complex leg factors: source level
and scatterer strength (on the transmit leg), beam gain, spreading, interface
transmission (1 + R down, 1 - R up), sediment and water attenuation, and the multipath
factors R_s^n_s R_b^n_b of image legs. Interface scatterers take sigma(theta)^(1/4) on
each leg, i.e. the bistatic strength sqrt(sigma(theta_t) sigma(theta_r)) (equal to the
monostatic sigma for backscatter). Levels are evaluated at the carrier frequency.

Rather than evaluating the pulse per echo, the kernel adds each echo's complex baseband
impulse A exp(-j 2 pi f_c tau) (the convention of :mod:`svss_daq.conventions`) at its
fractional delay into a baseband buffer with 4-tap Lagrange weights, and
:func:`to_passband` convolves the buffer once with the sampled baseband pulse
s_bb(t) = s_a(t) exp(-j 2 pi f_c t) and remodulates. The baseband pulse occupies about
+-B/2 around 0 Hz, far below the sample rate, where cubic Lagrange interpolation is
accurate to ~-90 dB; only the pulse's out-of-band edges (the taper's pedestal) are
band-limited, as a real digitiser's anti-alias filter would.

Pass 1 evaluates every scatterer's transmit legs: :func:`transmit_kernel` (the
reference: the scalar :func:`leg` per scatterer and projector image) or
:func:`transmit_fast_kernel` (the fast path's: the legs of first-sediment scatterers
vectorised across scatterers, as pass 2 vectorises receive legs across channels). Pass 2
has two implementations that form the same echoes: :func:`accumulate_fast_kernel` (the
default: scatterer-parallel into per-thread float32 buffers, the receive legs of one
scatterer vectorised across channels; see the comment above it) and
:func:`accumulate_kernel` (the reference: parallel over channels, so no two threads write
the same buffer); :mod:`sim_device.synthesis_gpu` runs pass 2 on a GPU. Geometry is in
the tile frame (z down from the interface), float64.

The kernels take the named bundles of :mod:`sim_device.synthesis_args` (scatterers,
transmit legs, paths, medium, beam, window). :func:`transmit_legs`, :func:`accumulate`,
:func:`accumulate_fast` and :func:`accumulate_fast_serial` take the same arrays and
scalars one by one, in the order :class:`~sim_device.environment_source.EnvironmentSource`
forms them, and make the bundles (:func:`~sim_device.synthesis_args.bundles`).

The scalar functions of a leg are defined once, in :func:`build`, and compiled by the
decorator it is given: ``njit(inline="always")`` here (the module-level names, used by
the CPU kernels) and ``cuda.jit(device=True)`` in :mod:`sim_device.synthesis_gpu`; so is
the reference and GPU kernels' echo loop (:mod:`sim_device.echo_loop`).
"""

from __future__ import annotations

import math
import types
from types import SimpleNamespace

import numba as nb
import numpy as np
import scipy.fft as sfft
from llvmlite import ir as llvm_ir
from numba import types as nbtypes
from numba.core import cgutils
from numba.extending import intrinsic

from svss_daq.conventions import baseband_carrier, remodulation
from svss_daq.waveform import Waveform

from . import echo_loop, layered_rays
from .layered_rays import _EPS, T_TOL, TABLE_CEILING, TABLE_RESIDUAL, TABLE_TRUSTED
from .synthesis_args import (  # noqa: F401 (the column names: re-exported)
    IMG_DIR,
    IMG_H,
    IMG_NB,
    IMG_RS,
    IMG_X,
    IMG_Y,
    MED_INTERFACE,
    Beam,
    Medium,
    Points,
    TransmitLegs,
    bundles,
)

#: the ray amplitude terms of :mod:`sim_device.layered_rays`, re-exported for tests
ray_amplitude_terms = layered_rays.ray_amplitude_terms

#: samples of margin on each side of the window kept in the baseband buffer
_MARGIN = 4


def build(jit_inline, rays, floor):
    """The scalar synthesis functions compiled with ``jit_inline`` (numba's
    ``njit(inline="always")`` for the CPU kernels of this module, ``cuda.jit(device=True)``
    for :mod:`sim_device.synthesis_gpu`); ``rays``: the ray functions of
    :func:`sim_device.layered_rays.build` compiled for the same target; ``floor``: the
    target's floor of a float (:func:`float_floor` on the CPU: a float, so that a loop
    calling it vectorises without float64 -> int64 conversions, which AVX2 lacks;
    ``math.floor`` on the GPU). Returns a namespace of them: one source for the CPU and
    GPU kernels."""
    table_ray_tan = rays.table_ray_tan
    leg_extents = rays.leg_extents
    ray_tan = rays.ray_tan
    amplitude_terms = rays.ray_amplitude_terms
    reflection = rays.reflection

    @jit_inline
    def _interp(table, x):
        """Linear interpolation of ``table`` sampled uniformly on [0, 1] at x in [0, 1]."""
        n = table.size
        u = x * (n - 1)
        if u <= 0.0:
            return table[0]
        if u >= n - 1:
            return table[n - 1]
        i = int(u)
        f = u - i
        return table[i] + f * (table[i + 1] - table[i])

    @jit_inline
    def cis_cycles(x):
        """(cos, sin) of 2 pi x for any x (cycles): x is reduced to [-1/2, 1/2], the angle
        quartered into [-pi/4, pi/4], a Taylor series taken there (error < 1e-12) and
        squared back twice."""
        a = 2.0 * math.pi * (x - floor(x + 0.5)) * 0.25
        a2 = a * a
        c = 1.0 + a2 * (-1 / 2 + a2 * (1 / 24 + a2 * (-1 / 720 + a2 * (1 / 40320 + a2 * (
            -1 / 3628800 + a2 * (1 / 479001600))))))
        s = a * (1.0 + a2 * (-1 / 6 + a2 * (1 / 120 + a2 * (-1 / 5040 + a2 * (
            1 / 362880 + a2 * (-1 / 39916800 + a2 * (1 / 6227020800)))))))
        c, s = c * c - s * s, 2.0 * c * s
        return c * c - s * s, 2.0 * c * s

    @jit_inline
    def gain(cos_off, front, back, lo_front, lo_back):
        """Beam gain for the cosine of the off-axis angle: the main-lobe table over
        [lo_front, 1], the back-lobe table over [lo_back, 1] for -cos_off, else 0."""
        if cos_off >= lo_front:
            return _interp(front, (cos_off - lo_front) / (1.0 - lo_front))
        if back.size > 0 and -cos_off >= lo_back:
            return _interp(back, (-cos_off - lo_back) / (1.0 - lo_back))
        return 0.0

    @jit_inline
    def two_medium_terms(t, rho, h0, h1, c0, c1, a0, a1, src):
        """:func:`ray_amplitude_terms` for water over one sediment (both extents > 0)."""
        cmax = c0 if c0 > c1 else c1  # noqa: FURB136
        tt = t * t
        iq = 1.0 / math.sqrt(1.0 + tt)
        p = t * iq / cmax
        r0 = c0 / cmax
        r1 = c1 / cmax
        g0 = iq if r0 == 1.0 else math.sqrt(1.0 + tt * (1.0 - r0 * r0)) * iq
        g1 = iq if r1 == 1.0 else math.sqrt(1.0 + tt * (1.0 - r1 * r1)) * iq
        ig0 = 1.0 / g0
        ig1 = 1.0 / g1
        tau = p * rho + h0 * g0 / c0 + h1 * g1 / c1
        s1 = h0 * c0 * ig0 + h1 * c1 * ig1
        s2 = h0 * c0 * ig0 * ig0 * ig0 + h1 * c1 * ig1 * ig1 * ig1
        gs = g1 / c1 if src == 1 else g0 / c0
        spread = 1.0 / (gs * math.sqrt(s1 * s2))
        att = a0 * h0 * ig0 + a1 * h1 * ig1
        return p, tau, spread, g0, att

    @jit_inline
    def leg_amplitude(cos_off, f_surf, spread, att, trans, n_b, q, r_bot, g_front, g_back,
                      lo_front, lo_back):
        """A leg's complex amplitude factor from its terms: the element's beam gain at
        the off-axis cosine ``cos_off`` (0: unseen), the surface factor, spreading,
        attenuation (Np), transmission and ``n_b`` coherent seabed bounces at the cos of
        the grazing angle ``q``."""
        g = gain(cos_off, g_front, g_back, lo_front, lo_back)
        if g == 0.0:
            return complex(0.0, 0.0)
        amp = (g * f_surf * spread * math.exp(-att)) * trans
        if n_b > 0:
            rb = _interp(r_bot, q)
            for _ in range(n_b):
                amp *= rb
        return amp

    @jit_inline
    def leg_body(ex, ey, height, direction, f_surf, n_b, x, y, z, med, up, c, rho_m, delta,
                 alpha, z_top, tab, r_top, r_bot, bore, g_front, g_back, lo_front, lo_back,
                 hbuf, cbuf):
        """:func:`leg` with the medium's and the beam's arrays one by one, for the CPU
        kernels' loops: they unpack their bundles once, at the top, and call this."""
        dx = x - ex
        dy = y - ey
        rho = math.sqrt(dx * dx + dy * dy)
        c0 = c[0]
        trans = complex(1.0, 0.0)
        if med <= 0:
            v = height + (z if med == 0 else 0.0)
            d = direction
            if v < 0.0:
                v = -v
                d = -d
            r = math.sqrt(rho * rho + v * v)
            if r == 0.0:
                return 0.0, complex(0.0, 0.0), 0.0
            tau = r / c0
            sinp = rho / r
            cosp = v / r
            spread = 1.0 / r
            att = alpha[0] * r
        else:
            if med == 1 and height > 0.0 and z > 0.0:
                t = table_ray_tan(rho, height, z, c0, c[1], tab, hbuf, cbuf)
                n = 2
                p, tau, spread, cosp, att = two_medium_terms(t, rho, height, z, c0, c[1],
                                                             alpha[0], alpha[1], 1 if up else 0)
            else:
                n = leg_extents(height, z, med, z_top, hbuf)
                t = ray_tan(rho, hbuf, c, n)
                p, tau, spread, cosp, att = amplitude_terms(t, rho, hbuf, c, alpha, n,
                                                            med if up else 0)
            sinp = p * c0
            for k in range(1, n):
                q = c[k - 1] * p
                if k == 1:
                    rk = _interp(r_top, q)
                else:
                    rk = reflection(q, rho_m[k] / rho_m[k - 1], c[k] / c[k - 1], delta[k])
                trans *= (1.0 - rk) if up else (1.0 + rk)
            d = direction
        if rho > 0.0:
            cos_off = (sinp * (dx * bore[0] + dy * bore[1]) / rho + d * cosp * bore[2])
        else:
            cos_off = d * cosp * bore[2]
        return tau, leg_amplitude(cos_off, f_surf, spread, att, trans, n_b, sinp, r_bot,
                                  g_front, g_back, lo_front, lo_back), sinp

    @jit_inline
    def leg(ex, ey, height, direction, f_surf, n_b, x, y, z, med, up, medium, beam, hbuf,
            cbuf):
        """One leg between an element image (ex, ey, height above the interface, direction,
        surface factor R_s^n_s, seabed bounces n_b) and a scatterer (x, y, z, medium
        ``med``; -1: on the interface), through ``medium`` (a
        :class:`~sim_device.synthesis_args.Medium`) and the element's ``beam`` (a
        :class:`~sim_device.synthesis_args.Beam`); ``hbuf``, ``cbuf``: the ray solver's
        scratch arrays.

        ``up``: the leg carries the scattered wave up to a receiver (transmission 1 - R and
        spreading from a source in the scatterer's medium) rather than down from the
        projector. ``r_top``/``r_bot`` of the medium: tables over cos(grazing) in [0, 1] of
        the interface's reflection coefficient and of its coherent (Eckart) value for
        seabed bounces. Returns (delay s, complex amplitude factor, cos of the grazing angle
        at the interface); the amplitude is 0 where the element's beam does not see the leg.
        The body is :func:`leg_body` (the CPU kernels call it with their unpacked arrays).
        """
        return leg_body(ex, ey, height, direction, f_surf, n_b, x, y, z, med, up, medium.c,
                        medium.rho, medium.delta, medium.alpha, medium.z_top, medium.tab,
                        medium.r_top, medium.r_bot, beam.bore, beam.front, beam.back,
                        beam.lo_front, beam.lo_back, hbuf, cbuf)

    @jit_inline
    def cis_cycles32(x):
        """(cos, sin) of 2 pi x as :func:`cis_cycles`, to float32 accuracy (error < 3e-8):
        x reduced in float64 (the delay-phase product is large), the rest shorter series."""
        a = 2.0 * math.pi * (x - floor(x + 0.5)) * 0.25
        a2 = a * a
        c = 1.0 + a2 * (-1 / 2 + a2 * (1 / 24 + a2 * (-1 / 720 + a2 * (1 / 40320))))
        s = a * (1.0 + a2 * (-1 / 6 + a2 * (1 / 120 + a2 * (-1 / 5040 + a2 * (1 / 362880)))))
        c, s = c * c - s * s, 2.0 * c * s
        return c * c - s * s, 2.0 * c * s

    @jit_inline
    def lagrange4(w):
        """Cubic Lagrange weights of the samples i1 - 1 .. i1 + 2 for an echo at fractional
        position w in [0, 1) after sample i1."""
        wm1 = w - 1.0
        wm2 = w - 2.0
        wp1 = w + 1.0
        return (-w * wm1 * wm2 / 6.0, wp1 * wm1 * wm2 / 2.0, -wp1 * w * wm2 / 2.0,
                wp1 * w * wm1 / 6.0)

    return SimpleNamespace(_interp=_interp, cis_cycles=cis_cycles, gain=gain,
                           two_medium_terms=two_medium_terms, leg=leg, leg_body=leg_body,
                           leg_amplitude=leg_amplitude,
                           cis_cycles32=cis_cycles32,
                           lagrange4=lagrange4)


@nb.njit(cache=True, inline="always")
def float_floor(x):
    """floor(x) as a float (numba's ``math.floor`` returns an integer: a float64 -> int64
    conversion and back, which only AVX-512 has as a vector instruction)."""
    return np.floor(x)


_cpu = build(nb.njit(cache=True, inline="always"), layered_rays._cpu, float_floor)
_interp = _cpu._interp
cis_cycles = _cpu.cis_cycles
gain = _cpu.gain
two_medium_terms = _cpu.two_medium_terms
leg = _cpu.leg
leg_body = _cpu.leg_body
leg_amplitude = _cpu.leg_amplitude
cis_cycles32 = _cpu.cis_cycles32
lagrange4 = _cpu.lagrange4


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
    for b in nb.prange((ns + chunk - 1) // chunk):
        hbuf = np.empty(nmed + 1)
        cbuf = np.empty(2)
        for k in range(b * chunk, min(ns, (b + 1) * chunk)):
            for m in range(nt):
                tau, a, cg = leg_body(img[m, IMG_X], img[m, IMG_Y], img[m, IMG_H],
                                      img[m, IMG_DIR], img[m, IMG_RS], int(img[m, IMG_NB]),
                                      sx[k], sy[k], sz[k], smed[k], False, c, rho_m, delta,
                                      alpha, z_top, tab, r_top, r_bot, bore, g_front,
                                      g_back, lo_front, lo_back, hbuf, cbuf)
                if smed[k] == MED_INTERFACE and a != 0.0:
                    a *= _interp(sig, cg)
                tau_out[k, m] = tau
                amp_out[k, m] = a * samp[k]


def transmit_legs(sx, sy, sz, smed, samp, img, c, rho_m, delta, alpha, z_top, tab, r_top,
                  r_bot, bore, g_front, g_back, lo_front, lo_back, sig, tau_out, amp_out,
                  fast=False):
    """:func:`transmit_kernel` (``fast``: :func:`transmit_fast_kernel`, the same legs
    vectorised across scatterers) of the arrays and scalars in the order
    :class:`~sim_device.environment_source.EnvironmentSource` forms them."""
    kernel = transmit_fast_kernel if fast else transmit_kernel
    kernel(Points(sx, sy, sz, smed), samp, img,
           Medium(c, rho_m, delta, alpha, z_top, tab, r_top, r_bot, sig),
           Beam(bore, g_front, g_back, float(lo_front), float(lo_back)),
           TransmitLegs(tau_out, amp_out))


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


def accumulate(sx, sy, sz, smed, tau_t, amp_t, img, allowed, c, rho_m, delta, alpha, z_top,
               tab, r_top, r_bot, bore, g_front, g_back, lo_front, lo_back, sig, fc, t_lo,
               t_hi, t_buf0, fs, buf):
    """:func:`accumulate_kernel` of the arrays and scalars in the order
    :class:`~sim_device.environment_source.EnvironmentSource` forms them (every path to
    any depth)."""
    return accumulate_kernel(*bundles(sx, sy, sz, smed, tau_t, amp_t, img, allowed, c,
                                      rho_m, delta, alpha, z_top, tab, r_top, r_bot, bore,
                                      g_front, g_back, lo_front, lo_back, sig, fc, t_lo,
                                      t_hi, t_buf0, fs), buf)


#: the simulated digitiser's anti-alias filter: raised-cosine low-pass from
#: AA_PASS * fs to AA_STOP * fs (an assumption; the hardware file gives none)
AA_PASS = 0.36
AA_STOP = 0.48
#: samples kept before the pulse's start and after its end for the filter's tails
AA_PAD = 24


def digitised_pulse(waveform: Waveform, fs: float, oversample: int = 16
                    ) -> tuple[np.ndarray, np.ndarray, int]:
    """The transmit pulse as the digitiser sees it: band-limited by its anti-alias
    filter, on the sample grid t_j = (j - AA_PAD) / fs.

    Returns (real pulse, analytic pulse, AA_PAD). Computed on a grid ``oversample``
    times finer, filtered in the frequency domain and sampled; the analytic pulse is
    the exact Hilbert pair (positive frequencies only).
    """
    n_pulse = int(math.ceil(waveform.duration_s * fs)) + 1
    n = n_pulse + 2 * AA_PAD
    n_fine = sfft.next_fast_len(n * oversample * 2)
    fs_fine = fs * oversample
    t = np.arange(n_fine) / fs_fine - AA_PAD / fs
    s = waveform.real(t)
    spec = sfft.fft(s)
    f = np.abs(sfft.fftfreq(n_fine, 1.0 / fs_fine))
    lo, hi = AA_PASS * fs, AA_STOP * fs
    h = np.where(f <= lo, 1.0, np.where(f >= hi, 0.0,
                                        0.5 * (1.0 + np.cos(np.pi * (f - lo) / (hi - lo)))))
    freq = sfft.fftfreq(n_fine, 1.0 / fs_fine)
    real = sfft.ifft(spec * h).real[::oversample][:n]
    analytic = sfft.ifft(spec * h * np.where(freq > 0, 2.0, np.where(freq == 0, 1.0, 0.0)))
    return real.copy(), analytic[::oversample][:n].copy(), AA_PAD


class PulseSynthesiser:
    """Turns baseband impulse buffers into digitiser-rate passband pressure.

    The digitiser's sample n holds the pressure at t_n = t_first + n / fs; the pulse
    kernel is :func:`digitised_pulse` in baseband, s_bb(t_j) = s_a(t_j) exp(-j 2 pi f_c t_j)
    on t_j = (j - pad) / fs.
    """

    def __init__(self, waveform: Waveform, fs: float, n_samples: int, t_first: float):
        self.fs = float(fs)
        self.fc = waveform.center_hz
        self.n = int(n_samples)
        self.t_first = float(t_first)
        real, analytic, pad = digitised_pulse(waveform, fs)
        n_pulse = real.size
        tp = (np.arange(n_pulse) - pad) / fs
        self.pulse_real = real
        self.pad = pad
        self.pulse_bb = analytic * baseband_carrier(tp, self.fc)
        self.n_pulse = n_pulse
        # buffer sample j <-> t_buf0 + j / fs; conv index m <-> t_buf0 + (m - pad) / fs
        self.offset = n_pulse + _MARGIN
        self.n_buf = self.n + n_pulse + 2 * _MARGIN
        self.t_buf0 = self.t_first - (self.offset - pad) / fs
        # echoes whose kernel support can reach the window
        self.t_lo = self.t_first - (n_pulse - pad + 2) / fs
        self.t_hi = self.t_first + (self.n + pad + 1) / fs
        self.n_fft = sfft.next_fast_len(self.n_buf + n_pulse - 1)
        self.pulse_fft = sfft.fft(self.pulse_bb, self.n_fft)
        t = self.t_first + np.arange(self.n) / fs
        self.remod = remodulation(t, self.fc)

    def buffer(self, n_channels: int) -> np.ndarray:
        return np.zeros((n_channels, self.n_buf), dtype=np.complex128)

    def to_passband(self, buf: np.ndarray) -> np.ndarray:
        """Convolve with the baseband pulse, remodulate, take the real part (uPa)."""
        y = sfft.ifft(sfft.fft(buf, self.n_fft, axis=-1) * self.pulse_fft, axis=-1)
        return (y[:, self.offset:self.offset + self.n] * self.remod).real


# ------------------------------------------------------------------- fast accumulation
#
# The reference pass 2 (:func:`accumulate_kernel`) runs channels in parallel and, for
# each channel, every scatterer through the echo loop of :mod:`sim_device.echo_loop` (the
# GPU kernel's loop): the scatterer arrays are streamed once per channel and the
# per-scatterer bookkeeping (earliest transmit delay, receive images needed) is kept in
# ping-sized arrays. :func:`accumulate_fast_kernel` turns the loops round: threads take
# interleaved chunks of scatterers; for each scatterer the bookkeeping is done once, each
# receive image's legs are evaluated for all channels in one inner loop (the reference's
# scalar leg, :func:`leg_body`, where the vectorised forms do not apply; element-image
# rows transposed so the channel loop reads contiguous memory), then every kept transmit
# image's echoes for all channels are formed (vectorised) and added to the thread's own
# float32 buffer, laid out (channel, sample) with each sample's real and imaginary parts
# side by side, so that an echo's four Lagrange taps are eight neighbouring floats, added
# as one vector multiply-add (:func:`_add_taps`). The threads' buffers are summed at the
# end. Table look-ups use unsigned indices (:func:`_uidx`): numba guards every signed
# index against negative values, which in the look-up loops cost about as much as the
# look-ups. It
# does not share the echo loop: a loop over one channel's echoes cannot be vectorised
# across channels, which is this kernel's speed. The echoes and their delays, amplitudes
# and phases are those of the reference to float64 rounding; only the accumulation is
# float32, so the two paths agree to float32 rounding.
#
# Every kernel unpacks its bundles at its top and its loops see plain arrays only: a
# bundle passed on into the functions the loops call costs an atomic reference count per
# array per call and the loop unswitching LLVM does otherwise (docs/simulator.md,
# "Bundled kernels and speed").


@intrinsic
def _add_taps(typingctx, buf, row, col, re, im, w0, w1, w2, w3):
    """buf[row, col:col + 8] += (re w0, im w0, re w1, im w1, re w2, im w2, re w3, im w3)
    for a C-contiguous float32 ``buf`` (an echo's four Lagrange taps, real and imaginary
    parts interleaved), as one <8 x float> multiply-add: numba leaves LLVM's SLP
    vectoriser off and the eight scalar adds unvectorised. Generic LLVM vector IR (on
    AVX: one 256-bit load, fused multiply-add and store; split on narrower targets);
    no bounds or negative-index checks (the caller's index is in the buffer)."""
    sig = nbtypes.void(buf, row, col, re, im, w0, w1, w2, w3)

    def codegen(context, builder, signature, args):
        arrty = signature.args[0]
        ary = context.make_array(arrty)(context, builder, args[0])
        inds = [context.cast(builder, v, t, nbtypes.intp)
                for v, t in zip(args[1:3], signature.args[1:3])]
        ptr = cgutils.get_item_pointer2(context, builder, data=ary.data,
                                        shape=cgutils.unpack_tuple(builder, ary.shape),
                                        strides=cgutils.unpack_tuple(builder, ary.strides),
                                        layout=arrty.layout, inds=inds, wraparound=False,
                                        boundscheck=False)
        v8 = llvm_ir.VectorType(llvm_ir.FloatType(), 8)
        re_, im_, *w = (context.cast(builder, v, t, nbtypes.float32)
                        for v, t in zip(args[3:], signature.args[3:]))
        x = llvm_ir.Constant(v8, llvm_ir.Undefined)
        y = llvm_ir.Constant(v8, llvm_ir.Undefined)
        for j in range(8):
            lane = llvm_ir.Constant(llvm_ir.IntType(32), j)
            x = builder.insert_element(x, re_ if j % 2 == 0 else im_, lane)
            y = builder.insert_element(y, w[j // 2], lane)
        vptr = builder.bitcast(ptr, v8.as_pointer())
        fmuladd = cgutils.get_or_insert_function(
            builder.module, llvm_ir.FunctionType(v8, [v8, v8, v8]), "llvm.fmuladd.v8f32")
        builder.store(builder.call(fmuladd, [x, y, builder.load(vptr, align=4)]), vptr,
                      align=4)
        return context.get_dummy_value()

    if not (isinstance(buf, nbtypes.Array) and buf.dtype == nbtypes.float32
            and buf.ndim == 2 and buf.layout == "C"):
        return None
    return sig, codegen


#: one, unsigned (an unsigned index + _U1 stays unsigned)
_U1 = np.uint64(1)


@nb.njit(cache=True, fastmath=True, error_model="numpy", inline="always")
def _uidx(x):
    """A table position held as a float (>= 0) as an unsigned index: numba checks signed
    indices for negative values (wrap-around) on every access, unsigned ones not."""
    return np.uint64(np.int64(x))


@nb.njit(cache=True, fastmath=True, error_model="numpy", inline="always")
def _idx(u, n1):
    """Index and fraction of u (clamped to [0, 1]) on a uniform table of n1 + 1 nodes:
    table[i] + f (table[i + 1] - table[i]) interpolates it. Scalars only (arrays passed
    to inlined helpers cost reference counting in the channel loops)."""
    x = min(max(u, 0.0), 1.0) * n1
    i = min(int(x), n1 - 1)
    return i, x - i


@nb.njit(cache=True, fastmath=True, error_model="numpy", inline="always")
def _exp_neg(x):
    """exp(-x) for x >= 0 without a library call (vectorisable): exp(-x/512) by its
    Taylor series (|x/512| <= 0.16 below the clamp at x = 80; error < 1e-11), squared
    nine times (relative error < 1e-8); exp(-80) = 2e-35 stands for anything smaller."""
    y = -min(x, 80.0) * (1.0 / 512.0)
    e = 1.0 + y * (1.0 + y * (1 / 2 + y * (1 / 6 + y * (1 / 24 + y * (
        1 / 120 + y * (1 / 720 + y * (1 / 5040)))))))
    e = e * e
    e = e * e
    e = e * e
    e = e * e
    e = e * e
    e = e * e
    e = e * e
    e = e * e
    return e * e


@nb.njit(cache=True, fastmath=True, error_model="numpy", inline="always")
def _s_terms(s, rho, h0, h1, cmax, r0, r1, c0, c1, a0, a1):
    """:func:`two_medium_terms` of a leg with extents h0 (water) and h1 (first sediment)
    and offset rho, from s = p c_max instead of t: the cosines g_i = sqrt(1 - (s r_i)^2)
    independent of each other (relative rounding ~1e-16 / (1 - s^2), below 1e-10 under
    TABLE_CEILING). Returns (delay, g0, 1/g0, 1/g1, sqrt(s1 s2) of the spreading, the
    attenuation exponent, sin of the water angle, |offset(s) - rho|: the residual
    table_ray_tan checks). No table, no library call: vectorisable."""
    p = s / cmax
    q0 = s * r0
    q1 = s * r1
    g0 = math.sqrt(1.0 - q0 * q0)
    g1 = math.sqrt(1.0 - q1 * q1)
    ig0 = 1.0 / g0
    ig1 = 1.0 / g1
    resid = abs(h0 * q0 * ig0 + h1 * q1 * ig1 - rho)
    tau = p * rho + h0 * g0 / c0 + h1 * g1 / c1
    s1 = h0 * c0 * ig0 + h1 * c1 * ig1
    s2 = h0 * c0 * ig0 * ig0 * ig0 + h1 * c1 * ig1 * ig1 * ig1
    att = a0 * h0 * ig0 + a1 * h1 * ig1
    return tau, g0, ig0, ig1, math.sqrt(s1 * s2), att, p * c0, resid


@nb.njit(cache=True, fastmath=True, error_model="numpy", inline="always")
def _beam_pos(cos_off, lo_front, lo_back, ilf, ilb, ng, nbk, off_b, off_z):
    """Position (float index, fraction) on the combined beam table (main lobe over
    [lo_front, 1], back lobe from ``off_b`` over -cos_off in [lo_back, 1], the zero pair
    at ``off_z``: no gain) for the cosine of the off-axis angle."""
    front = cos_off >= lo_front
    u = (cos_off - lo_front) * ilf if front else (-cos_off - lo_back) * ilb
    n1 = ng if front else nbk
    x = min(max(u, 0.0), 1.0) * n1
    xi = min(np.floor(x), n1 - 1.0)
    return xi + (0.0 if front else (off_b if -cos_off >= lo_back else off_z)), x - xi


@nb.njit(cache=True, fastmath=True, error_model="numpy", inline="always")
def _table_pos(u, n1):
    """Position (float index, fraction) of u (clamped to [0, 1]) on a uniform table of
    n1 + 1 nodes, as :func:`_idx` with the index a float (vectorisable)."""
    x = min(max(u, 0.0), 1.0) * n1
    xi = min(np.floor(x), n1 - 1.0)
    return xi, x - xi


@nb.njit(cache=True, fastmath=True, error_model="numpy")
def _medium_terms(geo, imt, fix, wk):
    """Loop 2 of :func:`_receive_legs` (water over the first sediment): from the table's
    s (``wk[1]``) and the offset (``wk[0]``) of every channel of element image ``b``,
    the delay (``wk[8]``), the amplitude without the table factors (``wk[4]``) and the
    positions on the beam and interface tables (``wk[2]``, ``wk[3]``, ``wk[5]``,
    ``wk[6]``); ``wk[7]`` = 1 where the table's s fails its residual check (and the leg
    is not already marked in ``fix``). Returns whether any did. ``geo``: the scatterer
    and the medium's, beam's and tables' scalars (a tuple of scalars: no reference
    counts)."""
    (xk, yk, zk, b, c0, c1, cmax, r0, r1, a0, a1, b0, b1, b2, lo_front, lo_back, ilf, ilb,
     ng, nbk, nr1, n_gtab) = geo
    nch = fix.size
    # 2. two_medium_terms in s: the cosines g_i = sqrt(1 - (s r_i)^2), independent of
    #    each other (relative rounding ~1e-16 / (1 - s^2), below 1e-10 under
    #    TABLE_CEILING); from TABLE_TRUSTED up, the table's s is kept where its offset
    #    sum h_i q_i / g_i (q_i = s r_i) is within TABLE_RESIDUAL of the leg's, as
    #    table_ray_tan checks it, else the leg is marked in wk[7] (Newton); then
    #    the positions on the beam table (main lobe, back lobe or the zero pair at its
    #    end, gtab) and on the interface tables (over sinp)
    off_b = ng + 1.0
    off_z = n_gtab - 2.0
    any_poor = False
    for ch in range(nch):
        rho = wk[0, ch]
        s = wk[1, ch]
        h0 = imt[b, IMG_H, ch]
        tau, g0, _ig0, ig1, s12, att, sinp, resid = _s_terms(s, rho, h0, zk, cmax, r0, r1,
                                                             c0, c1, a0, a1)
        poor = (s >= TABLE_TRUSTED) & (resid > TABLE_RESIDUAL * (h0 + zk)) & ~fix[ch]
        wk[7, ch] = 1.0 if poor else 0.0
        any_poor |= poor
        wk[8, ch] = tau
        spread = c1 * ig1 / s12              # from a source in the sediment
        irho = 1.0 / max(rho, 1e-300)
        dx = xk - imt[b, IMG_X, ch]
        dy = yk - imt[b, IMG_Y, ch]
        cos_off = sinp * (dx * b0 + dy * b1) * irho + imt[b, IMG_DIR, ch] * g0 * b2
        wk[4, ch] = imt[b, IMG_RS, ch] * spread * _exp_neg(att)
        wk[2, ch], wk[3, ch] = _beam_pos(cos_off, lo_front, lo_back, ilf, ilb, ng, nbk,
                                         off_b, off_z)
        wk[5, ch], wk[6, ch] = _table_pos(sinp, nr1)
    return any_poor


#: Newton iterations at most per leg in :func:`_newton_s` (from the table's s it takes
#: 3 to 6; a leg that has not converged goes to the scalar leg, Brent)
NEWTON_MAX = 30


@nb.njit(cache=True, fastmath=True, error_model="numpy", inline="always")
def _newton_one(s, rho, h0, h1, r0, r1):
    """The ray of one two-medium leg (extents h0, h1, offset rho) by Newton's method on
    the offset in t = tan of the fastest medium's angle,
    rho(t) = h0 r0 t / sqrt(1 + t^2 (1 - r0^2)) + h1 r1 t / sqrt(1 + t^2 (1 - r1^2)),
    from the table's s. rho(t) is increasing and concave (r_i <= 1), so from any t > 0
    the iterates stay in t >= 0 and, after the first, increase to the root; stopped at
    Brent's tolerance (layered_rays.ray_tan: |dt| <= T_TOL (1 + t) / 2 + 2 eps t).
    Returns (s = t / sqrt(1 + t^2), True) once converged below TABLE_CEILING, else
    (s, False): the leg is left to the scalar leg (Brent)."""
    a0 = 1.0 - r0 * r0
    a1 = 1.0 - r1 * r1
    t = s / math.sqrt(1.0 - s * s)
    done = False
    for _ in range(NEWTON_MAX):
        tt = t * t
        u0 = 1.0 + tt * a0
        u1 = 1.0 + tt * a1
        v0 = 1.0 / math.sqrt(u0)
        v1 = 1.0 / math.sqrt(u1)
        f = (h0 * r0 * v0 + h1 * r1 * v1) * t - rho
        df = h0 * r0 * v0 / u0 + h1 * r1 * v1 / u1
        dt = f / df
        t = max(t - dt, 0.0)
        if abs(dt) <= 0.5 * T_TOL * (1.0 + t) + 2.0 * _EPS * t:
            done = True
            break
    s = t / math.sqrt(1.0 + t * t)
    return s, done and s < TABLE_CEILING


@nb.njit(cache=True, fastmath=True, error_model="numpy")
def _newton_s(zk, b, imt, r0, r1, fix, wk):
    """:func:`_newton_one` for every receive leg of element image ``b`` marked in
    ``wk[7]`` (the table's s failed its residual check): the converged s goes to
    ``wk[1]``, a leg that does not converge is marked in ``fix`` (the scalar leg)."""
    for ch in range(fix.size):
        if wk[7, ch] == 0.0:
            continue
        s, ok = _newton_one(wk[1, ch], wk[0, ch], imt[b, IMG_H, ch], zk, r0, r1)
        if ok:
            wk[1, ch] = s
        else:
            fix[ch] = True
        wk[7, ch] = 0.0


@nb.njit(cache=True, fastmath=True, error_model="numpy")
def _receive_legs(xk, yk, zk, mk, b, imt, ms, tabf, nv, itab, gtab, sig, fix, wk):
    """Receive legs of one scatterer through element image ``b`` to every channel
    (vectorisable loops): delay ``wk[8]``, complex amplitude (``wk[9]``, ``wk[10]``) as
    :func:`leg` (times sigma^(1/4) for interface scatterers). Channels the fast forms
    do not cover (the two-medium table's checked region, a zero range, other media)
    are marked in ``fix`` for :func:`leg`. Returns True if any channel was marked.
    ``ms``: the medium's and the beam's scalars (:func:`_receive_scalars`); ``itab``:
    rows r_top.real, r_top.imag, r_bot.real, r_bot.imag over cos(grazing); ``gtab``:
    :func:`_beam_table`. Few arrays: numba keeps a reference count per array argument
    of a function that branches around loops (an atomic increment and decrement per
    call)."""
    c0, c1, nmed, a0, a1, b0, b1, b2, lo_front, lo_back, ilf, ilb, ng, nbk = ms
    nch = fix.size
    any_fix = False
    nr1 = itab.shape[1] - 1
    ns1 = sig.size - 1
    off_b = ng + 1.0
    off_z = gtab.size - 2.0
    n_b = int(imt[b, IMG_NB, 0])
    if n_b > 2:
        for ch in range(nch):
            fix[ch] = True
        return True
    if mk <= 0:
        zz = zk if mk == 0 else 0.0
        for ch in range(nch):
            dx = xk - imt[b, IMG_X, ch]
            dy = yk - imt[b, IMG_Y, ch]
            rho2 = dx * dx + dy * dy
            v = imt[b, IMG_H, ch] + zz
            d = imt[b, IMG_DIR, ch]
            d = -d if v < 0.0 else d
            v = abs(v)
            r = math.sqrt(rho2 + v * v)
            ir = 1.0 / max(r, 1e-300)
            tau = r / c0
            sinp = math.sqrt(rho2) * ir
            cos_off = (dx * b0 + dy * b1) * ir + d * v * ir * b2
            x, f = _beam_pos(cos_off, lo_front, lo_back, ilf, ilb, ng, nbk, off_b, off_z)
            i = _uidx(x)
            g = gtab[i] + f * (gtab[i + _U1] - gtab[i])
            a = g * imt[b, IMG_RS, ch] * ir * _exp_neg(a0 * r)
            i, f = _idx(sinp, nr1)
            re = itab[2, i] + f * (itab[2, i + 1] - itab[2, i])
            im = itab[3, i] + f * (itab[3, i + 1] - itab[3, i])
            fr = 1.0 if n_b == 0 else (re if n_b == 1 else re * re - im * im)
            fi = 0.0 if n_b == 0 else (im if n_b == 1 else 2.0 * re * im)
            pr = a * fr
            pi = a * fi
            if mk == MED_INTERFACE:
                i, f = _idx(sinp, ns1)
                sg = sig[i] + f * (sig[i + 1] - sig[i])
                pr *= sg
                pi *= sg
            wk[8, ch] = tau
            wk[9, ch] = pr
            wk[10, ch] = pi
            fix[ch] = r == 0.0
            any_fix |= r == 0.0
        return any_fix
    if mk != 1 or nmed < 2:
        for ch in range(nch):
            fix[ch] = True
        return True
    cmax = c0 if c0 > c1 else c1
    r0 = c0 / cmax
    r1 = c1 / cmax
    nw = tabf.size // nv
    # the loops are split so that everything but the table look-ups vectorises across
    # channels; the look-ups (gathers) run in loops of their own. Table positions are
    # kept as floats (floor, not int: no vector float64 -> int64 conversion before
    # AVX-512) and converted where they are used.
    # 1a. geometry and the two-medium table's coordinates
    for ch in range(nch):
        dx = xk - imt[b, IMG_X, ch]
        dy = yk - imt[b, IMG_Y, ch]
        rho = math.sqrt(dx * dx + dy * dy)
        h0 = imt[b, IMG_H, ch]
        d_all = h0 + zk
        x = h0 / d_all * (nw - 1)
        y = rho / (rho + d_all) * (nv - 1)
        xi = min(max(np.floor(x), 0.0), nw - 2.0)
        yj = min(max(np.floor(y), 0.0), nv - 2.0)
        wk[0, ch] = rho
        wk[5, ch] = xi * nv + yj
        wk[6, ch] = x - xi
        wk[7, ch] = y - yj
    # 1b. the bilinear look-up of s = p c_max (gathers; unsigned indices: no
    #     negative-index wrap-around)
    unv = np.uint64(nv)
    for ch in range(nch):
        o = _uidx(wk[5, ch])
        fx = wk[6, ch]
        fy = wk[7, ch]
        s = ((1.0 - fx) * ((1.0 - fy) * tabf[o] + fy * tabf[o + _U1])
             + fx * ((1.0 - fy) * tabf[o + unv] + fy * tabf[o + unv + _U1]))
        bad = (s >= TABLE_CEILING) | (wk[0, ch] <= 0.0) | (imt[b, IMG_H, ch] <= 0.0)
        wk[1, ch] = 0.5 if bad else s
        fix[ch] = bad
    # 2. the terms of every leg from s (_medium_terms); legs whose table s fails the
    #    residual check are solved by Newton's method from it (_newton_s) and the terms
    #    evaluated again
    geo = (xk, yk, zk, b, c0, c1, cmax, r0, r1, a0, a1, b0, b1, b2, lo_front, lo_back, ilf,
           ilb, ng, nbk, nr1, gtab.size)
    if _medium_terms(geo, imt, fix, wk):
        _newton_s(zk, b, imt, r0, r1, fix, wk)
        _medium_terms(geo, imt, fix, wk)
    # 3. beam gain, transmission 1 - R up through the interface, seabed bounces (gathers)
    if n_b == 0:
        for ch in range(nch):
            i = _uidx(wk[2, ch])
            f = wk[3, ch]
            a = (gtab[i] + f * (gtab[i + _U1] - gtab[i])) * wk[4, ch]
            i = _uidx(wk[5, ch])
            f = wk[6, ch]
            wk[9, ch] = a * (1.0 - (itab[0, i] + f * (itab[0, i + _U1] - itab[0, i])))
            wk[10, ch] = -a * (itab[1, i] + f * (itab[1, i + _U1] - itab[1, i]))
            any_fix |= fix[ch]
        return any_fix
    for ch in range(nch):
        i = _uidx(wk[2, ch])
        f = wk[3, ch]
        a = (gtab[i] + f * (gtab[i + _U1] - gtab[i])) * wk[4, ch]
        i = _uidx(wk[5, ch])
        f = wk[6, ch]
        pr = a * (1.0 - (itab[0, i] + f * (itab[0, i + _U1] - itab[0, i])))
        pi = -a * (itab[1, i] + f * (itab[1, i + _U1] - itab[1, i]))
        re = itab[2, i] + f * (itab[2, i + _U1] - itab[2, i])
        im = itab[3, i] + f * (itab[3, i + _U1] - itab[3, i])
        fr = re if n_b == 1 else re * re - im * im
        fi = im if n_b == 1 else 2.0 * re * im
        wk[9, ch] = pr * fr - pi * fi
        wk[10, ch] = pr * fi + pi * fr
        any_fix |= fix[ch]
    return any_fix


@nb.njit(cache=True, fastmath=True, error_model="numpy", inline="always")
def _beam_scalars(g_front, g_back, lo_front, lo_back):
    """(ng, 1/(1 - lo_front), nbk, 1/(1 - lo_back), lo_back) of a beam's tables for
    :func:`_beam_pos` on the combined table (:func:`_beam_table`): without a back lobe
    (a table of fewer than two nodes) lo_back = 2, which -cos_off never reaches."""
    ng = g_front.size - 1
    ilf = 1.0 / (1.0 - lo_front)
    if g_back.size > 1:
        return ng, ilf, g_back.size - 1, 1.0 / (1.0 - lo_back), lo_back
    return ng, ilf, ng, 0.0, 2.0


@nb.njit(cache=True)
def _beam_table(g_front, g_back):
    """One beam table: the main lobe, the back lobe (if any) and a pair of zeros (no
    gain)."""
    return np.concatenate((g_front, g_back if g_back.size > 1 else g_front[:0],
                           np.zeros(2)))


@nb.njit(cache=True)
def _interface_tables(r_top, r_bot):
    """The interface's reflection tables as one array for the fast kernels' look-ups:
    rows r_top.real, r_top.imag, r_bot.real, r_bot.imag (the same cos(grazing) grid)."""
    if r_top.size != r_bot.size:
        raise ValueError("the interface's reflection tables differ in size")
    t = np.empty((4, r_top.size))
    t[0, :] = r_top.real
    t[1, :] = r_top.imag
    t[2, :] = r_bot.real
    t[3, :] = r_bot.imag
    return t


@nb.njit(cache=True, inline="always")
def _receive_scalars(c, alpha, bore, g_front, g_back, lo_front, lo_back):
    """The scalars :func:`_receive_legs` takes (one tuple: no reference counts): sound
    speeds and attenuations of the water and the first sediment (the water's again
    where there is none), the number of media, the boresight and the beam's
    :func:`_beam_scalars`."""
    ng, ilf, nbk, ilb, lob = _beam_scalars(g_front, g_back, lo_front, lo_back)
    two = c.size > 1
    return (c[0], c[1] if two else c[0], c.size, alpha[0], alpha[1] if two else 0.0,
            bore[0], bore[1], bore[2], lo_front, lob, ilf, ilb, ng, nbk)


@nb.njit(cache=True, fastmath=True, error_model="numpy")
def _transmit_terms(k0, sx, sy, img_m, c0, c1, cmax, r0, r1, a0, a1, bore, lo_front,
                    lo_back, ilf, ilb, ng, nbk, nr1, n_gtab, fix, wk):
    """Loop 2 of :func:`_transmit_image`, as :func:`_medium_terms` with the scatterer's
    depth per lane (``wk[8]``) and the source in the water: delay ``wk[9]``, amplitude
    without the table factors ``wk[4]``, beam and interface table positions ``wk[2]``,
    ``wk[3]``, ``wk[5]``, ``wk[6]``; ``wk[7]`` = 1 where the table's s fails its
    residual check. Returns whether any did. ``img_m``: the projector image's row
    (x, y, height, direction, R_s^n_s, n_b)."""
    ex = img_m[IMG_X]
    ey = img_m[IMG_Y]
    h0 = img_m[IMG_H]
    d = img_m[IMG_DIR]
    rs = img_m[IMG_RS]
    b0 = bore[0]
    b1 = bore[1]
    b2 = bore[2]
    off_b = ng + 1.0
    off_z = n_gtab - 2.0
    any_poor = False
    for j in range(fix.size):
        k = k0 + j
        rho = wk[0, j]
        s = wk[1, j]
        z = wk[8, j]
        tau, g0, ig0, _ig1, s12, att, sinp, resid = _s_terms(s, rho, h0, z, cmax, r0, r1,
                                                             c0, c1, a0, a1)
        poor = (s >= TABLE_TRUSTED) & (resid > TABLE_RESIDUAL * (h0 + z)) & ~fix[j]
        wk[7, j] = 1.0 if poor else 0.0
        any_poor |= poor
        wk[9, j] = tau
        spread = c0 * ig0 / s12              # from a source in the water
        irho = 1.0 / max(rho, 1e-300)
        dx = sx[k] - ex
        dy = sy[k] - ey
        cos_off = sinp * (dx * b0 + dy * b1) * irho + d * g0 * b2
        wk[4, j] = rs * spread * _exp_neg(att)
        wk[2, j], wk[3, j] = _beam_pos(cos_off, lo_front, lo_back, ilf, ilb, ng, nbk,
                                       off_b, off_z)
        wk[5, j], wk[6, j] = _table_pos(sinp, nr1)
    return any_poor


@nb.njit(cache=True, fastmath=True, error_model="numpy")
def _transmit_image(k0, sx, sy, sz, smed, samp, m, img, c, alpha, tabf, nv, rt_re, rt_im,
                    rb_re, rb_im, bore, gtab, lo_front, lo_back, ilf, ilb, ng, nbk,
                    tau_out, amp_out, fix, wk):
    """Transmit legs from projector image ``m`` (row of ``img``) to the scatterers
    k0 .. k0 + fix.size - 1 of the first sediment (medium 1, z > 0) in vectorisable
    loops, as :func:`_receive_legs` forms receive legs across channels: the geometry and
    the two-medium table's coordinates, the table's s (gathers), the terms from s with
    the residual check and Newton's method where the table is poor, the beam, 1 + R
    down through the interface and the seabed bounces (gathers); the delay and the
    amplitude times the scatterer's strength go to ``tau_out[k, m]``,
    ``amp_out[k, m]``. Lanes the fast forms do not cover (other media, interface
    scatterers, the table's checked region, a zero offset, more than two seabed
    bounces) are marked in ``fix`` for :func:`leg`. Returns True if any lane was."""
    n = fix.size
    h0 = img[m, IMG_H]
    n_b = int(img[m, IMG_NB])
    if n_b > 2 or h0 <= 0.0 or c.size < 2 or rt_re.size != rb_re.size:
        for j in range(n):
            fix[j] = True
        return True
    ex = img[m, IMG_X]
    ey = img[m, IMG_Y]
    c0 = c[0]
    c1 = c[1]
    cmax = c0 if c0 > c1 else c1  # noqa: FURB136 (numba: no variadic max)
    r0 = c0 / cmax
    r1 = c1 / cmax
    nw = tabf.size // nv
    nr1 = rb_re.size - 1
    # 1a. geometry and the table's coordinates (lanes outside the first sediment get a
    #     harmless depth and are marked)
    for j in range(n):
        k = k0 + j
        ok = (smed[k] == 1) & (sz[k] > 0.0)
        z = sz[k] if ok else 1.0
        dx = sx[k] - ex
        dy = sy[k] - ey
        rho = math.sqrt(dx * dx + dy * dy)
        d_all = h0 + z
        x = h0 / d_all * (nw - 1)
        y = rho / (rho + d_all) * (nv - 1)
        xi = min(max(np.floor(x), 0.0), nw - 2.0)
        yj = min(max(np.floor(y), 0.0), nv - 2.0)
        wk[0, j] = rho
        wk[8, j] = z
        wk[5, j] = xi * nv + yj
        wk[6, j] = x - xi
        wk[7, j] = y - yj
        fix[j] = not ok
    # 1b. the bilinear look-up of s = p c_max (gathers; unsigned indices)
    unv = np.uint64(nv)
    for j in range(n):
        o = _uidx(wk[5, j])
        fx = wk[6, j]
        fy = wk[7, j]
        s = ((1.0 - fx) * ((1.0 - fy) * tabf[o] + fy * tabf[o + _U1])
             + fx * ((1.0 - fy) * tabf[o + unv] + fy * tabf[o + unv + _U1]))
        bad = (s >= TABLE_CEILING) | (wk[0, j] <= 0.0) | fix[j]
        wk[1, j] = 0.5 if bad else s
        fix[j] = bad
    # 2. the terms from s; Newton's method where the table's s is poor, then again
    img_m = img[m]
    if _transmit_terms(k0, sx, sy, img_m, c0, c1, cmax, r0, r1, alpha[0], alpha[1], bore,
                       lo_front, lo_back, ilf, ilb, ng, nbk, nr1, gtab.size, fix, wk):
        for j in range(n):
            if wk[7, j] == 0.0:
                continue
            s, conv = _newton_one(wk[1, j], wk[0, j], h0, wk[8, j], r0, r1)
            if conv:
                wk[1, j] = s
            else:
                fix[j] = True
            wk[7, j] = 0.0
        _transmit_terms(k0, sx, sy, img_m, c0, c1, cmax, r0, r1, alpha[0], alpha[1], bore,
                        lo_front, lo_back, ilf, ilb, ng, nbk, nr1, gtab.size, fix, wk)
    # 3. beam gain, transmission 1 + R down through the interface, seabed bounces
    any_fix = False
    for j in range(n):
        if fix[j]:
            any_fix = True
            continue
        i = _uidx(wk[2, j])
        f = wk[3, j]
        a = (gtab[i] + f * (gtab[i + _U1] - gtab[i])) * wk[4, j]
        i = _uidx(wk[5, j])
        f = wk[6, j]
        pr = a * (1.0 + (rt_re[i] + f * (rt_re[i + _U1] - rt_re[i])))
        pi = a * (rt_im[i] + f * (rt_im[i + _U1] - rt_im[i]))
        if n_b > 0:
            re = rb_re[i] + f * (rb_re[i + _U1] - rb_re[i])
            im = rb_im[i] + f * (rb_im[i + _U1] - rb_im[i])
            fr = re if n_b == 1 else re * re - im * im
            fi = im if n_b == 1 else 2.0 * re * im
            pr, pi = pr * fr - pi * fi, pr * fi + pi * fr
        k = k0 + j
        tau_out[k, m] = wk[9, j]
        amp_out[k, m] = complex(pr, pi) * samp[k]
    return any_fix


@nb.njit(parallel=True, cache=True, fastmath=True, error_model="numpy")
def transmit_fast_kernel(pts, samp, img, medium, beam, out):
    """Pass 1 as :func:`transmit_kernel` (the same legs: delays and amplitudes to float64
    rounding, the attenuation's exponential to < 1e-12 relative for realistic paths),
    the legs of scatterers in the first sediment vectorised across scatterers
    (:func:`_transmit_image`, chunks of 256 per thread), the others by the scalar
    :func:`leg`."""
    sx, sy, sz, smed = pts
    c, rho_m, delta, alpha, z_top, tab, r_top, r_bot, sig = medium
    bore, g_front, g_back, lo_front, lo_back = beam
    tau_out, amp_out = out
    ns = sx.size
    nt = img.shape[0]
    nmed = c.size
    rt_re = np.ascontiguousarray(r_top.real)
    rt_im = np.ascontiguousarray(r_top.imag)
    rb_re = np.ascontiguousarray(r_bot.real)
    rb_im = np.ascontiguousarray(r_bot.imag)
    tabf = np.ascontiguousarray(tab).reshape(-1)
    nv = tab.shape[1]
    gtab = _beam_table(g_front, g_back)
    ng, ilf, nbk, ilb, lob = _beam_scalars(g_front, g_back, lo_front, lo_back)
    chunk = 256
    for q in nb.prange((ns + chunk - 1) // chunk):
        k0 = q * chunk
        n = min(ns, k0 + chunk) - k0
        hbuf = np.empty(nmed + 1)
        cbuf = np.empty(2)
        fix = np.zeros(n, dtype=np.bool_)
        wk = np.empty((10, n))
        for m in range(nt):
            if not _transmit_image(k0, sx, sy, sz, smed, samp, m, img, c, alpha, tabf, nv,
                                   rt_re, rt_im, rb_re, rb_im, bore, gtab, lo_front, lob,
                                   ilf, ilb, ng, nbk, tau_out, amp_out, fix, wk):
                continue
            for j in range(n):
                if not fix[j]:
                    continue
                k = k0 + j
                tau, a, cg = leg_body(img[m, IMG_X], img[m, IMG_Y], img[m, IMG_H],
                                      img[m, IMG_DIR], img[m, IMG_RS], int(img[m, IMG_NB]),
                                      sx[k], sy[k], sz[k], smed[k], False, c, rho_m, delta,
                                      alpha, z_top, tab, r_top, r_bot, bore, g_front,
                                      g_back, lo_front, lo_back, hbuf, cbuf)
                if smed[k] == MED_INTERFACE and a != 0.0:
                    a *= _interp(sig, cg)
                tau_out[k, m] = tau
                amp_out[k, m] = a * samp[k]


@nb.njit(parallel=True, cache=True, fastmath=True, error_model="numpy")
def accumulate_fast_kernel(pts, legs_t, paths, medium, beam, win, n_buf, n_blocks):
    """Pass 2 as :func:`accumulate_kernel` (same echoes, same delays, amplitudes and
    phases to float64 rounding), scatterer-parallel into per-thread float32 buffers
    (module comment above).

    ``paths.zmax[a, b]``: deepest scatterer (m below the interface) for which path (a, b)
    is synthesised (finite: the kernel is compiled with fastmath; the level cut-off of
    :mod:`sim_device.fidelity`). Returns (buffer (n_channels, n_buf) complex128, echoes
    added per block)."""
    # the bundles unpacked here, outside the loops, which see plain arrays only
    # (docs/simulator.md, "Bundled kernels and speed")
    sx, sy, sz, smed = pts
    tau_t, amp_t = legs_t
    img, allowed, zmax = paths
    c, rho_m, delta, alpha, z_top, tab, r_top, r_bot, sig = medium
    bore, g_front, g_back, lo_front, lo_back = beam
    sign, t_lo, t_hi, t_buf0, fs = win
    nch = img.shape[0]
    nr = img.shape[1]
    nt = tau_t.shape[1]
    ns = sx.size
    nmed = c.size
    # element-image rows transposed: imt[b, column, ch]
    imt = np.empty((nr, 6, nch))
    for ch in range(nch):
        for b in range(nr):
            for j in range(6):
                imt[b, j, ch] = img[ch, b, j]
    itab = _interface_tables(r_top, r_bot)
    ms = _receive_scalars(c, alpha, bore, g_front, g_back, lo_front, lo_back)
    # the two-medium table flattened, and one beam table: the main lobe, the back lobe
    # (if any) and a pair of zeros (no gain)
    tabf = np.ascontiguousarray(tab).reshape(-1)
    nv = tab.shape[1]
    gtab = _beam_table(g_front, g_back)
    # per block: (channel, sample) with the real and imaginary parts interleaved, so
    # that an echo's four taps are eight neighbouring floats
    bufs = np.zeros((n_blocks, nch, 2 * n_buf), dtype=np.float32)
    counts = np.zeros(n_blocks, dtype=np.int64)
    chunk = 64
    n_chunks = (ns + chunk - 1) // chunk
    for blk in nb.prange(n_blocks):
        hbuf = np.empty(nmed + 1)
        cbuf = np.empty(2)
        need = np.zeros(nr, dtype=np.bool_)
        fix = np.zeros(nch, dtype=np.bool_)
        wk = np.empty((11, nch))
        tr = wk[8]              # the receive legs: delay, amplitude (re, im)
        ar_re = wk[9]
        ar_im = wk[10]
        e_i = np.empty(nch, dtype=np.int32)
        e_w = np.empty((nch, 4), dtype=np.float32)
        e_re = np.empty(nch, dtype=np.float32)
        e_im = np.empty(nch, dtype=np.float32)
        e_ok = np.empty(nch, dtype=np.bool_)
        buf = bufs[blk]
        n_add = 0
        for q in range(blk, n_chunks, n_blocks):
            for k in range(q * chunk, min(ns, (q + 1) * chunk)):
                any_need = False
                zk = sz[k]
                for b in range(nr):
                    need[b] = False
                for a in range(nt):
                    if amp_t[k, a] != 0.0:
                        for b in range(nr):
                            if allowed[a, b] and zk <= zmax[a, b]:
                                need[b] = True
                                any_need = True
                if not any_need:
                    continue
                xk = sx[k]
                yk = sy[k]
                mk = smed[k]
                for b in range(nr):
                    if not need[b]:
                        continue
                    if _receive_legs(xk, yk, zk, mk, b, imt, ms, tabf, nv, itab, gtab,
                                     sig, fix, wk):
                        for ch in range(nch):
                            if not fix[ch]:
                                continue
                            tau_r, a_r, cg = leg_body(
                                imt[b, IMG_X, ch], imt[b, IMG_Y, ch], imt[b, IMG_H, ch],
                                imt[b, IMG_DIR, ch], imt[b, IMG_RS, ch],
                                int(imt[b, IMG_NB, ch]), xk, yk, zk, mk, True, c, rho_m,
                                delta, alpha, z_top, tab, r_top, r_bot, bore, g_front,
                                g_back, lo_front, lo_back, hbuf, cbuf)
                            if mk == MED_INTERFACE and a_r != 0.0:
                                a_r *= _interp(sig, cg)
                            tr[ch] = tau_r
                            ar_re[ch] = a_r.real
                            ar_im[ch] = a_r.imag
                    for a in range(nt):
                        if not allowed[a, b] or zk > zmax[a, b]:
                            continue
                        a_t = amp_t[k, a]
                        if a_t == 0.0:
                            continue
                        t_t = tau_t[k, a]
                        at_re = a_t.real
                        at_im = a_t.imag
                        # echoes of all channels (vectorisable) ...
                        for ch in range(nch):
                            tau = t_t + tr[ch]
                            co, si = cis_cycles32(sign * tau)
                            pr = at_re * ar_re[ch] - at_im * ar_im[ch]
                            pi = at_re * ar_im[ch] + at_im * ar_re[ch]
                            u = (tau - t_buf0) * fs
                            u = min(max(u, 1.0), n_buf - 3.0)
                            u1 = np.floor(u)          # a float: the loop vectorises
                            w0, w1, w2, w3 = lagrange4(u - u1)
                            e_i[ch] = u1
                            e_w[ch, 0] = w0
                            e_w[ch, 1] = w1
                            e_w[ch, 2] = w2
                            e_w[ch, 3] = w3
                            e_re[ch] = pr * co - pi * si
                            e_im[ch] = pr * si + pi * co
                            e_ok[ch] = ((tau > t_lo) & (tau < t_hi)
                                        & ((ar_re[ch] != 0.0) | (ar_im[ch] != 0.0)))
                        # ... added at their fractional delays
                        for ch in range(nch):
                            if not e_ok[ch]:
                                continue
                            re = e_re[ch]
                            im = e_im[ch]
                            _add_taps(buf, ch, 2 * e_i[ch] - 2, re, im, e_w[ch, 0],
                                      e_w[ch, 1], e_w[ch, 2], e_w[ch, 3])
                            n_add += 1
        counts[blk] = n_add
    out = np.zeros((nch, n_buf), dtype=np.complex128)
    for ch in nb.prange(nch):
        for blk in range(n_blocks):
            for j in range(n_buf):
                out[ch, j] += complex(bufs[blk, ch, 2 * j], bufs[blk, ch, 2 * j + 1])
    return out, counts


def _renamed(func, name):
    """A copy of ``func`` under another name: numba's on-disk cache is keyed by the
    qualified name (and line), not by the compile flags, so a serial compilation of the
    same function under the same name would be loaded by the parallel dispatcher."""
    f = types.FunctionType(func.__code__, func.__globals__, name, func.__defaults__,
                           func.__closure__)
    f.__qualname__ = name
    f.__doc__ = func.__doc__
    return f


#: :func:`accumulate_fast_kernel` compiled without threads, for pings with few scatterers
#: (a scene of points in water): a parallel region's start costs more than their echoes
accumulate_fast_serial_kernel = nb.njit(cache=True, fastmath=True, error_model="numpy")(
    _renamed(accumulate_fast_kernel.py_func, "accumulate_fast_serial_kernel"))


def accumulate_fast(sx, sy, sz, smed, tau_t, amp_t, img, allowed, c, rho_m, delta, alpha,
                    z_top, tab, r_top, r_bot, bore, g_front, g_back, lo_front, lo_back, sig,
                    fc, t_lo, t_hi, t_buf0, fs, n_buf, n_blocks, zmax):
    """:func:`accumulate_fast_kernel` of the arrays and scalars in the order
    :class:`~sim_device.environment_source.EnvironmentSource` forms them."""
    return accumulate_fast_kernel(*bundles(sx, sy, sz, smed, tau_t, amp_t, img, allowed, c,
                                           rho_m, delta, alpha, z_top, tab, r_top, r_bot,
                                           bore, g_front, g_back, lo_front, lo_back, sig,
                                           fc, t_lo, t_hi, t_buf0, fs, zmax),
                                  n_buf, n_blocks)


def accumulate_fast_serial(sx, sy, sz, smed, tau_t, amp_t, img, allowed, c, rho_m, delta,
                           alpha, z_top, tab, r_top, r_bot, bore, g_front, g_back, lo_front,
                           lo_back, sig, fc, t_lo, t_hi, t_buf0, fs, n_buf, n_blocks, zmax):
    """:func:`accumulate_fast` without threads (:data:`SERIAL_BELOW`)."""
    return accumulate_fast_serial_kernel(*bundles(sx, sy, sz, smed, tau_t, amp_t, img,
                                                  allowed, c, rho_m, delta, alpha, z_top,
                                                  tab, r_top, r_bot, bore, g_front, g_back,
                                                  lo_front, lo_back, sig, fc, t_lo, t_hi,
                                                  t_buf0, fs, zmax),
                                         n_buf, n_blocks)

#: below this many scatterers in view the serial kernel is used
SERIAL_BELOW = 2048
