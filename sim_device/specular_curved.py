"""Coherent (specular) returns of an undulating water-sediment interface
(:mod:`sim_device.bed_undulation`), by geometrical optics: the stationary-phase
evaluation of the Kirchhoff integral over the curved surface.

The outputs are those of :func:`sim_device.specular.interface_paths` (a
:class:`~sim_device.specular.PathSet`, synthesised by the same
:class:`~sim_device.specular.SpectralSynthesiser`); over a plane they are the same paths.

**Geometry.** For a reflection sequence with one seabed bounce (``B``, and with a flat
sea surface ``SB``, ``BS``, ``SBS``), the projector's legs before the bounce and the
receiver's after it are mirrored in the sea surface z = -D as :mod:`sim_device.multipath`
does (M_S(z) = -2 D - z), giving a source image A and a receiver image B above the
interface. Every stationary point S = (sx, sy, u(sx, sy)) of the path length
L(S) = |S - A| + |S - B| over the surface is one specular path (the surface's normal
bisects the directions to A and B there). Over an undulating surface there may be
several: a trough is a concave mirror (radius of curvature 1 / (a k^2) for a sinusoid of
amplitude a and wavenumber k, 4.05 m for 10 cm over 4 m), and a projector and receiver
together farther above it than that see three points in it.

They are found for each channel by Newton's method
(:func:`sim_device.bed_undulation.specular_point`) from a grid of starts an eighth
of the shortest undulation wavelength apart (:data:`START_SPACING`), about the level
interface's specular point; only starts where the bisector of the directions to A and
B tilts from the vertical by no more than the surface's steepest normal can (plus the
tilt's change across the grid's spacing) are used, as no stationary point lies
elsewhere. Converged points closer than :data:`SAME_POINT_M` are one.

**Amplitude.** The Kirchhoff integral of a surface of reflection coefficient R,

    p(B) = -(i k / 4 pi) Int R (n . (e_1 + e_2)) exp(i k (r_1 + r_2)) / (r_1 r_2) dS,

(n the normal into the water, e_j the unit vectors from the surface point to A and B;
physics convention exp(-i omega t)), evaluated by stationary phase over the surface
coordinates (x, y), gives at each stationary point

    R exp(i k L) / L * sqrt(|det H_plane| / |det H|) * exp(-i pi/2 n_neg),

H the 2 x 2 Hessian of L over (x, y) at S for the curved surface, H_plane the same for
its tangent plane at S (positive definite, its stationary point being the tangent
plane's image-source path, whose amplitude is R exp(i k L) / L), and n_neg the number of
negative eigenvalues of H (each turns the phase by -pi/2: a saddle, or a maximum of L
past a focus). Each path therefore carries the level interface's image-source factor
for its own geometry -- beam gains along the legs' directions at the elements, surface
reflections, the Rayleigh coefficient at the incidence angle about the local normal,
1 / L, the water's absorption along L, and Eckart's coherent loss with the local grazing
angle (beta = 2 k^2 h^2 sin^2(grazing)) -- times that curvature factor and phase.

**At a caustic** (det H -> 0, stationary points merging) stationary phase diverges
while the integral stays finite. Along an eigenvector v of H whose eigenvalue is small
(|lambda| below :data:`CAUSTIC_CAP` = half the tangent plane's smaller eigenvalue, which
a plane's never are) the magnitude |lambda| is replaced by no less than

    lambda_c = max(4 pi / (k C3^2) (k |mu| / 6)^(2/3),  2 pi / (k C4^2) (k |nu| / 24)^(1/2)),

C3 = |Int exp(i t^3) dt| = 2 Gamma(4/3) cos(pi/6), C4 = |Int exp(i t^4) dt| =
2 Gamma(5/4), mu and nu the third and fourth derivatives of L along v (central
differences of v^T H v), k at ``frequency``. The first (a fold) is the value at which
one point's stationary-phase amplitude is 1/sqrt(2) of the exact cubic integral
Int exp(i k mu s^3 / 6) ds, so that the two merging points (phases differing by pi/2,
the same delay) sum to it exactly, in magnitude and phase, at the fold. The second (a
cusp, where mu = 0 by symmetry: above a trough's centre of curvature) is the value at
which one point's amplitude is that of the quartic integral (three points merging there
overshoot it by at most sqrt(5)). lambda_c is capped at CAUSTIC_CAP and floored at
:data:`CAUSTIC_FLOOR` of the plane's eigenvalue, so the factor is at most
1 / sqrt(CAUSTIC_FLOOR) per direction and never infinite.

**Exact:** the stationary points and their delays (to the Newton tolerance, ~1e-12 m);
every geometric quantity at them (local angles, the legs' directions at the elements,
both Hessians); over a plane (zero amplitude) the image-source paths of
:func:`~sim_device.specular.interface_paths` to rounding.

**Approximated:** the Kirchhoff (tangent-plane) approximation with the plane-wave
Rayleigh coefficient at the local angle; leading-order stationary phase (errors
O(1 / (k L)) and from the surface's higher derivatives within a Fresnel zone, largest
near caustics, where the uniform (Airy) transition is replaced by the clipping above);
Eckart's coherent loss and the beam gains taken at the stationary point, as the level
model does; no shadowing of a stationary point by other parts of the surface and no
multiple scattering between them; the sea surface flat (mirrored exactly); stationary
points at which Newton's method does not converge within its iteration cap (only at
a caustic's very edge) are missed, as are any beyond :data:`MAX_POINTS` per channel.
Within about a Fresnel scale of a caustic the result is only a bound: against a
directly evaluated Kirchhoff integral (tests/sim/test_specular_curved.py; 10 cm / 4 m
sinusoid, 27.5 kHz) it agrees to 0.02 dB and 0.02 rad with one point 2.5 m up, to
0.9 dB and 0.15 rad with three points 4.5-7 m up, but a few centimetres on the
one-point side of a fold (where the evanescent Airy tail, from complex stationary
points, is left out) it is off by up to ~8 dB and ~2 rad, and at the cusp by up to
+7 dB.
"""

from __future__ import annotations

import logging
import math

import numba as nb
import numpy as np

from .acoustics import reflection_coefficient
from .beams import BeamTable
from .bed_undulation import specular_point, surface
from .environment import Media
from .multipath import CoherentPath
from .specular import PathSet

log = logging.getLogger(__name__)

#: starts of the search for stationary points, as a fraction of the shortest undulation
#: wavelength apart (the points of a sinusoid are a quarter wave or more apart away from
#: caustics, and Newton's basin about each is wider than this)
START_SPACING = 0.125
#: the most stationary points kept per channel and sequence
MAX_POINTS = 16
#: converged points closer than this (m) are the same point
SAME_POINT_M = 1e-5
#: the caustic bound's floor, as a fraction of the tangent plane's smaller eigenvalue
CAUSTIC_FLOOR = 0.01
#: the caustic bound's cap, as a fraction of the tangent plane's smaller eigenvalue (a
#: stationary point whose eigenvalues are all above it is never clipped; a plane's are)
CAUSTIC_CAP = 0.5
#: Int exp(i t^3) dt over the real line: 2 Gamma(4/3) cos(pi/6)
AIRY_C = 2.0 * math.gamma(4.0 / 3.0) * math.cos(math.pi / 6.0)
#: |Int exp(i t^4) dt| over the real line: 2 Gamma(5/4)
QUARTIC_C = 2.0 * math.gamma(5.0 / 4.0)
#: step (m) of the central differences giving d^3 L / ds^3, d^4 L / ds^4 near a caustic
MU_STEP = 1e-3

#: exp(-i pi/2 n_neg), n_neg = 0, 1, 2
_CAUSTIC_PHASE = np.array([1.0, -1j, -1.0])

# fields of the per-point output of _points
F_X, F_Y, F_Z, F_L, F_COS, F_E1, F_E2, F_GAIN, F_NNEG = 0, 1, 2, 3, 4, 5, 8, 11, 12
N_FIELDS = 13


@nb.njit(cache=True)
def _hessians(sx, sy, ax, ay, az, bx, by, bz, rows):
    """At S = (sx, sy, u(sx, sy)): u, ux, uy, L = |S - A| + |S - B|, the unit vectors
    from A and from B to S, and the Hessians of L over (sx, sy) for the curved surface
    (hxx, hxy, hyy) and for its tangent plane at S (pxx, pxy, pyy)."""
    u, ux, uy, uxx, uxy, uyy = surface(sx, sy, rows)
    saa = 1.0 + ux * ux
    sab = ux * uy
    sbb = 1.0 + uy * uy
    length = 0.0
    pxx = 0.0
    pxy = 0.0
    pyy = 0.0
    ez = 0.0
    e1 = np.empty(3)
    e2 = np.empty(3)
    for leg in range(2):
        qx, qy, qz = (ax, ay, az) if leg == 0 else (bx, by, bz)
        dx = sx - qx
        dy = sy - qy
        dz = u - qz
        r = math.sqrt(dx * dx + dy * dy + dz * dz)
        length += r
        e = e1 if leg == 0 else e2
        e[0] = dx / r
        e[1] = dy / r
        e[2] = dz / r
        # dS/dx = (1, 0, ux), dS/dy = (0, 1, uy): d|S-Q|/dx = e . S_x
        da = e[0] + e[2] * ux
        db = e[1] + e[2] * uy
        pxx += (saa - da * da) / r
        pxy += (sab - da * db) / r
        pyy += (sbb - db * db) / r
        ez += e[2]
    # the curved surface adds e_z u_ab per leg (S_ab = (0, 0, u_ab))
    hxx = pxx + ez * uxx
    hxy = pxy + ez * uxy
    hyy = pyy + ez * uyy
    return u, ux, uy, length, e1, e2, hxx, hxy, hyy, pxx, pxy, pyy


@nb.njit(cache=True)
def _eigen(hxx, hxy, hyy):
    """Eigenvalues (ascending) and the unit eigenvector of each of a symmetric 2 x 2."""
    m = 0.5 * (hxx + hyy)
    d = math.sqrt(0.25 * (hxx - hyy) ** 2 + hxy * hxy)
    lam = (m - d, m + d)
    vecs = np.empty((2, 2))
    for i in range(2):
        v1x, v1y = hxy, lam[i] - hxx
        v2x, v2y = lam[i] - hyy, hxy
        n1 = math.hypot(v1x, v1y)
        n2 = math.hypot(v2x, v2y)
        if n1 >= n2 and n1 > 0.0:
            vecs[i, 0] = v1x / n1
            vecs[i, 1] = v1y / n1
        elif n2 > 0.0:
            vecs[i, 0] = v2x / n2
            vecs[i, 1] = v2y / n2
        else:                       # a multiple of the identity: any pair of axes
            vecs[i, 0] = 1.0 - i
            vecs[i, 1] = float(i)
    return lam[0], lam[1], vecs


@nb.njit(cache=True)
def _curvature_factor(sx, sy, ax, ay, az, bx, by, bz, rows, k, hxx, hxy, hyy,
                      pxx, pxy, pyy):
    """sqrt(|det H_plane| / |det H|) with the caustic bound (module docstring), and the
    number of negative eigenvalues of H (the plane's are positive)."""
    det_p = pxx * pyy - pxy * pxy
    p_lo = 0.5 * (pxx + pyy) - math.sqrt(0.25 * (pxx - pyy) ** 2 + pxy * pxy)
    l1, l2, vecs = _eigen(hxx, hxy, hyy)
    n_neg = (1 if l1 < 0.0 else 0) + (1 if l2 < 0.0 else 0)
    cap = CAUSTIC_CAP * p_lo
    if abs(l1) >= cap and abs(l2) >= cap:
        return math.sqrt(det_p / abs(hxx * hyy - hxy * hxy)), n_neg
    mags = np.array([abs(l1), abs(l2)])
    for i in range(2):
        if mags[i] >= cap:
            continue
        vx = vecs[i, 0]
        vy = vecs[i, 1]
        # d^3 L / ds^3 and d^4 L / ds^4 along v: the change of v^T H v along v
        q = np.empty(2)
        for j in range(2):
            s = MU_STEP if j == 0 else -MU_STEP
            r = _hessians(sx + s * vx, sy + s * vy, ax, ay, az, bx, by, bz, rows)
            q[j] = r[6] * vx * vx + 2.0 * r[7] * vx * vy + r[8] * vy * vy
        q0 = hxx * vx * vx + 2.0 * hxy * vx * vy + hyy * vy * vy
        mu = (q[0] - q[1]) / (2.0 * MU_STEP)
        nu = (q[0] - 2.0 * q0 + q[1]) / (MU_STEP * MU_STEP)
        lam_c = max(4.0 * math.pi / (k * AIRY_C * AIRY_C) * (k * abs(mu) / 6.0) ** (2.0 / 3.0),
                    2.0 * math.pi / (k * QUARTIC_C * QUARTIC_C)
                    * math.sqrt(k * abs(nu) / 24.0))
        lam_c = max(min(lam_c, cap), CAUSTIC_FLOOR * p_lo)
        mags[i] = max(mags[i], lam_c)
    return math.sqrt(det_p / (mags[0] * mags[1])), n_neg


@nb.njit(cache=True)
def _points(a, b, rows, slope, spacing, k, out, count):
    """The stationary points of |S - A| + |S - B| over the surface for each channel
    (images a[ch], b[ch] (3,), above it), in ``out[ch, j]`` (fields F_*), their number in
    ``count[ch]``. ``slope``: a bound of |grad u|; ``spacing``: the starts' grid, m;
    ``k``: the wavenumber of the caustic bound, rad/m."""
    tilt = slope / math.sqrt(1.0 + slope * slope)     # the normal's largest horizontal part
    max_pts = out.shape[1]
    for ch in range(a.shape[0]):
        ax, ay, az = a[ch, 0], a[ch, 1], a[ch, 2]
        bx, by, bz = b[ch, 0], b[ch, 1], b[ch, 2]
        ha = max(-az, 1e-6)
        hb = max(-bz, 1e-6)
        # the level plane's specular point, and the search half-width about it
        f = ha / (ha + hb)
        x0 = ax + f * (bx - ax)
        y0 = ay + f * (by - ay)
        r1 = math.sqrt((x0 - ax) ** 2 + (y0 - ay) ** 2 + ha * ha)
        r2 = math.sqrt((x0 - bx) ** 2 + (y0 - by) ** 2 + hb * hb)
        cos0 = ha / r1
        half = min(1.5 * 0.5 * (r1 + r2) * slope / (cos0 * cos0) + 2.0 * spacing,
                   4.0 * max(ha, hb))
        n = int(math.ceil(half / spacing)) if slope > 0.0 else 0
        found = 0
        for i in range(-n, n + 1):
            for j in range(-n, n + 1):
                x = x0 + i * spacing
                y = y0 + j * spacing
                # the bisector of the directions to A and B: a stationary point's normal
                z = surface(x, y, rows)[0]
                d1x, d1y, d1z = ax - x, ay - y, az - z
                d2x, d2y, d2z = bx - x, by - y, bz - z
                q1 = math.sqrt(d1x * d1x + d1y * d1y + d1z * d1z)
                q2 = math.sqrt(d2x * d2x + d2y * d2y + d2z * d2z)
                mx = d1x / q1 + d2x / q2
                my = d1y / q1 + d2y / q2
                mz = d1z / q1 + d2z / q2
                mn = math.sqrt(mx * mx + my * my + mz * mz)
                if mn <= 0.0:
                    continue
                # how far the bisector can turn within the grid's spacing
                margin = spacing * (1.0 / q1 + 1.0 / q2) / mn
                if math.sqrt(mx * mx + my * my) / mn > tilt + margin:
                    continue
                sx, sy, sz, ok = specular_point(ax, ay, az, bx, by, bz, x, y, rows)
                if not ok or not (sz > az and sz > bz):
                    continue
                same = False
                for m in range(found):
                    if (abs(out[ch, m, F_X] - sx) < SAME_POINT_M
                            and abs(out[ch, m, F_Y] - sy) < SAME_POINT_M):
                        same = True
                        break
                if same or found == max_pts:
                    continue
                u, ux, uy, length, e1, e2, hxx, hxy, hyy, pxx, pxy, pyy = _hessians(
                    sx, sy, ax, ay, az, bx, by, bz, rows)
                # the incidence angle about the local normal (into the water)
                nn = math.sqrt(1.0 + ux * ux + uy * uy)
                c1 = -(ux * e1[0] + uy * e1[1] - e1[2]) / nn
                c2 = -(ux * e2[0] + uy * e2[1] - e2[2]) / nn
                if not (c1 > 0.0 and c2 > 0.0):
                    continue                 # A or B behind the tangent plane
                gain, n_neg = _curvature_factor(sx, sy, ax, ay, az, bx, by, bz, rows, k,
                                                hxx, hxy, hyy, pxx, pxy, pyy)
                o = out[ch, found]
                o[F_X] = sx
                o[F_Y] = sy
                o[F_Z] = u
                o[F_L] = length
                o[F_COS] = min(1.0, 0.5 * (c1 + c2))
                for t in range(3):
                    o[F_E1 + t] = e1[t]
                    o[F_E2 + t] = e2[t]
                o[F_GAIN] = gain
                o[F_NNEG] = n_neg
                found += 1
        count[ch] = found


def _images(seq: CoherentPath, tx: np.ndarray, rx: np.ndarray,
            depth: float) -> tuple[np.ndarray, np.ndarray, bool, bool]:
    """The projector's and receivers' images (n, 3) for a sequence with one seabed
    bounce, and whether each was mirrored in the sea surface."""
    s = seq.sequence
    if s.count("B") != 1:
        raise ValueError(f"reflection sequence {s!r}: an undulating interface's coherent "
                         "paths have one seabed bounce (a leg reflected by the curved "
                         "seabed is not modelled; multipath order <= 1)")
    before, after = s.split("B")
    if len(before) > 1 or len(after) > 1:
        raise ValueError(f"reflection sequence {s!r}: not an alternating sequence")
    a = np.broadcast_to(np.asarray(tx, dtype=np.float64), rx.shape).copy()
    b = np.array(rx, dtype=np.float64)
    if before:
        a[:, 2] = -2.0 * depth - a[:, 2]
    if after:
        b[:, 2] = -2.0 * depth - b[:, 2]
    return a, b, bool(before), bool(after)


def curved_interface_paths(tx: np.ndarray, rx: np.ndarray, bore: np.ndarray, media: Media,
                           water_depth: float | None, r_surface: float,
                           sequences: list[CoherentPath], tx_beam: BeamTable,
                           rx_beam: BeamTable, rho_ratio: float, nu: float, delta: float,
                           rows: np.ndarray, frequency: float) -> PathSet:
    """Specular paths of the undulating interface ``rows`` (n, 4: amplitude, kx, ky,
    phase; :class:`~sim_device.bed_undulation.Undulation`) in the bed frame of ``tx``
    (3,) and ``rx`` (n, 3): the arguments of
    :func:`~sim_device.specular.interface_paths`, and ``frequency`` (Hz) for the caustic
    bound. Each sequence gives one column per stationary point a channel can have,
    earliest first: the first (the least time, labelled as the level interface's path)
    for every channel, the others where a channel sees them with non-zero beam gains
    (else amplitude 0 at the first's delay)."""
    rows = np.ascontiguousarray(rows, dtype=np.float64).reshape(-1, 4)
    rx = np.atleast_2d(np.asarray(rx, dtype=np.float64))
    tx = np.asarray(tx, dtype=np.float64)
    n_ch = rx.shape[0]
    c0 = float(media.c[0])
    k = 2.0 * math.pi * frequency / c0
    k2 = 2.0 * (2.0 * math.pi / c0) ** 2 * media.rough[1] ** 2
    wave_k = np.hypot(rows[:, 1], rows[:, 2])
    live = (rows[:, 0] != 0.0) & (wave_k > 0.0)
    slope = float((np.abs(rows[:, 0]) * wave_k).sum())
    shortest = 2.0 * math.pi / wave_k[live].max() if live.any() else math.inf
    crest = float(np.abs(rows[:, 0]).sum())
    # over a plane the level specular point is the one start
    spacing = START_SPACING * shortest if live.any() else 1.0
    depth = water_depth if water_depth is not None else 0.0
    taus, amps, betas, labels, orders = [], [], [], [], []
    for seq in sequences:
        a, b, tx_mirrored, rx_mirrored = _images(seq, tx, rx, depth)
        if np.any(a[:, 2] >= -crest) or np.any(b[:, 2] >= -crest):
            raise ValueError(f"sequence {seq.sequence!r}: an element or its image is not "
                             "above the undulating interface's crests")
        out = np.zeros((n_ch, MAX_POINTS, N_FIELDS))
        count = np.zeros(n_ch, dtype=np.int64)
        _points(a, b, rows, slope, spacing, k, out, count)
        if np.any(count == MAX_POINTS):
            log.warning("sequence %s: %d channel(s) have more than %d stationary points "
                        "(the rest left out)", seq.sequence, int((count == MAX_POINTS).sum()),
                        MAX_POINTS)
        if np.any(count == 0):
            raise RuntimeError(f"sequence {seq.sequence!r}: no specular point found for "
                               f"{int((count == 0).sum())} channel(s)")
        valid = np.arange(MAX_POINTS)[None, :] < count[:, None]
        length = np.where(valid, out[..., F_L], np.inf)
        # earliest first
        order = np.argsort(length, axis=1, kind="stable")
        out = np.take_along_axis(out, order[..., None], axis=1)
        valid = np.take_along_axis(valid, order, axis=1)
        length = out[..., F_L]
        cos_inc = np.clip(out[..., F_COS], 0.0, 1.0)
        # the legs' directions at the elements (a mirrored leg leaves or meets its
        # element with the vertical part turned over)
        d_tx = out[..., F_E1:F_E1 + 3].copy()
        d_rx = out[..., F_E2:F_E2 + 3].copy()
        if tx_mirrored:
            d_tx[..., 2] *= -1.0
        if rx_mirrored:
            d_rx[..., 2] *= -1.0
        g_tx = tx_beam(d_tx @ bore)
        g_rx = rx_beam(d_rx @ bore)
        r = reflection_coefficient(np.arcsin(np.where(valid, cos_inc, 1.0)), rho_ratio,
                                   nu, delta)
        with np.errstate(divide="ignore", invalid="ignore"):
            amp = (g_tx * g_rx * r_surface ** seq.n_surface * r / length
                   * np.exp(-media.alpha[0] * length) * out[..., F_GAIN]
                   * _CAUSTIC_PHASE[out[..., F_NNEG].astype(np.int64)])
        amp = np.where(valid, amp, 0.0)
        # columns: the first point of every channel, then the others it sees
        keep = valid & ((np.arange(MAX_POINTS)[None, :] == 0) | (amp != 0))
        rank = np.cumsum(keep, axis=1) - 1
        n_col = int(keep.sum(axis=1).max())
        tau_s = np.repeat(length[:, :1] / c0, n_col, axis=1)
        amp_s = np.zeros((n_ch, n_col), dtype=complex)
        beta_s = np.zeros((n_ch, n_col))
        ch, j = np.nonzero(keep)
        tau_s[ch, rank[ch, j]] = length[ch, j] / c0
        amp_s[ch, rank[ch, j]] = amp[ch, j]
        beta_s[ch, rank[ch, j]] = k2 * cos_inc[ch, j] ** 2
        for col in range(n_col):
            taus.append(tau_s[:, col])
            amps.append(amp_s[:, col])
            betas.append(beta_s[:, col])
            labels.append(f"interface {seq.sequence}" if col == 0
                          else f"interface {seq.sequence} #{col + 1}")
            orders.append(seq.order)
    if not taus:
        z = np.zeros((n_ch, 0))
        return PathSet(z, z.astype(complex), z, z, [], np.zeros(0, dtype=int))
    return PathSet(np.stack(taus, 1), np.stack(amps, 1), np.stack(betas, 1),
                   np.zeros((n_ch, len(taus))), labels, np.array(orders, dtype=int))
