"""Acoustic scattering by spheres: rigid fixed sphere and elastic solid sphere.

Modal (partial-wave) series, time dependence exp(-iωt).  For an incident plane wave of
unit amplitude the far scattered pressure is p_s = f(θ) e^{ikr}/r, with θ the
scattering angle (θ = 0 forward, θ = π backscatter) and the phase referenced to the
sphere centre:

    f(θ) = (−i/k) Σ_n (2n+1) b_n P_n(cos θ),   f_bs = f(π) = (−i/k) Σ_n (2n+1)(−1)^n b_n

* rigid fixed sphere:  b_n = −j_n'(ka) / h_n'(ka)
* elastic sphere (Faran 1951; Hickling 1962):
  b_n = −[j_n(ka) + G_n j_n'(ka)] / [h_n(ka) + G_n h_n'(ka)], with G_n from the
  solid's boundary conditions (see ``docs/targets.md``; G_n → ∞ is the rigid sphere).

TS = 20 log10 |f| (dB re 1 m²).  For echo synthesis with numpy's FFT convention
(components e^{+iωt}) use the complex conjugate of f.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._bessel import bessel_first
from ._series import (DEFAULT_TOL, as_frequency, complex_matmul, legendre_table,
                      modal_amplitudes, regular_pair, target_strength)
from .materials import ElasticMaterial, Fluid

__all__ = [
    "SphereSeries",
    "sphere_backscatter",
    "sphere_modal_series",
    "sphere_scattering_amplitude",
    "sphere_target_strength",
    "rigid_sphere_rayleigh_backscatter",
    "elastic_sphere_rayleigh_backscatter",
]


@dataclass(frozen=True)
class SphereSeries:
    """Sphere modal series: ``coefficients[i, n] = (2n+1) b_n`` (zero-padded beyond
    ``n_terms[i]``) at wavenumber ``k[i]`` (rad/m); ``converged[i]`` tolerance reached."""

    coefficients: np.ndarray
    n_terms: np.ndarray
    converged: np.ndarray
    k: np.ndarray


def _check_radius(radius: float) -> float:
    a = float(radius)
    if not (np.isfinite(a) and a > 0):
        raise ValueError(f"radius must be a positive finite length (m), got {radius!r}")
    return a


def _elastic_ratio(n: np.ndarray, x: np.ndarray, x1: np.ndarray, x2: np.ndarray,
                   rho_ratio: float, fluid_target: bool) -> tuple[np.ndarray, np.ndarray]:
    """Boundary-condition ratio G_n = num/den of an elastic (or fluid) sphere.

    ``n``: orders 0..N−1, shape (1, N); ``x = ka``, ``x1 = k_L a``, ``x2 = k_T a``,
    shape (F, 1); ``rho_ratio`` = ρ_fluid/ρ_solid.
    The pair (num, den) is homogeneous, so poles of the logarithmic derivatives of
    j_n(x1), j_n(x2) give finite results.
    """
    nmax = n.shape[-1] - 1
    u1, v1 = regular_pair(*bessel_first(nmax, x1[:, 0], True), x1, n, 0.5)
    if fluid_target:
        # Fluid sphere: continuity of pressure and normal velocity.
        return -(x / rho_ratio) * v1 * np.ones_like(u1), u1
    u2, v2 = regular_pair(*bessel_first(nmax, x2[:, 0], True), x2, n, 0.5)
    m = n * (n + 1.0)
    x2s = x2 * x2
    d11 = u1
    d12 = m * v2
    d21 = (2.0 * m - x2s) * v1 - 4.0 * u1
    d22 = 2.0 * m * (u2 - v2)
    d31 = 2.0 * (u1 - v1)
    d32 = (2.0 * m - 2.0 - x2s) * v2 - 2.0 * u2
    q = rho_ratio * x2s / x
    num = d21 * d32 - d22 * d31
    den = q * (d11 * d32 - d12 * d31)
    n0 = np.broadcast_to(n == 0, num.shape)
    num = np.where(n0, d21, num)      # n = 0: no shear wave is excited
    den = np.where(n0, q * d11, den)
    return num, den


def sphere_modal_series(freq, radius: float, fluid: Fluid,
                        material: ElasticMaterial | None = None,
                        tol: float = DEFAULT_TOL,
                        max_terms: int | None = None) -> SphereSeries:
    """Modal amplitudes (2n+1) b_n of a sphere for frequencies ``freq`` (Hz, 1-D).

    ``radius`` (m); ``fluid`` host medium; ``material`` None for a rigid fixed sphere.
    ``tol``: relative truncation tolerance (see :func:`._series.sum_modal_series`).
    """
    f = np.atleast_1d(as_frequency(freq)).ravel()
    a = _check_radius(radius)
    s, k = modal_amplitudes(f, a, fluid, material, True, _elastic_ratio,
                            lambda n: 2 * n + 1, tol=tol, max_terms=max_terms)
    return SphereSeries(s.coefficients, s.n_terms, s.converged, k)


def sphere_scattering_amplitude(freq, radius: float, fluid: Fluid,
                                material: ElasticMaterial | None = None,
                                theta=np.pi, tol: float = DEFAULT_TOL) -> np.ndarray:
    """Far-field scattering amplitude f(θ) (m, complex) of a sphere.

    ``freq`` (Hz, scalar or array), ``radius`` (m), ``fluid`` host medium, ``material``
    None for a rigid fixed sphere, ``theta`` scattering angle(s) (rad; 0 forward,
    π backscatter; the bistatic angle β gives θ = π − β).
    Returns shape ``np.shape(freq) + np.shape(theta)``.
    """
    shape = np.shape(freq) + np.shape(theta)
    theta = np.asarray(theta, dtype=float)
    if not np.all(np.isfinite(theta)):
        raise ValueError("theta must be finite (rad)")
    s = sphere_modal_series(freq, radius, fluid, material, tol=tol)
    mu = np.cos(theta.ravel())
    p = legendre_table(s.coefficients.shape[1], mu)           # (N, A)
    total = complex_matmul(s.coefficients, p)                 # (F, A)
    amp = (-1j / s.k)[:, None] * total
    return amp.reshape(shape)


def sphere_backscatter(freq, radius: float, fluid: Fluid,
                       material: ElasticMaterial | None = None,
                       tol: float = DEFAULT_TOL) -> np.ndarray:
    """Monostatic backscatter amplitude f_bs = f(π) (m, complex), shape of ``freq`` (Hz).

    ``radius`` (m); ``material`` None for a rigid fixed sphere.
    """
    s = sphere_modal_series(freq, radius, fluid, material, tol=tol)
    n = np.arange(s.coefficients.shape[1])
    sign = np.where(n % 2 == 0, 1.0, -1.0)
    amp = (-1j / s.k) * np.sum(s.coefficients * sign, axis=1)
    return amp.reshape(np.shape(freq))


def sphere_target_strength(freq, radius: float, fluid: Fluid,
                           material: ElasticMaterial | None = None,
                           tol: float = DEFAULT_TOL) -> np.ndarray:
    """Backscatter target strength TS = 20 log10 |f_bs| (dB re 1 m²) at ``freq`` (Hz)."""
    return target_strength(sphere_backscatter(freq, radius, fluid, material, tol=tol))


def rigid_sphere_rayleigh_backscatter(freq, radius: float, fluid: Fluid) -> np.ndarray:
    """Rayleigh (ka ≪ 1) limit of the rigid fixed sphere, f_bs = −(5/6) k² a³ (m)."""
    k = 2.0 * np.pi * as_frequency(freq) / fluid.sound_speed
    return -(5.0 / 6.0) * k**2 * _check_radius(radius) ** 3 + 0j


def elastic_sphere_rayleigh_backscatter(freq, radius: float, fluid: Fluid,
                                        material: ElasticMaterial) -> np.ndarray:
    """Rayleigh (ka ≪ 1) limit of a solid sphere (m):
    f_bs = −k² a³ [(1 − κ₁/κ)/3 + (ρ₁ − ρ)/(2ρ₁ + ρ)], with κ = 1/(ρc²) the fluid and
    κ₁ = 1/(ρ₁(c_L² − 4c_T²/3)) the solid's compressibility."""
    k = 2.0 * np.pi * as_frequency(freq) / fluid.sound_speed
    a = _check_radius(radius)
    kappa = 1.0 / (fluid.density * fluid.sound_speed**2)
    bulk = material.density * (material.c_l**2 - 4.0 * material.c_t**2 / 3.0)
    rho1, rho = material.density, fluid.density
    mono = (1.0 - (1.0 / bulk) / kappa) / 3.0
    dip = (rho1 - rho) / (2.0 * rho1 + rho)
    return -(k**2) * a**3 * (mono + dip) + 0j
