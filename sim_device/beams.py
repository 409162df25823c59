"""Lookup tables of the simulated transducers' directivity and the interface's levels.

The kernels look gains up by the cosine of the off-axis angle and interface quantities
by the cosine of the grazing angle, so no trigonometric function is evaluated per echo.
Tables are built from :mod:`sim_device.acoustics`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .acoustics import (Sediment, cone_gate, eckart_factor, piston_directivity,
                        piston_radius_for_half_angle, reflection_coefficient,
                        sigma_interface)

#: table sizes
GAIN_NODES = 2049
INTERFACE_NODES = 2049
REFLECTION_NODES = 8193


@dataclass(frozen=True)
class BeamTable:
    """Amplitude gain of one transducer against cos(off-axis angle).

    ``front`` covers cos in [lo_front, 1]; ``back`` (empty if there is no back lobe)
    covers -cos in [lo_back, 1]; elsewhere the gain is 0. ``edge``: the widest off-axis
    angle (rad) of the main lobe with a non-zero gain.
    """
    front: np.ndarray
    back: np.ndarray
    lo_front: float
    lo_back: float
    edge: float

    def __call__(self, cos_off) -> np.ndarray:
        """Gain for cos(off-axis angle) (vectorised; for tests and the coherent paths)."""
        u = np.asarray(cos_off, dtype=np.float64)
        out = np.zeros(u.shape)
        xs = np.linspace(self.lo_front, 1.0, self.front.size)
        inside = u >= self.lo_front
        out[inside] = np.interp(u[inside], xs, self.front)
        if self.back.size:
            xb = np.linspace(self.lo_back, 1.0, self.back.size)
            behind = ~inside & (-u >= self.lo_back)
            out[behind] = np.interp(-u[behind], xb, self.back)
        return out


def beam_table(half_angle: float, pattern: str, taper: float, back_lobe_db: float | None,
               frequency: float, sound_speed: float, n: int = GAIN_NODES) -> BeamTable:
    """Directivity of a transducer with a beam cone of ``half_angle`` (rad): flat
    ('cone') or a piston that is -3 dB at the half-angle ('piston', at ``frequency`` Hz
    in water of ``sound_speed`` m/s), times a raised-cosine taper of width ``taper`` (rad)
    across the cone edge (0: hard edge, the edge inside). A back lobe, if given, is the
    main lobe about -boresight at ``back_lobe_db`` (dB)."""
    edge = min(half_angle + 0.5 * taper, 0.5 * math.pi)
    lo = math.cos(edge)
    u = np.linspace(lo, 1.0, n)
    theta = np.arccos(np.clip(u, -1.0, 1.0))
    if taper > 0:
        g = cone_gate(theta, half_angle, taper)
    else:
        g = np.ones(n)                      # the hard edge is the table's lower end
    if pattern == "piston":
        a = piston_radius_for_half_angle(half_angle, frequency, sound_speed)
        g = g * piston_directivity(theta, frequency, a, sound_speed)
    elif pattern != "cone":
        raise ValueError(f"unknown beam pattern {pattern!r}")
    g = np.ascontiguousarray(g, dtype=np.float64)
    if back_lobe_db is None:
        back, lo_back = np.zeros(0), 2.0
    else:
        back, lo_back = g * 10.0 ** (back_lobe_db / 20.0), lo
    return BeamTable(g, np.ascontiguousarray(back), lo, lo_back, edge)


def _grazing_from_cos(n: int) -> np.ndarray:
    q = np.linspace(0.0, 1.0, n)
    return np.arccos(q)        # q = cos(grazing): 0 -> normal incidence, 1 -> grazing


def interface_sigma_table(sediment: Sediment | None, frequency: float, water_density: float,
                          water_sound_speed: float, model: str,
                          strength_db: float | None, n: int = INTERFACE_NODES) -> np.ndarray:
    """sigma^(1/4) of interface backscatter over cos(grazing) in [0, 1]: the APL-UW
    TR 9407 blend (Kirchhoff / composite roughness) or a constant strength."""
    if model == "constant":
        return np.full(n, 10.0 ** (strength_db / 40.0))
    if sediment is None:
        return np.zeros(n)
    theta = _grazing_from_cos(n)
    rho, nu, delta = sediment.ratios(water_density, water_sound_speed)
    sig = sigma_interface(theta, frequency, rho, nu, delta, sediment.spectral_strength,
                          sediment.spectral_exponent, water_sound_speed)
    return np.ascontiguousarray(np.maximum(sig, 0.0) ** 0.25)


def reflection_tables(sediment: Sediment | None, frequency: float, water_density: float,
                      water_sound_speed: float,
                      n: int = REFLECTION_NODES) -> tuple[np.ndarray, np.ndarray]:
    """(R, R_coh) of the water-sediment interface over cos(grazing) in [0, 1]: the
    Rayleigh coefficient and its Eckart coherent value at ``frequency``."""
    if sediment is None:
        z = np.zeros(n, dtype=np.complex128)
        return z, z.copy()
    theta = _grazing_from_cos(n)
    rho, nu, delta = sediment.ratios(water_density, water_sound_speed)
    r = reflection_coefficient(theta, rho, nu, delta)
    rc = r * eckart_factor(theta, frequency, sediment.rms_roughness, water_sound_speed)
    return (np.ascontiguousarray(r, dtype=np.complex128),
            np.ascontiguousarray(rc, dtype=np.complex128))
