"""The echo accumulation loop of pass 2, written once for the reference CPU kernel
(:func:`sim_device.synthesis.accumulate`) and the GPU kernel
(:mod:`sim_device.synthesis_gpu`): :func:`build` compiles it with a given decorator, the
leg functions of :func:`sim_device.synthesis.build` compiled for the same target, the
echo phase function and the target's way of adding an echo to its buffer.

For one scatterer k and one channel ch: each receive image b that some kept path needs
(a non-zero transmit leg a with ``allowed[a, b]`` and the scatterer above
``zmax[a, b]``) gets its receive leg, unless the straight line at the fastest speed
already puts every echo after the window; then every kept transmit image's echo
A exp(-j 2 pi f_c tau) is added at its fractional delay with 4-tap Lagrange weights.

The fast CPU kernel (:func:`sim_device.synthesis.accumulate_fast`) shares the path tests
and the scalar receive leg (:func:`path_kept`, :func:`receive_needed`, ``scattered_leg``)
but not this loop: it turns the loops round (one scatterer's legs and echoes for all
channels in vectorisable loops over channels, clamped indices and a keep mask instead of
branches), which a per-channel loop cannot express.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

from .synthesis_args import IMG_DIR, IMG_H, IMG_NB, IMG_RS, IMG_X, IMG_Y


def build(jit, legs, cis, deposit):
    """The loop compiled with ``jit`` (``njit(inline="always")`` on the CPU,
    ``cuda.jit(device=True)`` on the GPU); ``legs``: :func:`sim_device.synthesis.build`'s
    namespace for the same target; ``cis(x)``: (cos, sin) of 2 pi x; ``deposit(out, ch,
    i1, e, w0, w1, w2, w3)``: adds echo ``e`` to channel ``ch`` of ``out`` at samples
    i1 - 1 .. i1 + 2 with those weights. Returns a namespace of the functions."""
    scattered_leg = legs.scattered_leg
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
    def path_kept(paths, a, b, zk):
        """Path (transmit image a, receive image b) synthesised for a scatterer at depth
        zk (a :class:`~sim_device.synthesis_args.Paths`)."""
        return paths.allowed[a, b] and zk <= paths.zmax[a, b]

    @jit
    def receive_needed(legs_t, paths, k, b, zk):
        """Receive image b of scatterer k (depth zk) is on some kept path with a
        non-zero transmit leg (``legs_t``: :class:`~sim_device.synthesis_args.TransmitLegs`)."""
        for a in range(legs_t.amp.shape[1]):
            if legs_t.amp[k, a] != 0.0 and path_kept(paths, a, b, zk):
                return True
        return False

    @jit
    def scatterer_echoes(k, ch, pts, legs_t, paths, medium, beam, win, cmax, hbuf, cbuf,
                         out):
        """Every echo of scatterer k on channel ch (module docstring) added to ``out``
        by ``deposit``; ``cmax``: :func:`fastest` of the media. Returns the echoes
        added."""
        img = paths.img
        nr = img.shape[1]
        nt = legs_t.tau.shape[1]
        xk = pts.x[k]
        yk = pts.y[k]
        zk = pts.z[k]
        mk = pts.med[k]
        tmin = math.inf
        for a in range(nt):
            if legs_t.amp[k, a] != 0.0 and legs_t.tau[k, a] < tmin:
                tmin = legs_t.tau[k, a]
        n_add = 0
        for b in range(nr):
            if not receive_needed(legs_t, paths, k, b, zk):
                continue
            ex = img[ch, b, IMG_X]
            ey = img[ch, b, IMG_Y]
            hh = img[ch, b, IMG_H]
            # the straight line at the fastest speed bounds the receive delay
            dz = hh + (zk if zk > 0.0 else 0.0)
            dmin = math.sqrt((xk - ex) * (xk - ex) + (yk - ey) * (yk - ey) + dz * dz)
            if tmin + dmin / cmax >= win.t_hi:
                continue
            tau_r, a_r = scattered_leg(ex, ey, hh, img[ch, b, IMG_DIR], img[ch, b, IMG_RS],
                                       int(img[ch, b, IMG_NB]), xk, yk, zk, mk, True,
                                       medium, beam, hbuf, cbuf)
            if a_r == 0.0:
                continue
            for a in range(nt):
                if not path_kept(paths, a, b, zk):
                    continue
                a_t = legs_t.amp[k, a]
                if a_t == 0.0:
                    continue
                tau = legs_t.tau[k, a] + tau_r
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
                           receive_needed=receive_needed, scatterer_echoes=scatterer_echoes)
