"""Plane-wave reflection and transmission at the water–sediment interface.

Fluid–fluid interface with a lossy lower medium (APL-UW TR 9407; PHYSICS.md section 2):
ρ = ρ_sed/ρ_w, ν = c_sed/c_w, δ loss parameter, κ = (1 + iδ)/ν,
P(θ) = √(κ² − cos²θ) on the branch Im P ≥ 0 (and Re P ≥ 0 where Im P = 0),
R(θ) = (ρ sinθ − P)/(ρ sinθ + P), pressure transmission T = 1 + R.
θ is the grazing angle in radians (0 horizontal, π/2 normal incidence).

P is kept complex throughout, so nothing turns into NaN at or near the critical angle
(where P → 0 for a lossless sediment) or at grazing incidence. The single point where
numerator and denominator of R both vanish (θ = 0 on a lossless ν = 1 sediment) takes
its limit (ρ − 1)/(ρ + 1).

Also here: the critical angle, Snell's law with a complex transmitted angle, Eckart's
coherent reflection from a rough interface, and the band-limited rms height of a
power-law roughness spectrum (PHYSICS.md section 3).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "check_grazing_angle",
    "kappa",
    "vertical_wavenumber_ratio",
    "reflection_coefficient",
    "transmission_coefficient",
    "critical_angle",
    "snell_grazing_angle",
    "transmitted_angle",
    "eckart_factor",
    "coherent_reflection_coefficient",
    "band_limited_rms_roughness",
]

_ANGLE_TOL = 1e-9


def check_grazing_angle(theta: ArrayLike) -> np.ndarray:
    """Return θ as a float array, clipped to [0, π/2]; raise ValueError if far outside.

    Values within 1e-9 rad of the interval (rounding of computed angles) are clipped.
    """
    th = np.asarray(theta, dtype=float)
    if np.any(~np.isfinite(th)):
        raise ValueError("grazing angle must be finite (radians)")
    if np.any(th < -_ANGLE_TOL) or np.any(th > np.pi / 2 + _ANGLE_TOL):
        raise ValueError(
            f"grazing angle must lie in [0, pi/2] rad; got range "
            f"[{th.min():.6g}, {th.max():.6g}] rad")
    return np.clip(th, 0.0, np.pi / 2)


def _check_medium(rho: ArrayLike, nu: ArrayLike, delta: ArrayLike):
    rho = np.asarray(rho, dtype=float)
    nu = np.asarray(nu, dtype=float)
    delta = np.asarray(delta, dtype=float)
    if np.any(~(rho > 0)) or np.any(~(nu > 0)):
        raise ValueError("density ratio rho and sound-speed ratio nu must be > 0")
    if np.any(~(delta >= 0)):
        raise ValueError("loss parameter delta must be >= 0")
    return rho, nu, delta


def kappa(nu: ArrayLike, delta: ArrayLike = 0.0) -> np.ndarray:
    """Complex wavenumber ratio κ = k_sed/k_w = (1 + iδ)/ν."""
    return (1.0 + 1j * np.asarray(delta, dtype=float)) / np.asarray(nu, dtype=float)


def vertical_wavenumber_ratio(theta: ArrayLike, nu: ArrayLike,
                              delta: ArrayLike = 0.0) -> np.ndarray:
    """P(θ) = √(κ² − cos²θ) with Im P ≥ 0 (complex; vertical wavenumber in the sediment / k_w).

    θ grazing angle (rad); ν sound-speed ratio; δ loss parameter.
    """
    th = np.asarray(theta, dtype=float)
    nu = np.asarray(nu, dtype=float)
    delta = np.asarray(delta, dtype=float)
    # near grazing, kappa^2 - cos^2 as (kappa^2 - 1) + sin^2: cos^2 rounds to 1 below
    # 1e-8 rad, which lost sin^2 and gave R = 1 on a matched sediment (nu = 1; exact:
    # (rho - 1)/(rho + 1)); elsewhere the direct form (as the ray code's, which takes cos)
    k2m1 = ((1.0 - nu) * (1.0 + nu) - delta * delta + 2j * delta) / (nu * nu)
    s = np.sin(th)
    arg = np.where(s * s < 1e-4, k2m1 + s * s, kappa(nu, delta) ** 2 - np.cos(th) ** 2)
    p = np.where(k2m1 == 0.0, s + 0j, np.sqrt(arg + 0j))      # s * s may underflow
    # numpy's principal root already has Re ≥ 0; flip the few cases a signed zero put
    # on the lower half plane so the transmitted wave decays (or is outgoing).
    return np.where(p.imag < 0.0, -p, p)


def reflection_coefficient(theta: ArrayLike, rho: ArrayLike, nu: ArrayLike,
                           delta: ArrayLike = 0.0) -> np.ndarray:
    """Rayleigh plane-wave (pressure) reflection coefficient R(θ), complex.

    R = (ρ sinθ − P)/(ρ sinθ + P). θ grazing angle (rad, 0…π/2); ρ density ratio;
    ν sound-speed ratio; δ loss parameter. |R| ≤ 1 for δ ≥ 0; |R| = 1 below the
    critical angle of a lossless fast sediment; R(0) = −1 unless κ = 1.
    """
    th = check_grazing_angle(theta)
    rho, nu, delta = _check_medium(rho, nu, delta)
    p = vertical_wavenumber_ratio(th, nu, delta)
    a = rho * np.sin(th)
    # both terms scaled to order 1: complex division of subnormals (θ ~ 1e-320) gave NaN
    scale = np.maximum(np.abs(a), np.abs(p))
    scale = np.where(scale > 0.0, scale, 1.0)
    a, p = a / scale, p.real / scale + 1j * (p.imag / scale)
    den = a + p
    zero = den == 0  # only θ = 0 with κ = 1 exactly (lossless, ν = 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = (a - p) / np.where(zero, 1.0, den)
    limit = (rho - 1.0) / (rho + 1.0) + 0j
    return np.where(zero, limit, r)


def transmission_coefficient(theta: ArrayLike, rho: ArrayLike, nu: ArrayLike,
                             delta: ArrayLike = 0.0) -> np.ndarray:
    """Pressure transmission coefficient water → sediment, T = 1 + R (complex)."""
    return 1.0 + reflection_coefficient(theta, rho, nu, delta)


def critical_angle(nu: ArrayLike) -> np.ndarray:
    """Critical grazing angle θc = arccos(1/ν) (rad) for a fast sediment (ν > 1).

    Returns NaN where ν ≤ 1 (a slow sediment has no critical angle).
    """
    nu = np.asarray(nu, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(nu > 1.0, np.arccos(np.minimum(1.0 / nu, 1.0)), np.nan)


def snell_grazing_angle(theta_1: ArrayLike, c_1: ArrayLike, c_2: ArrayLike) -> np.ndarray:
    """Grazing angle in medium 2 from Snell's law cosθ1/c1 = cosθ2/c2 (complex-safe).

    Returns a complex angle: real in (0, π/2] while cosθ2 ≤ 1; beyond total reflection
    cosθ2 > 1 and the angle is purely imaginary (i·arccosh(cosθ2)), describing an
    evanescent wave — never NaN. Works in either direction (water → sediment or back).
    """
    th = check_grazing_angle(theta_1)
    cos2 = np.cos(th) * np.asarray(c_2, dtype=float) / np.asarray(c_1, dtype=float)
    sin2 = np.sqrt(1.0 - cos2 * cos2 + 0j)
    sin2 = np.where(sin2.imag < 0.0, -sin2, sin2)
    # θ = −i log(cosθ + i sinθ), exact for complex angles.
    return -1j * np.log(cos2 + 1j * sin2)


def transmitted_angle(theta: ArrayLike, nu: ArrayLike, delta: ArrayLike = 0.0) -> np.ndarray:
    """Complex grazing angle θt of the wave transmitted into a (lossy) sediment.

    cosθt = cosθ/κ, sinθt = P/κ (the branch Im P ≥ 0). For δ = 0 above the critical
    angle θt is real, equal to the Snell angle arccos(ν cosθ).
    """
    th = check_grazing_angle(theta)
    k = kappa(nu, delta)
    p = vertical_wavenumber_ratio(th, nu, delta)
    return -1j * np.log((np.cos(th) + 1j * p) / k)


# ------------------------------------------------------------------------- roughness
def eckart_factor(theta: ArrayLike, frequency: ArrayLike, rms_roughness: ArrayLike,
                  c_water: ArrayLike) -> np.ndarray:
    """Eckart coherent-reflection factor exp(−2 k² h² sin²θ) (real, 0 < · ≤ 1).

    θ grazing angle (rad); frequency Hz; rms_roughness h (m); c_water m/s.
    """
    th = check_grazing_angle(theta)
    k = 2.0 * np.pi * np.asarray(frequency, dtype=float) / np.asarray(c_water, dtype=float)
    h = np.asarray(rms_roughness, dtype=float)
    return np.exp(-2.0 * (k * h * np.sin(th)) ** 2)


def coherent_reflection_coefficient(theta: ArrayLike, frequency: ArrayLike, rho: ArrayLike,
                                    nu: ArrayLike, delta: ArrayLike,
                                    rms_roughness: ArrayLike,
                                    c_water: ArrayLike) -> np.ndarray:
    """Coherent (specular) reflection from a rough interface, Eckart (1953), complex.

    R_coh = R(θ) · exp(−2 k² h² sin²θ); h = 0 gives R. Units as in
    :func:`reflection_coefficient` and :func:`eckart_factor`.
    """
    return (reflection_coefficient(theta, rho, nu, delta)
            * eckart_factor(theta, frequency, rms_roughness, c_water))


def band_limited_rms_roughness(spectral_strength: ArrayLike, spectral_exponent: ArrayLike,
                               k_min: ArrayLike, k_max: ArrayLike = np.inf) -> np.ndarray:
    """RMS height (m) of an isotropic power-law roughness W(K) = w2 K^−γ over K_min…K_max.

    h² = ∫∫ W d²K = 2π w2 (K_min^{2−γ} − K_max^{2−γ})/(γ − 2)  (γ ≠ 2),
    which for K_max = ∞ and γ > 2 is PHYSICS.md's 2π w2 K_min^{2−γ}/(γ − 2).
    The integral diverges at low K for γ > 2, hence the band limit.
    spectral_strength w2 in m^(4−γ); K in rad/m (K_min > 0). Returns h in m.
    """
    w2 = np.asarray(spectral_strength, dtype=float)
    g = np.asarray(spectral_exponent, dtype=float)
    kmin = np.asarray(k_min, dtype=float)
    kmax = np.asarray(k_max, dtype=float)
    if np.any(~(kmin > 0)) or np.any(~(kmax > kmin)):
        raise ValueError("need 0 < k_min < k_max (rad/m)")
    if np.any(np.isinf(kmax) & (g <= 2.0)):
        raise ValueError("an unbounded band needs spectral_exponent > 2")
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        e = 2.0 - g
        span = np.log(kmax / kmin)
        # (K_min^e - K_max^e)/(-e) = K_min^e expm1(e ln(K_max/K_min))/e: no cancellation
        # as gamma -> 2 (the difference of powers lost 7 digits at gamma = 2 + 1e-11)
        bounded = np.where(np.abs(e) < 1e-300, span,
                           kmin ** e * np.expm1(e * span) / np.where(e == 0, 1.0, e))
        power = np.where(np.isinf(kmax), kmin ** e / -e, bounded)
    return np.sqrt(2.0 * np.pi * w2 * power)
