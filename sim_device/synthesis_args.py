"""What the point-scatterer synthesis kernels take, as named bundles (``NamedTuple``,
which numba passes to CPU kernels and CUDA kernels alike), grouped by meaning: the
scatterers, their transmit legs, the element images and the paths kept between them, the
layered medium, a beam, and the baseband buffer's time window.

The same bundles serve the reference and fast kernels (:mod:`sim_device.synthesis`) and
the GPU kernel of :mod:`sim_device.synthesis_gpu`, and their entry points: pass 1's
take the bundles (``transmit_legs(pts, samp, img, medium, beam, out)``), pass 2's one
:class:`Pass2` of them. :func:`beam_of` and :func:`window` make the Beam and the Window of
a beam table and of the baseband buffer's axis. Also the column layout of an
element-image row and the interface scatterers' medium code.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from svss_daq.conventions import ECHO_PHASE_SIGN

#: columns of an element-image row: x, y (m), height above the interface (m), direction
#: (+1: leaves the element downwards), the surface factor R_s^n_s, seabed bounces n_b
IMG_X, IMG_Y, IMG_H, IMG_DIR, IMG_RS, IMG_NB = range(6)

#: scatterer medium code of interface scatterers (media >= 0 are volume/point scatterers)
MED_INTERFACE = -1


class Points(NamedTuple):
    """The scatterers, in the tile frame relative to the projector's horizontal
    position (z down from the interface)."""
    x: np.ndarray         # (k,) m
    y: np.ndarray         # (k,) m
    z: np.ndarray         # (k,) m below the interface
    med: np.ndarray       # (k,) medium index, MED_INTERFACE on the interface


class TransmitLegs(NamedTuple):
    """Every scatterer's transmit legs, one per projector image (pass 1's output)."""
    tau: np.ndarray       # (k, a) delay, s
    amp: np.ndarray       # (k, a) complex amplitude (times the scatterer's strength)


class Paths(NamedTuple):
    """The receivers' element images and which (transmit, receive) image pairs are
    synthesised."""
    img: np.ndarray       # (channels, b, 6) element-image rows (IMG_* columns)
    allowed: np.ndarray   # (a, b) bool: path synthesised
    zmax: np.ndarray      # (a, b) deepest scatterer of the path, m (finite)


class Medium(NamedTuple):
    """The layered medium, its interface tables and the interface scattering strength."""
    c: np.ndarray         # (media,) sound speeds, m/s (water first)
    rho: np.ndarray       # (media,) densities
    delta: np.ndarray     # (media,) loss parameters
    alpha: np.ndarray     # (media,) attenuation, Np/m
    z_top: np.ndarray     # (media,) depth of each medium's top below the interface, m
    tab: np.ndarray       # (n_w, n_v) two-medium ray table (s = p c_max)
    r_top: np.ndarray     # complex reflection coefficient of the interface over cos(grazing)
    r_bot: np.ndarray     # complex coherent (Eckart) seabed reflection over cos(grazing)
    sig: np.ndarray       # sigma^(1/4) of the interface over cos(grazing)


class Beam(NamedTuple):
    """An element's beam: boresight and the main- and back-lobe gain tables."""
    bore: np.ndarray      # (3,) boresight, unit vector
    front: np.ndarray     # main-lobe gain over cos(off-axis) in [lo_front, 1]
    back: np.ndarray      # back-lobe gain over -cos(off-axis) in [lo_back, 1] (may be empty)
    lo_front: float
    lo_back: float


class Window(NamedTuple):
    """The baseband buffer's time axis and the echoes it keeps."""
    sign: float           # ECHO_PHASE_SIGN times the carrier, Hz (echo phase in cycles / s)
    t_lo: float           # s: echoes with delay in (t_lo, t_hi) are kept
    t_hi: float
    t_buf0: float         # s, delay of buffer sample 0
    fs: float             # samples per second


class Pass2(NamedTuple):
    """Everything pass 2 takes but its output: the bundles in the order of the kernels'
    arguments (``kernel(*p2, ...)``)."""
    pts: Points
    legs_t: TransmitLegs
    paths: Paths
    medium: Medium
    beam: Beam
    win: Window


def beam_of(table, bore) -> Beam:
    """The :class:`Beam` of a beam table (:class:`sim_device.beams.BeamTable`: ``front``,
    ``back``, ``lo_front``, ``lo_back``) and the element's boresight ``bore``."""
    return Beam(np.ascontiguousarray(bore, dtype=np.float64), table.front, table.back,
                float(table.lo_front), float(table.lo_back))


def window(fc, t_lo, t_hi, t_buf0, fs) -> Window:
    """The :class:`Window` of a carrier ``fc`` (Hz) and the buffer's time axis."""
    return Window(float(ECHO_PHASE_SIGN * fc), float(t_lo), float(t_hi), float(t_buf0),
                  float(fs))
