"""Fidelity options that make the synthesis follow what the image needs.

* **Scatterer density per resolution cell** (:func:`resolution_cell`,
  :func:`densities`): PoSSM's mean intensity does not depend on the density (each
  scatterer carries sqrt(sigma dA / n)); only the statistics do, and they need several
  scatterers per cell the sonar resolves. With ``[scattering]
  scatterers_per_resolution_cell = N`` the densities are N per resolution cell of one
  ping at nadir: depth c/(2B) (B the waveform's bandwidth, c the top sediment's speed
  for the volume), along and across lambda h / L (h the array's height above the
  interface, L the receive array's extent along and across, lambda at the carrier).
* **Volume depth cut-off by level** (:func:`volume_depth_limits`): a volume scatterer
  at depth z echoes, along a path (m_tx, m_rx), at the path's nadir sonar-equation level
  (as :mod:`sim_device.path_choice`) times sigma_v(z) dz |1 - R^2|^2 exp(-4 int alpha)
  with the spreading of the refracted nadir ray; with ``[scattering]
  volume_below_noise_db = X`` each path keeps the volume scatterers down to the depth
  where that level is X dB below the noise in the pulse's band. Multipath paths, being
  weaker, stop shallower than the direct path: multipath is synthesised only where its
  level matters.
* **Synthesis path** (``[scattering] synthesis``): ``fast`` (default,
  :func:`sim_device.synthesis.accumulate_fast`) or ``reference``
  (:func:`sim_device.synthesis.accumulate`); the two agree to float32 rounding.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from svss_daq.decibels import power_to_db

from .environment import Environment
from .path_choice import path_geometry

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ResolutionCell:
    """One ping's resolution cell at nadir (m): along, across, depth in water and in
    the top sediment."""
    along: float
    across: float
    depth_water: float
    depth_sediment: float

    @property
    def area(self) -> float:
        return self.along * self.across

    @property
    def volume(self) -> float:
        return self.area * self.depth_sediment


def resolution_cell(receivers_body: np.ndarray, pitch: float, bandwidth: float,
                    fc: float, altitude: float, c_water: float,
                    c_sediment: float) -> ResolutionCell:
    """The resolution cell of one ping at nadir: ``receivers_body`` (n, 3) element
    positions (body frame, x forward, y starboard), ``pitch`` the element spacing,
    ``altitude`` the array's height above the interface (m), ``bandwidth`` (Hz; for a
    CW pulse give 1 / duration)."""
    lam = c_water / fc
    ext = np.ptp(receivers_body[:, :2], axis=0) + pitch
    return ResolutionCell(lam * altitude / ext[0], lam * altitude / ext[1],
                          c_water / (2.0 * bandwidth), c_sediment / (2.0 * bandwidth))


def densities(cell: ResolutionCell, per_cell: float) -> tuple[float, float]:
    """(interface per m^2, volume per m^3) for ``per_cell`` scatterers per resolution
    cell."""
    return per_cell / cell.area, per_cell / cell.volume


def volume_depth_limits(*, allowed: np.ndarray, tx_z: float, rx_z: float,
                        water_depth: float | None, env: Environment, media, fc: float,
                        p0: float, pulse_s: float, r_bottom: complex, back_lobe: float,
                        noise_power: float, below_noise_db: float | None, z_max: float,
                        n: int = 2001) -> tuple[np.ndarray, dict]:
    """zmax[m_tx, m_rx]: the deepest volume scatterer each allowed path synthesises
    (module docstring; ``inf`` where no cut-off applies), and the levels used
    (dB re uPa^2 at the interface and the slope in dB/m, per path).

    ``tx_z``/``rx_z``: projector and mean receiver depth (tile frame, negative above the
    interface); ``r_bottom``: the interface's coherent R at normal incidence (seabed
    bounces of image legs); ``back_lobe``: back-lobe amplitude; ``z_max``: the scene's
    ``volume_max_depth_m``."""
    shape = allowed.shape
    zmax = np.full(shape, np.inf)
    info: dict = {}
    if below_noise_db is None or noise_power <= 0 or not env.has_seabed:
        return zmax, info
    depth = water_depth if water_depth is not None else 0.0
    c, alpha, z_top = media.c, media.alpha, media.z_top
    c0 = c[0]
    z = np.linspace(0.0, max(z_max, 1e-6), n)
    # per depth: medium, sigma_v, one-way attenuation (Np) and water-equivalent extent
    med = np.clip(np.searchsorted(z_top[1:], z, side="right"), 1, c.size - 1)
    sig_v = np.array([0.0] + [ly.sediment.volume_scattering_coefficient(fc)
                              for ly in env.layers])[med]
    att = np.concatenate([[0.0], np.cumsum(0.5 * (alpha[med[1:]] + alpha[med[:-1]])
                                            * np.diff(z))])
    stretch = np.concatenate([[0.0], np.cumsum(0.5 * (c[med[1:]] + c[med[:-1]]) / c0
                                               * np.diff(z))])
    floor = noise_power * 10.0 ** (-below_noise_db / 10.0)
    slab = c[1] * pulse_s / 2.0                    # the pulse's extent in the sediment
    r0 = abs(r_bottom)
    t4 = (1.0 - r0 * r0) ** 2                      # |T_down T_up|^2 at normal incidence
    for a in range(shape[0]):
        for b in range(shape[1]):
            if not allowed[a, b]:
                continue
            h_t, h_r, amp, area = path_geometry(a, b, tx_z, rx_z, depth, env, r0,
                                                back_lobe, pulse_s)
            ms = (0.5 * p0 ** 2 * amp ** 2 * t4 * sig_v * slab * area
                  * np.exp(-4.0 * att) / ((h_t + stretch) * (h_r + stretch)) ** 2)
            above = np.flatnonzero(ms >= floor)
            zmax[a, b] = float(z[above[-1]]) if above.size else 0.0
            info[(a, b)] = float(power_to_db(max(ms[1] if n > 1 else ms[0], 1e-300)))
            log.info("volume of path (%d, %d) kept down to %.2f m (level %.1f dB re uPa^2 "
                     "below the interface, floor %.1f dB)", a, b, zmax[a, b],
                     info[(a, b)], float(power_to_db(floor)))
    return zmax, info
