"""Propagation between the sonar's elements and a target: buried and proud paths.

A target echo travels projector -> target -> receiver along two legs. Each leg here is
computed from an element (height h above the interface, tile frame: z down from the
interface) to the target centre:

* **Buried** (centre in sediment medium m >= 1): the refracted ray through the water and
  the layers above, solved in a proven bracket by Brent's method
  (:func:`sim_device.layered_rays.ray_tan`, Fermat's condition). Per leg: travel time,
  layered-media spreading (source in water for the incident leg, in medium m for the
  scattered leg), plane-wave pressure transmission at each boundary crossed (downwards
  1 + R, upwards 1 - R, R the Rayleigh coefficient of that boundary on the ray) and the
  sediment attenuation exp(-gamma f), gamma = sum_j 2 pi delta_j / c_j * (path length in
  layer j) (attenuation linear in frequency, PHYSICS.md section 5).
* **Proud** (centre in the water, depth < 0): the direct leg, and the leg reflected by
  the water-sediment interface (image of the element mirrored in z = 0), with the
  Rayleigh coefficient of the top sediment at the leg's grazing angle and Eckart's
  coherent loss exp(-2 k^2 h^2 sin^2 theta) = exp(-beta f^2). The echo has the four
  combinations direct/reflected x direct/reflected.

Over an undulating interface (:mod:`sim_device.bed_undulation`, one sediment half-space)
a buried target's leg crosses the curved surface at its Fermat point (exact travel time);
spreading and transmission are those of the tangent plane there, the look and arrival
directions the legs' own. A proud target's reflected leg is mirrored in the interface's
plane (the curved surface's image is not modelled).

Both legs also carry the element's beam gain (look direction along the leg's departure
from the element) and water absorption at the centre frequency. Surface multipath of
target echoes and reverberation inside the layers are not modelled. A target straddling
the interface is treated by its centre (buried if the centre is below it).

All factors here are in the physics convention exp(-i omega t) (as the form functions,
:mod:`sim_device.targets`); the synthesiser conjugates them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from ..bed_undulation import crossing
from ..bed_undulation import surface as surface_slopes
from ..layered_rays import leg_extents, ray_amplitude_terms, ray_tan, reflection

#: leg kinds
DIRECT, REFLECTED, REFRACTED = 0, 1, 2


@dataclass
class Legs:
    """One kind of leg from each of n elements to a target (arrays over elements).

    ``look``: unit vector from the element along the leg's departure (for beam gains);
    ``arrive``: unit direction of travel at the target of a wave going element ->
    target (the incident direction for a projector leg; minus the scattered direction
    for a receiver leg)."""
    kind: int
    time: np.ndarray        # s, one way
    factor: np.ndarray      # complex: spreading x transmission/reflection x absorption
    beta: np.ndarray        # s^2, coherent loss exp(-beta f^2)
    gamma: np.ndarray       # s, sediment attenuation exp(-gamma f)
    look: np.ndarray        # (n, 3)
    arrive: np.ndarray      # (n, 3)


@nb.njit(cache=True)
def _refracted(elements, target, med, c, rho, delta, z_top, upward, time, spread, trans,
               gamma, water_len, look, arrive):
    """Refracted legs from elements (n, 3) to a target in medium ``med`` >= 1."""
    n = elements.shape[0]
    h = np.empty(med + 1)
    zero = np.zeros(med + 1)
    for e in range(n):
        dx = target[0] - elements[e, 0]
        dy = target[1] - elements[e, 1]
        rho_h = math.sqrt(dx * dx + dy * dy)
        m = leg_extents(-elements[e, 2], target[2], med, z_top, h)
        t = ray_tan(rho_h, h, c, m)
        p, tau, sp, cos0, _ = ray_amplitude_terms(t, rho_h, h, c, zero, m,
                                                  med if upward else 0)
        time[e] = tau
        spread[e] = sp
        tr = 1.0 + 0j
        g = 0.0
        for j in range(1, m):
            r = reflection(c[j - 1] * p, rho[j] / rho[j - 1], c[j] / c[j - 1], delta[j])
            tr *= (1.0 - r) if upward else (1.0 + r)
            cos_j = math.sqrt(max(1e-300, 1.0 - (c[j] * p) ** 2))
            g += 2.0 * math.pi * delta[j] / c[j] * h[j] / cos_j
        trans[e] = tr
        gamma[e] = g
        water_len[e] = h[0] / cos0
        ux = dx / rho_h if rho_h > 0.0 else 0.0
        uy = dy / rho_h if rho_h > 0.0 else 0.0
        s0 = p * c[0]
        look[e, 0] = ux * s0
        look[e, 1] = uy * s0
        look[e, 2] = cos0
        sm = min(p * c[med], 1.0)
        arrive[e, 0] = ux * sm
        arrive[e, 1] = uy * sm
        arrive[e, 2] = math.sqrt(1.0 - sm * sm)


@nb.njit(cache=True)
def _refracted_curved(elements, target, c, rho, delta, upward, rows, time, spread, trans,
                      gamma, water_len, look, arrive):
    """Refracted legs from elements (n, 3) to a target in the half-space below the
    undulating interface ``rows``: the Fermat crossing, the tangent plane's terms."""
    c0 = c[0]
    c1 = c[1]
    px, py, pz = target[0], target[1], target[2]
    h = np.empty(2)
    zero = np.zeros(2)
    cmax = max(c0, c1)
    for e in range(elements.shape[0]):
        ex, ey, ez = elements[e, 0], elements[e, 1], elements[e, 2]
        sx, sy, sz, _ok = crossing(ex, ey, ez, px, py, pz, c0, c1, rows)
        d0 = np.array([sx - ex, sy - ey, sz - ez])
        d1 = np.array([px - sx, py - sy, pz - sz])
        l0 = math.sqrt(d0 @ d0)
        l1 = math.sqrt(d1 @ d1)
        _u, gx, gy, _a, _b, _c = surface_slopes(sx, sy, rows)
        nrm = np.array([-gx, -gy, 1.0]) / math.sqrt(1.0 + gx * gx + gy * gy)
        cos0 = min(1.0, abs(d0 @ nrm) / l0)
        cos1 = min(1.0, abs(d1 @ nrm) / l1)
        sin0 = math.sqrt(max(0.0, 1.0 - cos0 * cos0))
        sin1 = math.sqrt(max(0.0, 1.0 - cos1 * cos1))
        p = sin0 / c0
        s = min(p * cmax, 1.0 - 1e-15)
        h[0] = l0 * cos0
        h[1] = l1 * cos1
        _p, _tau, sp, _cos, _att = ray_amplitude_terms(s / math.sqrt(1.0 - s * s),
                                                       l0 * sin0 + l1 * sin1, h, c, zero,
                                                       2, 1 if upward else 0)
        time[e] = l0 / c0 + l1 / c1
        spread[e] = sp
        r = reflection(sin0, rho[1] / rho[0], c1 / c0, delta[1])
        trans[e] = (1.0 - r) if upward else (1.0 + r)
        gamma[e] = 2.0 * math.pi * delta[1] / c1 * l1
        water_len[e] = l0
        for j in range(3):
            look[e, j] = d0[j] / l0
            arrive[e, j] = d1[j] / l1


def refracted_legs(elements: np.ndarray, target: np.ndarray, med: int, media,
                   upward: bool, rows: np.ndarray | None = None) -> Legs:
    """Refracted legs from ``elements`` (n, 3) to a buried ``target`` (3,) in medium
    ``med`` of ``media`` (:class:`sim_device.environment.Media`); ``upward`` for
    receiver legs (the wave travels target -> element: spreading of a source in the
    sediment, transmission 1 - R). ``rows``: an undulating interface's rows
    (:class:`~sim_device.bed_undulation.Undulation`; None: level)."""
    elements = np.ascontiguousarray(elements, dtype=np.float64).reshape(-1, 3)
    n = elements.shape[0]
    time, spread, gamma, water_len = (np.empty(n) for _ in range(4))
    trans = np.empty(n, dtype=np.complex128)
    look, arrive = np.empty((n, 3)), np.empty((n, 3))
    if rows is not None:
        _refracted_curved(elements, np.asarray(target, dtype=np.float64), media.c,
                          media.rho, media.delta, bool(upward), rows, time, spread, trans,
                          gamma, water_len, look, arrive)
    else:
        _refracted(elements, np.asarray(target, dtype=np.float64), int(med), media.c,
                   media.rho, media.delta, media.z_top, bool(upward), time, spread, trans,
                   gamma, water_len, look, arrive)
    factor = spread * trans * np.exp(-media.alpha[0] * water_len)
    return Legs(REFRACTED, time, factor, np.zeros(n), gamma, look, arrive)


def water_legs(elements: np.ndarray, target: np.ndarray, media,
               reflected: bool) -> Legs:
    """Direct (``reflected`` False) or interface-reflected legs from ``elements`` (n, 3)
    to a proud ``target`` (3,) in the water (depth < 0). Without a seabed the reflected
    leg has a zero factor."""
    e = np.asarray(elements, dtype=np.float64).reshape(-1, 3)
    tgt = np.asarray(target, dtype=np.float64)
    c0 = float(media.c[0])
    d = tgt[None, :] - e
    if reflected:
        d[:, 2] = -tgt[2] - e[:, 2]             # towards the target's image below z = 0
    length = np.linalg.norm(d, axis=1)
    look = d / length[:, None]
    arrive = look.copy()
    factor = np.exp(-media.alpha[0] * length) / length + 0j
    beta = np.zeros(e.shape[0])
    if reflected:
        arrive[:, 2] = -arrive[:, 2]             # upgoing after the bounce
        if media.n > 1:
            sin_g = np.abs(look[:, 2])
            r = np.array([reflection(math.sqrt(max(0.0, 1.0 - s * s)),
                                     media.rho[1] / media.rho[0], media.c[1] / c0,
                                     media.delta[1]) for s in sin_g])
            factor = factor * r
            beta = 2.0 * (2.0 * math.pi / c0) ** 2 * media.rough[1] ** 2 * sin_g ** 2
        else:
            factor = factor * 0.0
    return Legs(REFLECTED if reflected else DIRECT, length / c0, factor, beta,
                np.zeros(e.shape[0]), look, arrive)


def target_legs(elements: np.ndarray, target: np.ndarray, med: int, media,
                upward: bool, rows: np.ndarray | None = None) -> list[Legs]:
    """Every leg kind between ``elements`` and a target in medium ``med``: the refracted
    leg for a buried target (``rows``: an undulating interface, None: level), the
    direct and reflected legs for a proud one."""
    if med >= 1:
        return [refracted_legs(elements, target, med, media, upward, rows)]
    return [water_legs(elements, target, media, False),
            water_legs(elements, target, media, True)]
