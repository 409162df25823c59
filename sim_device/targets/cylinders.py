"""Acoustic backscattering by solid circular cylinders (rigid or elastic) at any aspect.

Time dependence exp(-iωt); far field p_s = f e^{ikr}/r for a unit incident plane wave,
phase referenced to the cylinder centre; TS = 20 log10 |f| (dB re 1 m²).

Infinite cylinder, normal incidence (Faran 1951): with ε_0 = 1, ε_n = 2,
    p_s → sqrt(2/(πkr)) e^{i(kr − π/4)} T(φ),   T(φ) = Σ_n ε_n b_n cos(nφ)
* rigid: b_n = −J_n'(ka)/H_n'(ka)
* elastic: b_n = −[J_n(ka) + G_n J_n'(ka)] / [H_n(ka) + G_n H_n'(ka)], G_n from the
  boundary conditions (continuity of normal displacement and normal stress, zero shear
  stress); see ``docs/targets.md``.
The conventional form function is f_∞ = 2|T(π)|/sqrt(π ka) (→ 1 for ka ≫ 1, rigid).

Finite cylinder of length L at aspect ψ (angle between the cylinder axis and the
direction to the sonar; ψ = π/2 broadside, 0 or π end-on) — the Stanton (1988)
finite-length approximation, a Fraunhofer integral of the infinite-cylinder solution
along the axis:
    f_side = (−iL/π) · sin(Δ)/Δ · T(π; K),  Δ = kL cos ψ,  K = k sin ψ
where T(π; K) is evaluated at the projected frequency f·sin ψ (all wavenumbers, water,
compressional and shear, scaled by sin ψ).  For a rigid cylinder these are the modal
coefficients of the exact oblique-incidence solution; for an elastic one the axial
(helical-wave) coupling of oblique incidence is neglected.  Assumes the far field of
the whole cylinder (r ≫ L²/λ) and L ≫ a; see ``docs/targets.md`` for validity.
The near flat end cap is added as a Kirchhoff disc (see
:func:`.rocks.disc_backscatter`), which dominates near end-on.  At broadside and
ka ≫ 1 the rigid result tends to Urick's |f|² = aL²/(2λ).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._bessel import bessel_first
from ._series import (DEFAULT_TOL, as_frequency, complex_matmul, modal_amplitudes,
                      regular_pair, target_strength)
from .materials import ElasticMaterial, Fluid
from .rocks import kirchhoff_disc_directivity

__all__ = [
    "CylinderSeries",
    "cylinder_modal_series",
    "infinite_cylinder_form",
    "infinite_cylinder_form_function",
    "finite_cylinder_backscatter",
    "cylinder_backscatter_at",
    "finite_cylinder_target_strength",
    "urick_cylinder_broadside_ts",
    "cylinder_rayleigh_form",
]

#: Smallest projected size parameter K a used near end-on (the series is evaluated there,
#: the side term is then ~ (Ka)² → 0).
_MIN_KA = 1e-6


@dataclass(frozen=True)
class CylinderSeries:
    """Infinite-cylinder modal series: ``coefficients[i, n] = ε_n b_n`` (zero-padded
    beyond ``n_terms[i]``) at water wavenumber ``k[i]`` (rad/m)."""

    coefficients: np.ndarray
    n_terms: np.ndarray
    converged: np.ndarray
    k: np.ndarray


def _positive(value, name: str) -> float:
    v = float(value)
    if not (np.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a positive finite length (m), got {value!r}")
    return v


def _elastic_ratio(n, x, x1, x2, rho_ratio, fluid_target):
    """Homogeneous (num, den) of G_n for an elastic (or fluid) cylinder; ``x = ka``,
    ``x1 = k_L a``, ``x2 = k_T a``, ``rho_ratio`` = ρ_fluid/ρ_solid."""
    nmax = n.shape[-1] - 1
    u1, v1 = regular_pair(*bessel_first(nmax, x1[:, 0], False), x1, n, 0.0)
    if fluid_target:
        return -(x / rho_ratio) * v1 * np.ones_like(u1), u1
    u2, v2 = regular_pair(*bessel_first(nmax, x2[:, 0], False), x2, n, 0.0)
    n2 = n * n * 1.0
    x2s = x2 * x2
    d11 = u1
    d12 = n * v2
    d21 = (2.0 * n2 - x2s) * v1 - 2.0 * u1
    d22 = 2.0 * n * (u2 - v2)
    d31 = 2.0 * n * (v1 - u1)
    d32 = (x2s - 2.0 * n2) * v2 + 2.0 * u2
    q = rho_ratio * x2s / x
    num = d21 * d32 - d22 * d31
    den = q * (d11 * d32 - d12 * d31)
    n0 = np.broadcast_to(n == 0, num.shape)
    num = np.where(n0, d21, num)
    den = np.where(n0, q * d11, den)
    return num, den


def cylinder_modal_series(freq, radius: float, fluid: Fluid,
                          material: ElasticMaterial | None = None,
                          tol: float = DEFAULT_TOL,
                          max_terms: int | None = None) -> CylinderSeries:
    """Modal amplitudes ε_n b_n of an infinite cylinder at normal incidence.

    ``freq`` (Hz, 1-D), ``radius`` (m), ``material`` None for rigid; ``tol`` relative
    truncation tolerance.
    """
    f = np.atleast_1d(as_frequency(freq)).ravel()
    a = _positive(radius, "radius")
    s, k = modal_amplitudes(f, a, fluid, material, False, _elastic_ratio,
                            lambda n: np.where(n == 0, 1.0, 2.0), tol=tol,
                            max_terms=max_terms)
    return CylinderSeries(s.coefficients, s.n_terms, s.converged, k)


def infinite_cylinder_form(freq, radius: float, fluid: Fluid,
                           material: ElasticMaterial | None = None, phi=np.pi,
                           tol: float = DEFAULT_TOL) -> np.ndarray:
    """T(φ) = Σ ε_n b_n cos(nφ) (dimensionless, complex) of an infinite cylinder at
    normal incidence; ``phi`` (rad) the scattering angle in the cross-section plane
    (π = backscatter).  Shape ``np.shape(freq) + np.shape(phi)``."""
    shape = np.shape(freq) + np.shape(phi)
    phi = np.asarray(phi, dtype=float).ravel()
    s = cylinder_modal_series(freq, radius, fluid, material, tol=tol)
    n = np.arange(s.coefficients.shape[1])
    out = complex_matmul(s.coefficients, np.cos(np.outer(n, phi)))
    return out.reshape(shape)


def infinite_cylinder_form_function(freq, radius: float, fluid: Fluid,
                                    material: ElasticMaterial | None = None,
                                    tol: float = DEFAULT_TOL) -> np.ndarray:
    """Normalised backscatter form function f_∞ = 2|T(π)|/sqrt(π ka) (dimensionless)."""
    t = infinite_cylinder_form(freq, radius, fluid, material, tol=tol)
    ka = 2.0 * np.pi * as_frequency(freq) * radius / fluid.sound_speed
    return 2.0 * np.abs(t) / np.sqrt(np.pi * ka)


def finite_cylinder_backscatter(freq, radius: float, length: float, fluid: Fluid,
                                material: ElasticMaterial | None = None,
                                aspect=np.pi / 2, end_caps: bool = True,
                                tol: float = DEFAULT_TOL) -> np.ndarray:
    """Backscatter amplitude f (m, complex) of a finite solid cylinder.

    ``freq`` (Hz), ``radius`` and ``length`` (m), ``material`` None for rigid,
    ``aspect`` ψ (rad, 0..π): angle between the cylinder axis and the direction from
    the cylinder to the sonar (π/2 broadside).  ``end_caps`` adds the near flat end as
    a Kirchhoff disc with the material's normal-incidence reflection coefficient
    (1 for rigid).  Returns shape ``np.shape(freq) + np.shape(aspect)``.
    """
    shape = np.shape(freq) + np.shape(aspect)
    f = np.atleast_1d(as_frequency(freq)).ravel()
    psi = np.asarray(aspect, dtype=float).ravel()
    out = cylinder_backscatter_at(f[:, None], psi[None, :], radius, length, fluid,
                                  material, end_caps=end_caps, tol=tol)
    return out.reshape(shape)


def cylinder_backscatter_at(freq, aspect, radius: float, length: float, fluid: Fluid,
                            material: ElasticMaterial | None = None,
                            end_caps: bool = True, tol: float = DEFAULT_TOL,
                            form=None) -> np.ndarray:
    """:func:`finite_cylinder_backscatter` element by element: ``freq`` (Hz) and
    ``aspect`` (rad) broadcast together. ``form``, if given, replaces the modal series:
    a callable giving T(π) at projected frequencies (Hz, 1-D), e.g. a table."""
    f, psi = np.broadcast_arrays(np.asarray(freq, dtype=float), np.asarray(aspect, dtype=float))
    if np.any(~np.isfinite(f)) or np.any(f <= 0):
        raise ValueError("frequency must be positive and finite (Hz)")
    a = _positive(radius, "radius")
    length = _positive(length, "length")
    if not np.all(np.isfinite(psi)):
        raise ValueError("aspect must be finite (rad)")
    cos_psi = np.cos(psi)
    sin_psi = np.abs(np.sin(psi))
    k = 2.0 * np.pi * f / fluid.sound_speed
    # Side: infinite-cylinder solution at the projected frequency f·sinψ, each distinct
    # value once (aspects ψ and π − ψ share it).
    min_f = _MIN_KA * fluid.sound_speed / (2.0 * np.pi * a)
    f_proj = np.maximum(f * np.round(sin_psi, 14), min_f)
    uniq, inverse = np.unique(f_proj, return_inverse=True)
    t_u = (infinite_cylinder_form(uniq, a, fluid, material, tol=tol) if form is None
           else form(uniq))
    t = t_u[inverse.reshape(f_proj.shape)]
    delta = k * cos_psi * length
    total = (-1j * length / np.pi) * np.sinc(delta / np.pi) * t
    if end_caps:
        refl = 1.0 if material is None else material.normal_incidence_reflection(fluid)
        total = total + ((-1j * k * a * a / 2.0) * refl * np.abs(cos_psi)
                         * kirchhoff_disc_directivity(2.0 * k * a * sin_psi)
                         * np.exp(-1j * k * length * np.abs(cos_psi)))
    return total


def finite_cylinder_target_strength(freq, radius: float, length: float, fluid: Fluid,
                                    material: ElasticMaterial | None = None,
                                    aspect=np.pi / 2, end_caps: bool = True,
                                    tol: float = DEFAULT_TOL) -> np.ndarray:
    """TS (dB re 1 m²) of :func:`finite_cylinder_backscatter`."""
    return target_strength(finite_cylinder_backscatter(
        freq, radius, length, fluid, material, aspect, end_caps, tol))


def urick_cylinder_broadside_ts(freq, radius: float, length: float,
                                sound_speed: float) -> np.ndarray:
    """Urick's high-frequency broadside TS = 10 log10(a L²/(2λ)) (dB re 1 m²)."""
    lam = sound_speed / as_frequency(freq)
    return 10.0 * np.log10(radius * length**2 / (2.0 * lam))


def cylinder_rayleigh_form(freq, radius: float, fluid: Fluid,
                           material: ElasticMaterial | None = None) -> np.ndarray:
    """Low-frequency (ka ≪ 1) limit of T(π) for an infinite cylinder (dimensionless):
    T = −(iπ(ka)²/4)[(1 − κ₁/κ) + 2(ρ₁ − ρ)/(ρ₁ + ρ)], with κ₁ = 1/(ρ₁(c_L² − c_T²))
    the plane-strain compressibility (rigid: κ₁ = 0, ρ₁ → ∞, bracket = 3)."""
    ka = 2.0 * np.pi * as_frequency(freq) * radius / fluid.sound_speed
    if material is None:
        bracket = 3.0
    else:
        kappa = 1.0 / (fluid.density * fluid.sound_speed**2)
        kappa1 = 1.0 / (material.density * (material.c_l**2 - material.c_t**2))
        rho1, rho = material.density, fluid.density
        bracket = (1.0 - kappa1 / kappa) + 2.0 * (rho1 - rho) / (rho1 + rho)
    return -1j * np.pi * ka**2 / 4.0 * bracket
