"""The loops of the point-scatterer synthesis written once over a leg function: pass 1's
scalar transmit leg (:func:`transmit_leg`: the reference kernels' pass 1 and the legs the
fast kernel's vector forms leave) and the echo accumulation loop of pass 2, for the
reference CPU kernel (:func:`sim_device.synthesis_reference.accumulate_kernel`, also
over the undulating interface's leg, :mod:`sim_device.synthesis_curved`) and the GPU
kernel (:mod:`sim_device.synthesis_gpu`): :func:`build` compiles them with a given
decorator, the leg functions of :func:`sim_device.synthesis_legs.build` compiled for the
same target, the echo phase function and the target's way of adding an echo to its
buffer.

For one scatterer k, one channel ch and one receive image b that some kept path needs
(:func:`receive_needed`): the receive leg, unless the straight line at the fastest speed
already puts every echo after the window; then every kept transmit image's echo
A exp(-j 2 pi f_c tau) added at its fractional delay with 4-tap Lagrange weights
(:func:`image_echoes`). The callers do the per-scatterer bookkeeping (earliest transmit
delay, images needed): the reference kernel once per scatterer for all channels, a GPU
thread for its own scatterer.

:func:`image_echoes` and :func:`transmit_leg` take the kernels' arrays one by one, not
their bundles: the kernels unpack their bundles once, at the top. On the CPU an inlined
function that takes a bundle (a tuple of arrays) holds a reference to each array of the
tuple for the call, and where the function branches numba cannot prune those reference
counts: each is an atomic increment and decrement per call (docs/simulator.md, "Bundled
kernels and speed").

The fast CPU kernel (:func:`sim_device.synthesis_fast.accumulate_fast_kernel`) shares the
scalar receive leg (``leg_body``) but not this loop: it turns the
loops round (one scatterer's legs and echoes for all channels in vectorisable loops over
channels, clamped indices and a keep mask instead of branches), which a per-channel loop
cannot express.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

from .synthesis_args import IMG_DIR, IMG_H, IMG_NB, IMG_RS, IMG_X, IMG_Y, MED_INTERFACE


def build(jit, legs, cis, deposit):
    """The loop compiled with ``jit`` (``njit(inline="always")`` on the CPU,
    ``cuda.jit(device=True)`` on the GPU); ``legs``: :func:`sim_device.synthesis_legs.build`'s
    namespace for the same target; ``cis(x)``: (cos, sin) of 2 pi x; ``deposit(out, ch,
    i1, e, w0, w1, w2, w3)``: adds echo ``e`` to channel ``ch`` of ``out`` at samples
    i1 - 1 .. i1 + 2 with those weights. Returns a namespace of the functions."""
    leg_body = legs.leg_body
    interp = legs._interp
    lagrange4 = legs.lagrange4

    @jit
    def fastest(c):
        """The fastest sound speed of the media (bounds every delay from below)."""
        cmax = 0.0
        for i in range(c.size):
            if c[i] > cmax:
                cmax = c[i]
        return cmax

    @jit
    def path_kept(allowed, zmax, a, b, zk):
        """Path (transmit image a, receive image b) synthesised for a scatterer at depth
        zk (``allowed``, ``zmax``: of a :class:`~sim_device.synthesis_args.Paths`)."""
        return allowed[a, b] and zk <= zmax[a, b]

    @jit
    def receive_needed(amp_t, allowed, zmax, k, b, zk):
        """Receive image b of scatterer k (depth zk) is on some kept path with a
        non-zero transmit leg (``amp_t``: :class:`~sim_device.synthesis_args.TransmitLegs`'
        amplitudes)."""
        for a in range(amp_t.shape[1]):
            if amp_t[k, a] != 0.0 and path_kept(allowed, zmax, a, b, zk):
                return True
        return False

    @jit
    def transmit_leg(k, m, img, sx, sy, sz, smed, samp, c, rho_m, delta, alpha, z_top, tab,
                     r_top, r_bot, sig, bore, g_front, g_back, lo_front, lo_back, hbuf,
                     cbuf, tau_out, amp_out):
        """Pass 1's scalar leg: the transmit leg of scatterer k (``sx`` .. ``smed``: the
        arrays of a :class:`~sim_device.synthesis_args.Points`) from projector image m
        (row of ``img``), times sigma^(1/4) of an interface scatterer and the
        scatterer's strength ``samp[k]``, into ``tau_out[k, m]``, ``amp_out[k, m]``
        (the arrays of the Medium, Beam and TransmitLegs bundles)."""
        tau, a, cg = leg_body(img[m, IMG_X], img[m, IMG_Y], img[m, IMG_H], img[m, IMG_DIR],
                              img[m, IMG_RS], int(img[m, IMG_NB]), sx[k], sy[k], sz[k],
                              smed[k], False, c, rho_m, delta, alpha, z_top, tab, r_top,
                              r_bot, bore, g_front, g_back, lo_front, lo_back, hbuf, cbuf)
        if smed[k] == MED_INTERFACE and a != 0.0:
            a *= interp(sig, cg)
        tau_out[k, m] = tau
        amp_out[k, m] = a * samp[k]

    @jit
    def image_echoes(k, ch, b, pos, tmin, img, tau_t, amp_t, allowed, zmax, c, rho_m,
                     delta, alpha, z_top, tab, r_top, r_bot, sig, bore, g_front, g_back,
                     lo_front, lo_back, win, cmax, hbuf, cbuf, out):
        """Every echo of scatterer k (``pos``: its x, y, z and medium; earliest transmit
        delay ``tmin``) through receive image b on channel ch (module docstring), added
        to ``out`` by ``deposit``: the arrays of the Paths, TransmitLegs, Medium and Beam
        bundles, ``win`` the :class:`~sim_device.synthesis_args.Window`, ``cmax``:
        :func:`fastest` of the media. Returns the echoes added. (Fewer than 31
        parameters: Python passes a longer call's arguments as ``*args``, which numba
        cannot inline.)"""
        xk, yk, zk, mk = pos
        ex = img[ch, b, IMG_X]
        ey = img[ch, b, IMG_Y]
        hh = img[ch, b, IMG_H]
        # the straight line at the fastest speed bounds the receive delay (zk: the
        # scatterer's depth below the interface's plane, negative above it)
        dz = abs(hh + zk)
        dmin = math.sqrt((xk - ex) * (xk - ex) + (yk - ey) * (yk - ey) + dz * dz)
        if tmin + dmin / cmax >= win.t_hi:
            return 0
        tau_r, a_r, cg = leg_body(ex, ey, hh, img[ch, b, IMG_DIR], img[ch, b, IMG_RS],
                                  int(img[ch, b, IMG_NB]), xk, yk, zk, mk, True, c, rho_m,
                                  delta, alpha, z_top, tab, r_top, r_bot, bore, g_front,
                                  g_back, lo_front, lo_back, hbuf, cbuf)
        if a_r == 0.0:
            return 0
        if mk == MED_INTERFACE:
            a_r *= interp(sig, cg)
        n_add = 0
        for a in range(tau_t.shape[1]):
            if not path_kept(allowed, zmax, a, b, zk):
                continue
            a_t = amp_t[k, a]
            if a_t == 0.0:
                continue
            tau = tau_t[k, a] + tau_r
            if tau <= win.t_lo or tau >= win.t_hi:
                continue
            co, si = cis(win.sign * tau)
            e = a_t * a_r * complex(co, si)
            u = (tau - win.t_buf0) * win.fs
            i1 = int(u)
            w0, w1, w2, w3 = lagrange4(u - i1)
            deposit(out, ch, i1, e, w0, w1, w2, w3)
            n_add += 1
        return n_add

    return SimpleNamespace(fastest=fastest, path_kept=path_kept,
                           receive_needed=receive_needed, transmit_leg=transmit_leg,
                           image_echoes=image_echoes)
