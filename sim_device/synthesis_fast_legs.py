"""The fast path's legs in vectorisable loops (``[scattering] synthesis = "fast"``, the
default; :mod:`sim_device.synthesis_fast`'s kernels call them): a scatterer's receive
legs to every channel (:func:`_receive_legs`) and a projector image's transmit legs to a
chunk of first-sediment scatterers (:func:`_transmit_image`), each split into loops of
which all but the table look-ups vectorise: geometry and the two-medium table's
coordinates; the bilinear look-up of s = p c_max; the terms from s (:func:`_s_terms`:
travel time in the tau-p form, spreading, attenuation: no table, no library call) with
the table's residual check and Newton's method where the table is poor
(:func:`_newton_one`); the beam, transmission and bounce tables. Legs the vector forms do
not cover are marked for the scalar leg (:func:`sim_device.synthesis_legs.leg_body`).

Table look-ups use unsigned indices (:func:`_uidx`): numba guards every signed index
against negative values, which in the look-up loops cost about as much as the look-ups.
Table positions are kept as floats (floor, not int: no vector float64 -> int64
conversion before AVX-512). The helpers take scalars, or few arrays: numba keeps a
reference count per array argument of a function that branches around loops (an atomic
increment and decrement per call; docs/simulator.md, "Bundled kernels and speed").
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .layered_rays import _EPS, T_TOL, TABLE_CEILING, TABLE_RESIDUAL, TABLE_TRUSTED
from .synthesis_args import IMG_DIR, IMG_H, IMG_NB, IMG_RS, IMG_X, IMG_Y, MED_INTERFACE


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
