"""The scalar functions of the point-scatterer synthesis, written once for the CPU and
the GPU: one leg between an element image and a scatterer (:func:`leg`, its body
:func:`leg_body`), the beam gain, the two-medium ray terms, the echo phase
(:func:`cis_cycles`, :func:`cis_cycles32`) and the Lagrange weights (:func:`lagrange4`).

:func:`build` defines them and compiles them with the decorator it is given:
``njit(inline="always")`` here (the module-level names, used by the CPU kernels of
:mod:`sim_device.synthesis_reference`, :mod:`sim_device.synthesis_fast` and
:mod:`sim_device.synthesis_curved`) and ``cuda.jit(device=True)`` in
:mod:`sim_device.synthesis_gpu`. The physics is in :mod:`sim_device.synthesis`'s
docstring (PHYSICS.md section 5).
"""

from __future__ import annotations

import math
import types
from types import SimpleNamespace

import numba as nb
import numpy as np

from . import layered_rays

#: the ray amplitude terms of :mod:`sim_device.layered_rays`, re-exported for tests
ray_amplitude_terms = layered_rays.ray_amplitude_terms


def build(jit_inline, rays, floor):
    """The scalar synthesis functions compiled with ``jit_inline`` (numba's
    ``njit(inline="always")`` for the CPU kernels: this module's names,
    ``cuda.jit(device=True)`` for :mod:`sim_device.synthesis_gpu`); ``rays``: the ray functions of
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


def renamed(func, name, **names):
    """A copy of ``func`` under another name, its globals those of its module with
    ``names`` in place of some (another leg function for the same loops). numba's
    on-disk cache is keyed by the qualified name (and line), not by the compile flags or
    the globals, so a second compilation of the same function under the same name would
    be loaded by the first's dispatcher."""
    glob = dict(func.__globals__, **names) if names else func.__globals__
    f = types.FunctionType(func.__code__, glob, name, func.__defaults__,
                           func.__closure__)
    f.__qualname__ = name
    f.__doc__ = func.__doc__
    return f
