"""Point-scatterer synthesis over an undulating interface (:mod:`sim_device.bed_undulation`).

The two passes of the reference kernels (:mod:`sim_device.synthesis_reference`: pass 1
over scatterers, pass 2 over channels through :mod:`sim_device.echo_loop`'s loops),
compiled with the leg of a curved interface, :func:`curved_leg_body`, in place of the
level one (:func:`sim_device.synthesis_reference.kernels_over`):

* a scatterer in the water or on the interface (``MED_INTERFACE``, at z = u(x, y)): the
  straight leg; an interface scatterer's strength is looked up at its grazing angle
  about the surface's local normal;
* a scatterer in the sediment (one half-space below an undulating interface): the
  Fermat crossing (:func:`sim_device.bed_undulation.crossing`), so the travel time is
  exact; spreading, transmission (1 + R down, 1 - R up at the local incidence angle) and
  attenuation are those of the tangent plane at the crossing (the surface's focusing of
  the ray tube is left out);
* the element's beam gain along the leg's departure from the element.

A leg carrying seabed bounces (n_b > 0, multipath order 2 and more) would need the
curved surface's image; scenes with an undulating interface refuse that order
(:func:`sim_device.scene.check_undulation`).

The kernels and their entry points take the bundles of :mod:`sim_device.synthesis_args`
as the reference ones do; the medium bundle's ray-table slot (``Medium.tab``) carries the
surface's rows (amplitude, kx, ky, phase; in the scatterers' ping-local frame:
:meth:`Undulation.shifted`) instead, which these legs use in its place. Everything here runs in double precision on
the CPU: a scene with an undulating interface pays for its crossings, a level one never
does.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numba as nb

from . import echo_loop
from .bed_undulation import crossing, surface
from .synthesis_args import MED_INTERFACE, Beam, Medium, Pass2, Points, TransmitLegs
from .synthesis_legs import _interp, cis_cycles, lagrange4, leg_amplitude, two_medium_terms
from .synthesis_reference import _deposit, kernels_over


@nb.njit(cache=True, inline="always")
def curved_leg_body(ex, ey, height, direction, f_surf, n_b, x, y, z, med, up, c, rho_m,
                    delta, alpha, z_top, rows, r_top, r_bot, bore, g_front, g_back,
                    lo_front, lo_back, hbuf, cbuf):
    """:func:`sim_device.synthesis_legs.leg_body` over the undulating interface ``rows`` (in
    the slot of the ray table; the scratch arrays are unused). Returns (delay s, complex
    amplitude factor, cos of the grazing angle about the local normal: at the scatterer
    for an interface scatterer, at the crossing for a buried one)."""
    ez = -height
    c0 = c[0]
    trans = complex(1.0, 0.0)
    if med <= 0:
        dx = x - ex
        dy = y - ey
        dz = z - ez
        r = math.sqrt(dx * dx + dy * dy + dz * dz)
        if r == 0.0:
            return 0.0, complex(0.0, 0.0), 0.0
        ux = dx / r
        uy = dy / r
        uz = dz / r
        tau = r / c0
        spread = 1.0 / r
        att = alpha[0] * r
        if med == MED_INTERFACE:
            _u, gx, gy, _a, _b, _c = surface(x, y, rows)
            cn = (uz - gx * ux - gy * uy) / math.sqrt(1.0 + gx * gx + gy * gy)
            q = math.sqrt(max(0.0, 1.0 - cn * cn))
        else:
            q = math.sqrt(ux * ux + uy * uy)
    else:
        c1 = c[1]
        sx, sy, sz, _ok = crossing(ex, ey, ez, x, y, z, c0, c1, rows)
        d0x = sx - ex
        d0y = sy - ey
        d0z = sz - ez
        d1x = x - sx
        d1y = y - sy
        d1z = z - sz
        l0 = math.sqrt(d0x * d0x + d0y * d0y + d0z * d0z)
        l1 = math.sqrt(d1x * d1x + d1y * d1y + d1z * d1z)
        if l0 == 0.0 or l1 == 0.0:
            return 0.0, complex(0.0, 0.0), 0.0
        tau = l0 / c0 + l1 / c1
        _u, gx, gy, _a, _b, _c = surface(sx, sy, rows)
        nn = 1.0 / math.sqrt(1.0 + gx * gx + gy * gy)
        cos0 = min(1.0, abs(d0z - gx * d0x - gy * d0y) * nn / l0)
        cos1 = min(1.0, abs(d1z - gx * d1x - gy * d1y) * nn / l1)
        sin0 = math.sqrt(max(0.0, 1.0 - cos0 * cos0))
        sin1 = math.sqrt(max(0.0, 1.0 - cos1 * cos1))
        # the tangent plane's two-medium ray with the crossing's ray parameter
        p = sin0 / c0
        cmax = c0 if c0 > c1 else c1  # noqa: FURB136
        s = min(p * cmax, 1.0 - 1e-15)
        t = s / math.sqrt(1.0 - s * s)
        h0 = l0 * cos0
        h1 = l1 * cos1
        rho = l0 * sin0 + l1 * sin1
        _p, _tau, spread, _cosp, _att = two_medium_terms(t, rho, h0, h1, c0, c1, alpha[0],
                                                         alpha[1], 1 if up else 0)
        att = alpha[0] * l0 + alpha[1] * l1
        q = sin0
        rk = _interp(r_top, q)
        trans = (1.0 - rk) if up else (1.0 + rk)
        ux = d0x / l0
        uy = d0y / l0
        uz = d0z / l0
    cos_off = ux * bore[0] + uy * bore[1] + direction * uz * bore[2]
    return tau, leg_amplitude(cos_off, f_surf, spread, att, trans, n_b, q, r_bot, g_front,
                              g_back, lo_front, lo_back), q


_legs = SimpleNamespace(leg_body=curved_leg_body, _interp=_interp, lagrange4=lagrange4)
_echo = echo_loop.build(nb.njit(cache=True, inline="always"), _legs, cis_cycles, _deposit)
#: the reference kernels over the curved leg: pass 1 into a TransmitLegs, pass 2 into a
#: complex buffer (``medium.tab``: the surface's rows)
curved_transmit_kernel, curved_accumulate_kernel = kernels_over(_echo, "curved")


def curved_transmit_legs(pts: Points, samp, img, medium: Medium, beam: Beam,
                         out: TransmitLegs) -> None:
    """Pass 1 over an undulating interface (:func:`curved_transmit_kernel`): every
    scatterer's transmit legs, one per projector image (rows of ``img``), into ``out``;
    ``medium.tab``: the surface's rows in the scatterers' frame
    (:meth:`~sim_device.bed_undulation.Undulation.shifted`)."""
    curved_transmit_kernel(pts, samp, img, medium, beam, out)


def curved_accumulate(p2: Pass2, buf):
    """Pass 2 over an undulating interface (:func:`curved_accumulate_kernel`) of pass 2's
    bundles (``p2.medium.tab``: the surface's rows; ``p2.paths.zmax``: the deepest
    scatterer per path) into ``buf`` (complex baseband). Returns the echoes added per
    channel."""
    return curved_accumulate_kernel(*p2, buf)
