"""Flat-rock clutter: Kirchhoff (physical-optics) scattering by a flat circular disc.

Time dependence exp(-iωt); p_s = f e^{ikr}/r for a unit incident plane wave, phase
referenced to the disc centre.  Kirchhoff approximation for a flat facet S with unit
normal n̂ (towards the water), incident direction k̂_i (direction of travel),
scattered direction k̂_s and pressure reflection coefficient R:

    f = (−ik/4π) [R n̂·(k̂_s − k̂_i) + n̂·(k̂_s + k̂_i)] ∫_S exp(ik (k̂_i − k̂_s)·r') dS'

(surface field (1 + R)p_i, normal derivative (1 − R)∂p_i/∂n; the second bracket term
vanishes in the specular and backscatter directions).
For a disc of radius a the integral is πa² · 2J₁(qa)/(qa), q the in-plane component of
k(k̂_i − k̂_s).  Backscatter (k̂_s = −k̂_i) at tilt γ between the normal and the direction
to the sonar:

    f_bs = −i (k a²/2) R cos γ · 2J₁(2ka sin γ)/(2ka sin γ),  |f_bs(0)| = |R| k a²/2

R is the material's normal-incidence coefficient (ρ₁c_L − ρc)/(ρ₁c_L + ρc).  Valid for
ka ≫ 1 (the disc large compared with a wavelength) and moderate tilt; edge diffraction,
elastic waves in the rock and the rock's thickness are neglected.
"""

from __future__ import annotations

import numpy as np
from scipy.special import j1

from ._series import as_frequency, target_strength
from .materials import ElasticMaterial, Fluid

__all__ = [
    "disc_backscatter",
    "disc_scattering_amplitude",
    "disc_target_strength",
    "kirchhoff_disc_directivity",
]


def kirchhoff_disc_directivity(u) -> np.ndarray:
    """2 J₁(u)/u (dimensionless), equal to 1 at u = 0 (no division by zero)."""
    u = np.asarray(u, dtype=float)
    small = np.abs(u) < 1e-6
    safe = np.where(small, 1.0, u)
    return np.where(small, 1.0 - u * u / 8.0, 2.0 * j1(safe) / safe)


def _reflection(material: ElasticMaterial | None, fluid: Fluid, reflection) -> complex:
    if reflection is not None:
        return complex(reflection)
    if material is None:
        return 1.0 + 0j
    return material.normal_incidence_reflection(fluid)


def disc_backscatter(freq, radius: float, fluid: Fluid,
                     material: ElasticMaterial | None = None, tilt=0.0,
                     reflection: complex | None = None) -> np.ndarray:
    """Monostatic Kirchhoff backscatter amplitude f_bs (m, complex) of a flat disc.

    ``freq`` (Hz), ``radius`` (m), ``tilt`` γ (rad): angle between the disc normal and
    the direction to the sonar (0 = normal incidence; |γ| ≥ π/2 gives 0, the face is
    not lit).  Reflection coefficient: ``reflection`` if given, else the material's
    normal-incidence value (rigid, R = 1, if ``material`` is None).
    Returns shape ``np.shape(freq) + np.shape(tilt)``.
    """
    shape = np.shape(freq) + np.shape(tilt)
    f = np.atleast_1d(as_frequency(freq)).ravel()
    a = float(radius)
    if not (np.isfinite(a) and a > 0):
        raise ValueError(f"radius must be a positive finite length (m), got {radius!r}")
    g = np.asarray(tilt, dtype=float).ravel()
    refl = _reflection(material, fluid, reflection)
    k = (2.0 * np.pi * f / fluid.sound_speed)[:, None]
    cos_g = np.clip(np.cos(g), 0.0, None)[None, :]
    sin_g = np.abs(np.sin(g))[None, :]
    amp = (-1j * k * a * a / 2.0) * refl * cos_g * kirchhoff_disc_directivity(2 * k * a * sin_g)
    return amp.reshape(shape)


def disc_target_strength(freq, radius: float, fluid: Fluid,
                         material: ElasticMaterial | None = None, tilt=0.0,
                         reflection: complex | None = None) -> np.ndarray:
    """TS (dB re 1 m²) of :func:`disc_backscatter`."""
    return target_strength(disc_backscatter(freq, radius, fluid, material, tilt, reflection))


def disc_scattering_amplitude(freq, radius: float, fluid: Fluid, incident_dir,
                              scattered_dir, normal,
                              material: ElasticMaterial | None = None,
                              reflection: complex | None = None) -> np.ndarray:
    """Bistatic Kirchhoff scattering amplitude f (m, complex) of a flat disc.

    ``incident_dir``: unit vector(s) of the incident wave's direction of travel
    (projector → disc); ``scattered_dir``: unit vector(s) disc → receiver; ``normal``:
    disc normal (towards the lit side); arrays of shape (..., 3) broadcast together.
    Zero where either the projector or the receiver is behind the disc.
    Returns shape ``np.shape(freq) + broadcast shape of the vectors' leading axes``.
    """
    f = as_frequency(freq)
    a = float(radius)
    ki = np.asarray(incident_dir, dtype=float)
    ks = np.asarray(scattered_dir, dtype=float)
    nh = np.asarray(normal, dtype=float)
    nh = nh / np.linalg.norm(nh, axis=-1, keepdims=True)
    refl = _reflection(material, fluid, reflection)
    dq = ki - ks                                        # (…, 3)
    dq_n = np.sum(dq * nh, axis=-1, keepdims=True)
    q_t = np.linalg.norm(dq - dq_n * nh, axis=-1)       # |in-plane part| / k
    # Kirchhoff obliquity [R n̂·(k̂_s − k̂_i) + n̂·(k̂_s + k̂_i)]/2 (R cos γ in backscatter).
    obliq = (refl * np.sum(nh * (ks - ki), axis=-1) + np.sum(nh * (ks + ki), axis=-1)) / 2.0
    lit = (np.sum(nh * ki, axis=-1) < 0) & (np.sum(nh * ks, axis=-1) > 0)
    k = 2.0 * np.pi * np.reshape(f, np.shape(f) + (1,) * q_t.ndim) / fluid.sound_speed
    amp = (-1j * k * a * a / 2.0) * obliq * kirchhoff_disc_directivity(k * a * q_t)
    return np.where(lit, amp, 0.0)
