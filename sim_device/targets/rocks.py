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

R is the material's normal-incidence coefficient (ρ₁c_L − ρc)/(ρ₁c_L + ρc) (a half-space),
or, when the rock's ``thickness`` is given, the reflection coefficient of an elastic plate
of that thickness with the host fluid on both sides (:func:`plate_reflection`, exact for
an infinite plate: thickness resonances, leaky Lamb waves at oblique incidence) at the
local incidence angle of the facet (the angle between the normal and k̂_s − k̂_i).
Valid for ka ≫ 1 (the disc large compared with a wavelength) and moderate tilt; edge
diffraction and the plate's finite lateral size (no Lamb-wave re-radiation from edges)
are neglected.
"""

from __future__ import annotations

import numpy as np
from scipy.special import j1

from ._series import as_frequency, target_strength
from .materials import ElasticMaterial, Fluid

__all__ = [
    "plate_reflection",
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


def plate_reflection(freq, thickness: float, material: ElasticMaterial, fluid: Fluid,
                     cos_theta) -> tuple[np.ndarray, np.ndarray]:
    """Plane-wave reflection R and transmission T of an elastic plate (thickness d, m) in
    ``fluid`` (the same fluid on both sides) at incidence cos θ (θ from the normal).

    Time dependence exp(−iωt); R referenced to the lit face, T to the far face.  With
    ξ = k sin θ, the plate's vertical wavenumbers α = (k_L² − ξ²)^½, β = (k_T² − ξ²)^½
    (Im ≥ 0; complex k_L, k_T carry the loss), P = αd, Q = βd, the impedance ratios
    Z_L/Z = (ρ₁/ρ) k_z/α, Z_T/Z = (ρ₁/ρ) k_z/β and the mode-conversion weights
    cos² 2θ_T = (1 − 2ξ²/k_T²)², sin² 2θ_T = 4ξ²β²/k_T⁴:

        A = (Z_L/Z) cos² 2θ_T cot P + (Z_T/Z) sin² 2θ_T cot Q
        B = (Z_L/Z) cos² 2θ_T / sin P + (Z_T/Z) sin² 2θ_T / sin Q
        R = (A² − B² + 1) / ((A − i)² − B²),     T = −2iB / ((A − i)² − B²)

    (Brekhovskikh's plate in a liquid, in this sign convention; checked against a direct
    solution of the six boundary conditions in ``tests/targets/test_rocks.py``).  cot and
    1/sin are written with e^{2iP}, bounded for Im P ≥ 0, so a thick lossy plate tends to
    the half-space (A → −i Z_tot/Z, B → 0).  Broadcasts ``freq`` against ``cos_theta``.
    """
    f = np.asarray(freq, dtype=float)
    d = float(thickness)
    if not (np.isfinite(d) and d > 0):
        raise ValueError(f"thickness must be a positive finite length (m), got {thickness!r}")
    if material.is_fluid:
        raise ValueError("plate_reflection needs a solid (c_t > 0)")
    w = 2.0 * np.pi * f
    mu = np.clip(np.asarray(cos_theta, dtype=float), 0.0, 1.0)
    k = w / fluid.sound_speed
    kz = k * mu
    xi2 = (k * k) * (1.0 - mu * mu)
    k_l = w / material.complex_c_l
    k_t = w / material.complex_c_t

    def vertical(kk):
        q = np.sqrt(kk * kk - xi2 + 0j)
        q = np.where(q.imag < 0, -q, q)
        return np.where(q == 0, 1e-300, q)

    al, be = vertical(k_l), vertical(k_t)
    ratio = material.density / fluid.density
    zl = ratio * kz / al
    zt = ratio * kz / be
    kt2 = k_t * k_t
    c2 = (1.0 - 2.0 * xi2 / kt2) ** 2
    s2 = 4.0 * xi2 * be * be / (kt2 * kt2)
    with np.errstate(all="ignore"):
        ep, eq = np.exp(2j * al * d), np.exp(2j * be * d)
        cot_p, cot_q = 1j * (ep + 1) / (ep - 1), 1j * (eq + 1) / (eq - 1)
        csc_p = 2j * np.exp(1j * al * d) / (ep - 1)
        csc_q = 2j * np.exp(1j * be * d) / (eq - 1)
        a_ = zl * c2 * cot_p + zt * s2 * cot_q
        b_ = zl * c2 * csc_p + zt * s2 * csc_q
        den = (a_ - 1j) ** 2 - b_ * b_
        r = (a_ * a_ - b_ * b_ + 1.0) / den
        t = -2j * b_ / den
    grazing = kz == 0
    return np.where(grazing, -1.0 + 0j, r), np.where(grazing, 0j, t)


def _reflection(material: ElasticMaterial | None, fluid: Fluid, reflection) -> complex:
    if reflection is not None:
        return complex(reflection)
    if material is None:
        return 1.0 + 0j
    return material.normal_incidence_reflection(fluid)


def disc_backscatter(freq, radius: float, fluid: Fluid,
                     material: ElasticMaterial | None = None, tilt=0.0,
                     reflection: complex | None = None,
                     thickness: float | None = None) -> np.ndarray:
    """Monostatic Kirchhoff backscatter amplitude f_bs (m, complex) of a flat disc.

    ``freq`` (Hz), ``radius`` (m), ``tilt`` γ (rad): angle between the disc normal and
    the direction to the sonar (0 = normal incidence; |γ| ≥ π/2 gives 0, the face is
    not lit).  Reflection coefficient: ``reflection`` if given, else the plate's
    R(f, γ) when ``thickness`` (m) and ``material`` are given, else the material's
    normal-incidence half-space value (rigid, R = 1, if ``material`` is None).
    Returns shape ``np.shape(freq) + np.shape(tilt)``.
    """
    shape = np.shape(freq) + np.shape(tilt)
    f = np.atleast_1d(as_frequency(freq)).ravel()
    a = float(radius)
    if not (np.isfinite(a) and a > 0):
        raise ValueError(f"radius must be a positive finite length (m), got {radius!r}")
    g = np.asarray(tilt, dtype=float).ravel()
    cos_g = np.clip(np.cos(g), 0.0, None)[None, :]
    if reflection is None and thickness is not None and material is not None:
        refl = plate_reflection(f[:, None], thickness, material, fluid, cos_g)[0]
    else:
        refl = _reflection(material, fluid, reflection)
    k = (2.0 * np.pi * f / fluid.sound_speed)[:, None]
    sin_g = np.abs(np.sin(g))[None, :]
    amp = (-1j * k * a * a / 2.0) * refl * cos_g * kirchhoff_disc_directivity(2 * k * a * sin_g)
    return amp.reshape(shape)


def disc_target_strength(freq, radius: float, fluid: Fluid,
                         material: ElasticMaterial | None = None, tilt=0.0,
                         reflection: complex | None = None,
                         thickness: float | None = None) -> np.ndarray:
    """TS (dB re 1 m²) of :func:`disc_backscatter`."""
    return target_strength(disc_backscatter(freq, radius, fluid, material, tilt, reflection,
                                            thickness))


def disc_scattering_amplitude(freq, radius: float, fluid: Fluid, incident_dir,
                              scattered_dir, normal,
                              material: ElasticMaterial | None = None,
                              reflection: complex | None = None,
                              thickness: float | None = None) -> np.ndarray:
    """Bistatic Kirchhoff scattering amplitude f (m, complex) of a flat disc.

    ``incident_dir``: unit vector(s) of the incident wave's direction of travel
    (projector → disc); ``scattered_dir``: unit vector(s) disc → receiver; ``normal``:
    disc normal (towards the lit side); arrays of shape (..., 3) broadcast together.
    Zero where either the projector or the receiver is behind the disc.  With
    ``thickness`` (m) and ``material``: the plate's R(f, θ) at the local incidence angle
    cos θ = |n̂·(k̂_s − k̂_i)| / |k̂_s − k̂_i| (the facet's specular angle).
    Returns shape ``np.shape(freq) + broadcast shape of the vectors' leading axes``.
    """
    f = as_frequency(freq)
    a = float(radius)
    ki = np.asarray(incident_dir, dtype=float)
    ks = np.asarray(scattered_dir, dtype=float)
    nh = np.asarray(normal, dtype=float)
    nh = nh / np.linalg.norm(nh, axis=-1, keepdims=True)
    dq = ki - ks                                        # (…, 3)
    dq_n = np.sum(dq * nh, axis=-1, keepdims=True)
    q_t = np.linalg.norm(dq - dq_n * nh, axis=-1)       # |in-plane part| / k
    fr = np.reshape(f, np.shape(f) + (1,) * q_t.ndim)
    if reflection is None and thickness is not None and material is not None:
        cos_loc = np.abs(dq_n[..., 0]) / np.maximum(np.linalg.norm(dq, axis=-1), 1e-300)
        refl = plate_reflection(fr, thickness, material, fluid, cos_loc)[0]
    else:
        refl = _reflection(material, fluid, reflection)
    # Kirchhoff obliquity [R n̂·(k̂_s − k̂_i) + n̂·(k̂_s + k̂_i)]/2 (R cos γ in backscatter).
    obliq = (refl * np.sum(nh * (ks - ki), axis=-1) + np.sum(nh * (ks + ki), axis=-1)) / 2.0
    lit = (np.sum(nh * ki, axis=-1) < 0) & (np.sum(nh * ks, axis=-1) > 0)
    k = 2.0 * np.pi * fr / fluid.sound_speed
    amp = (-1j * k * a * a / 2.0) * obliq * kirchhoff_disc_directivity(k * a * q_t)
    return np.where(lit, amp, 0.0)
