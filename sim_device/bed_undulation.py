"""An undulating seabed: the water-sediment interface as a sum of sinusoids about its
plane, and the exact ray geometry at such a surface (Fermat crossings, specular points,
ray hits).

In the bed frame of :mod:`sim_device.bed_plane` (the tile frame over a level bed: x along
the track, y to starboard, z down from the interface's plane) the interface lies at

    z = u(x, y) = sum_i a_i cos(kx_i x + ky_i y + phi_i),

each term a crest pattern of amplitude ``a_i`` (m), wavelength 2 pi / |k_i| and crests
normal to the wave vector (kx_i, ky_i), which points ``direction_deg`` from the
along-track axis towards starboard. A target's or point's ``depth_m`` is its depth below
the surface above it (bed frame z = u(x, y) + depth). A single sediment half-space lies
below an undulating interface (a layered one is refused at loading).

Every function of a leg here is exact for the curved surface:

* :func:`crossing`: the point where the fastest path from a point in the water to one in
  the sediment crosses the interface, by Newton's method on the two-dimensional travel
  time T(s) = |S - E|/c0 + |P - S|/c1, S = (sx, sy, u(sx, sy)) (Fermat's principle; the
  first arrival is the global minimum of T, which for a surface as gentle as a seabed's
  lies in the basin of the level-interface solution the iteration starts from). The
  travel time is then exact; the amplitude is taken through the tangent plane at S
  (Snell's law, transmission and attenuation exact there; the focusing of the ray tube
  by the surface's curvature left out).
* :func:`specular_point`: a stationary point of |S - A| + |S - B| over the surface (the
  coherent reflection's path).
* :func:`ray_hit`: the first intersection of a ray with the surface (a DVL beam).

The numba functions take the surface as ``rows`` (n, 4): amplitude, kx, ky, phase, the
form the synthesis kernels carry; :meth:`Undulation.shifted` gives the rows of a frame
whose origin is moved (the kernels' ping-local coordinates).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

#: Newton's step (m) below which a crossing or specular point has converged; the step is
#: still taken, leaving the point ~1e-12 m off, and the time is stationary there (a point
#: 1e-6 m off would change it by ~1e-16 s)
STEP_TOL = 1e-6
#: iterations before a crossing gives up (it has then converged to well below a
#: micrometre for any surface a scene accepts: the count is a safeguard)
MAX_ITER = 60


@dataclass(frozen=True)
class Undulation:
    """The interface's undulation about its plane: ``rows`` (n, 4) of amplitude (m),
    wave vector kx, ky (rad/m, bed frame) and phase (rad)."""
    rows: np.ndarray

    @classmethod
    def from_terms(cls, terms) -> "Undulation":
        """From (amplitude_m, wavelength_m, direction_deg, phase_deg) per term."""
        rows = []
        for a, lam, direction, phase in terms:
            k = 2.0 * math.pi / lam
            d = math.radians(direction)
            rows.append((a, k * math.cos(d), k * math.sin(d), math.radians(phase)))
        return cls(np.array(rows, dtype=np.float64).reshape(-1, 4))

    @property
    def amplitude_bound(self) -> float:
        """The most the surface can depart from its plane, m."""
        return float(np.abs(self.rows[:, 0]).sum())

    @property
    def slope_bound(self) -> float:
        """An upper bound of the surface's gradient |grad u|."""
        return float((np.abs(self.rows[:, 0]) * np.hypot(self.rows[:, 1], self.rows[:, 2])).sum())

    @property
    def curvature_bound(self) -> float:
        """An upper bound of the surface's second derivatives, 1/m."""
        k2 = self.rows[:, 1] ** 2 + self.rows[:, 2] ** 2
        return float((np.abs(self.rows[:, 0]) * k2).sum())

    @property
    def shortest_wavelength(self) -> float:
        return float(2.0 * math.pi / np.hypot(self.rows[:, 1], self.rows[:, 2]).max())

    def height(self, x, y) -> np.ndarray:
        """u(x, y), m (arrays broadcast)."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        out = np.zeros(np.broadcast(x, y).shape)
        for a, kx, ky, ph in self.rows:
            out += a * np.cos(kx * x + ky * y + ph)
        return out

    def gradient(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """(du/dx, du/dy) at (x, y)."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        gx = np.zeros(np.broadcast(x, y).shape)
        gy = np.zeros_like(gx)
        for a, kx, ky, ph in self.rows:
            s = -a * np.sin(kx * x + ky * y + ph)
            gx += s * kx
            gy += s * ky
        return gx, gy

    def shifted(self, ox: float, oy: float) -> np.ndarray:
        """The rows of the same surface in a frame whose origin is at (ox, oy) of this
        one (u'(x', y') = u(x' + ox, y' + oy))."""
        r = np.array(self.rows, dtype=np.float64)
        r[:, 3] += r[:, 1] * ox + r[:, 2] * oy
        return np.ascontiguousarray(r)


# ------------------------------------------------------------------ numba kernels

@nb.njit(cache=True, inline="always")
def surface(x, y, rows):
    """u and its derivatives at (x, y): (u, ux, uy, uxx, uxy, uyy)."""
    u = 0.0
    ux = 0.0
    uy = 0.0
    uxx = 0.0
    uxy = 0.0
    uyy = 0.0
    for i in range(rows.shape[0]):
        a = rows[i, 0]
        kx = rows[i, 1]
        ky = rows[i, 2]
        arg = kx * x + ky * y + rows[i, 3]
        co = a * math.cos(arg)
        si = a * math.sin(arg)
        u += co
        ux -= si * kx
        uy -= si * ky
        uxx -= co * kx * kx
        uxy -= co * kx * ky
        uyy -= co * ky * ky
    return u, ux, uy, uxx, uxy, uyy


@nb.njit(cache=True, inline="always")
def _leg_terms(sx, sy, sz, ux, uy, uxx, uxy, uyy, qx, qy, qz, w):
    """One straight leg between the surface point S = (sx, sy, sz) (derivatives of the
    surface there: ux ... uyy) and a point Q, weighted ``w`` (a slowness): its length L,
    and w times the gradient and Hessian of L over (sx, sy)."""
    dx = sx - qx
    dy = sy - qy
    dz = sz - qz
    ln = math.sqrt(dx * dx + dy * dy + dz * dz)
    if ln == 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    ex = dx / ln
    ey = dy / ln
    ez = dz / ln
    # S_x = (1, 0, ux), S_y = (0, 1, uy), S_xx = (0, 0, uxx), ...
    da = ex + ez * ux
    db = ey + ez * uy
    saa = 1.0 + ux * ux
    sab = ux * uy
    sbb = 1.0 + uy * uy
    haa = (saa - da * da) / ln + ez * uxx
    hab = (sab - da * db) / ln + ez * uxy
    hbb = (sbb - db * db) / ln + ez * uyy
    return ln, w * da, w * db, w * haa, w * hab, w * hbb


@nb.njit(cache=True)
def _two_leg_newton(sx, sy, ax, ay, az, wa, bx, by, bz, wb, rows, minimise):
    """Newton's iteration for a stationary point of wa |S - A| + wb |S - B| over the
    surface, from (sx, sy). ``minimise``: a minimum is wanted (Fermat's first arrival):
    a step after which the time is higher is halved (from where it was taken), and where
    the Hessian is not positive definite the gradient is followed. One evaluation of the
    surface per iteration. Returns (sx, sy, converged)."""
    t_prev = math.inf
    x_prev = sx
    y_prev = sy
    px = 0.0
    py = 0.0
    lam = 1.0
    for _ in range(MAX_ITER):
        u, ux, uy, uxx, uxy, uyy = surface(sx, sy, rows)
        la, ga, gb, haa, hab, hbb = _leg_terms(sx, sy, u, ux, uy, uxx, uxy, uyy,
                                               ax, ay, az, wa)
        lb, ga2, gb2, haa2, hab2, hbb2 = _leg_terms(sx, sy, u, ux, uy, uxx, uxy, uyy,
                                                    bx, by, bz, wb)
        t = wa * la + wb * lb
        if minimise and t > t_prev:
            # the last step overshot: halve it, from where it was taken
            lam *= 0.5
            if lam * math.sqrt(px * px + py * py) < STEP_TOL:
                return x_prev, y_prev, True
            sx = x_prev + lam * px
            sy = y_prev + lam * py
            continue
        gx = ga + ga2
        gy = gb + gb2
        hxx = haa + haa2
        hxy = hab + hab2
        hyy = hbb + hbb2
        det = hxx * hyy - hxy * hxy
        if minimise and not (hxx > 0.0 and det > 0.0):
            # not convex here: a gradient step of the length the curvature allows
            scale = max(abs(hxx), abs(hyy), 1e-12)
            px = -gx / scale
            py = -gy / scale
        elif det != 0.0:
            px = -(hyy * gx - hxy * gy) / det
            py = -(hxx * gy - hxy * gx) / det
        else:
            return sx, sy, False
        if math.sqrt(px * px + py * py) < STEP_TOL:
            return sx + px, sy + py, True
        t_prev = t
        x_prev = sx
        y_prev = sy
        lam = 1.0
        sx += px
        sy += py
    return sx, sy, False


@nb.njit(cache=True, inline="always")
def level_start(ex, ey, ez, px, py, pz, c0, c1, u0):
    """Where the ray E -> P would cross a level interface at z = u0, nearly: the
    two-medium Snell condition sin0/c0 = sin1/c1 on the water leg's horizontal offset,
    by three Newton steps from the straight line (the start of :func:`crossing`, which
    converges from there)."""
    h0 = u0 - ez
    h1 = pz - u0
    dx = px - ex
    dy = py - ey
    rho = math.sqrt(dx * dx + dy * dy)
    if rho == 0.0 or h0 <= 0.0 or h1 <= 0.0:
        f = 0.0 if rho == 0.0 else min(1.0, max(0.0, h0 / max(h0 + h1, 1e-300)))
        return ex + f * dx, ey + f * dy
    r0 = rho * h0 / (h0 + h1)
    for _ in range(3):
        r1 = rho - r0
        q0 = math.sqrt(r0 * r0 + h0 * h0)
        q1 = math.sqrt(r1 * r1 + h1 * h1)
        f = r0 / (q0 * c0) - r1 / (q1 * c1)
        df = h0 * h0 / (q0 * q0 * q0 * c0) + h1 * h1 / (q1 * q1 * q1 * c1)
        r0 = min(rho, max(0.0, r0 - f / df))
    return ex + r0 / rho * dx, ey + r0 / rho * dy


@nb.njit(cache=True)
def crossing(ex, ey, ez, px, py, pz, c0, c1, rows):
    """Where the first arrival between E (water, z = ez above the surface) and P
    (sediment) crosses the surface ``rows``: (sx, sy, sz, converged)."""
    u0 = surface(px, py, rows)[0]
    u0 = min(u0, pz - 1e-9)
    sx, sy = level_start(ex, ey, ez, px, py, pz, c0, c1, u0)
    return crossing_from(sx, sy, ex, ey, ez, px, py, pz, c0, c1, rows)


@nb.njit(cache=True, inline="always")
def crossing_from(sx, sy, ex, ey, ez, px, py, pz, c0, c1, rows):
    """:func:`crossing` from the start (sx, sy) (a neighbouring leg's crossing, moved)."""
    sx, sy, ok = _two_leg_newton(sx, sy, ex, ey, ez, 1.0 / c0, px, py, pz, 1.0 / c1,
                                 rows, True)
    return sx, sy, surface(sx, sy, rows)[0], ok


@nb.njit(cache=True)
def specular_point(ax, ay, az, bx, by, bz, sx, sy, rows):
    """A stationary point of |S - A| + |S - B| on the surface (A, B above it), by
    Newton's method from (sx, sy): (sx, sy, sz, converged)."""
    sx, sy, ok = _two_leg_newton(sx, sy, ax, ay, az, 1.0, bx, by, bz, 1.0, rows, False)
    return sx, sy, surface(sx, sy, rows)[0], ok


@nb.njit(cache=True)
def ray_hit(ox, oy, oz, dx, dy, dz, rows, bound, step):
    """Distance along the unit ray (d, pointing down: dz > 0) from O (above the surface)
    to its first intersection with the surface, whose departure from its plane is at
    most ``bound``; the ray is stepped by ``step`` (m, small against the surface's
    wavelengths) to bracket the first crossing, then bisected. NaN: no hit."""
    if dz <= 0.0:
        return math.nan
    t = max(0.0, (-bound - oz) / dz)
    t_end = (bound - oz) / dz + step
    f = oz + t * dz - surface(ox + t * dx, oy + t * dy, rows)[0]
    if f > 0.0:
        return math.nan                 # O lies below the surface
    if f == 0.0:
        return t
    while t < t_end:
        t2 = t + step
        f2 = oz + t2 * dz - surface(ox + t2 * dx, oy + t2 * dy, rows)[0]
        if f2 >= 0.0:
            lo = t
            hi = t2
            for _ in range(100):
                mid = 0.5 * (lo + hi)
                fm = oz + mid * dz - surface(ox + mid * dx, oy + mid * dy, rows)[0]
                if fm >= 0.0:
                    hi = mid
                else:
                    lo = mid
            return 0.5 * (lo + hi)
        t = t2
    return math.nan
