"""Diffuse bottom backscatter after APL-UW TR 9407 (PHYSICS.md section 4).

σ_b(θ) = σ_br(θ) + σ_bv(θ), every cross section linear, per unit area and solid angle
(backscattering strength = 10 log10 σ; see :mod:`svss_daq.decibels`).

Roughness spectrum: W(K) = w2 K^−γ (K rad/m, w2 in m^(4−γ)), 2 < γ < 4, α = γ/2 − 1.

* Kirchhoff (near normal): σ_kr = b q_c |R(π/2)|² / {8π [cos^{4α}θ + a q_c² sin⁴θ]^{(1+α)/(2α)}}
  with C_h², q_c, a, b from :func:`kirchhoff_parameters`.
* Perturbation (small roughness): σ_pr = 4 k⁴ sin⁴θ |Y|² W(2k cosθ),
  Y = [(ρ−1)² cos²θ + ρ² − κ²]/(ρ sinθ + P)².
* Composite roughness (this module's form, after the composite-roughness idea of
  Jackson, Winebrenner & Ishimaru 1986 used by TR 9407): the spectrum is split at K_c into
  large-scale slopes and small-scale ripple. K_c is set by the small-scale Rayleigh
  criterion 2 k h_s = 1, h_s² = 2π w2 K_c^{2−γ}/(γ−2), so
  K_c = [8π w2 k²/(γ−2)]^{1/(γ−2)}. The in-plane large-scale slope s' is Gaussian with
  variance s² = π w2 K_c^{4−γ}/(4−γ) (one component of the isotropic slope variance).
  σ_cr(θ) = S(θ) ∫ σ_pr,small(θ_l) p(s') ds',  θ_l = θ + arctan s' (facets facing the
  sonar, θ_l > 0; θ_l > π/2 is folded back to π − θ_l), where σ_pr,small uses W only for
  K ≥ K_c, and S(θ) = 1/(1 + Λ(v)), v = tanθ/(√2 s),
  Λ(v) = [e^{−v²}/(√π v) − erfc v]/2 is Smith's (1967) shadowing of a facet that faces
  the sonar. The integral is done by Gauss–Legendre quadrature over s' (±6 s).
* Blend: σ_br = f σ_kr + (1 − f) σ_cr, f(θ) = 1/(1 + e^{x}), x = β (θ_b − θ), θ in rad,
  default β = 80 rad⁻¹ and θ_b = 65°: σ_kr near normal incidence, σ_cr at low grazing
  (10 %→90 % of the way across 63.4°…66.6°). θ_b lies in the range where σ_kr and σ_pr
  agree (both tend to b q_c |R(π/2)|²/(8π cos^γ θ)); there σ_kr and σ_cr differ by less
  than 1 dB for the seed sediments at 20–35 kHz, so the switch leaves no visible step.
* Volume: σ_bv = 5 δ σ2 |1 − R²|² sin²θ / (ν ln10 |P|² Im P); σ2 = σ_v/α with σ_v the
  volume scattering coefficient (m⁻¹) and α the attenuation in dB/m. For δ = 0 the
  δ → 0 limit δ/Im P → ν² Re P is used.

All functions broadcast over θ (rad, 0…π/2), frequency (Hz) and the sediment parameters.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike
from scipy.special import erfc, gamma as gamma_fn

from svss_daq.decibels import power_to_db

from .attenuation import sediment_attenuation_db_per_m
from .interface import (check_grazing_angle, kappa, reflection_coefficient,
                        vertical_wavenumber_ratio)

__all__ = [
    "BLEND_CENTRE",
    "BLEND_STEEPNESS",
    "KirchhoffParameters",
    "BackscatterComponents",
    "roughness_spectrum",
    "kirchhoff_parameters",
    "sigma_kirchhoff",
    "sigma_perturbation",
    "composite_cutoff_wavenumber",
    "large_scale_slope_variance",
    "shadowing_factor",
    "sigma_composite",
    "blend_weight",
    "sigma_interface",
    "sigma_volume",
    "sigma2_from_volume_strength",
    "volume_strength_from_sigma2",
    "sigma_total",
    "bottom_backscatter",
]

#: Default blend centre θ_b (rad): 65° grazing.
BLEND_CENTRE = math.radians(65.0)
#: Default blend steepness β (rad⁻¹).
BLEND_STEEPNESS = 80.0
_SLOPE_SPAN = 6.0  # quadrature over |s'| ≤ 6 s
_N_QUAD = 48       # Gauss–Legendre nodes per integration region


class KirchhoffParameters(NamedTuple):
    """TR 9407 Kirchhoff intermediates (arrays broadcast like the inputs)."""
    alpha: np.ndarray  # γ/2 − 1
    ch2: np.ndarray    # C_h², structure-function constant, m^(2−2α)
    qc: np.ndarray     # q_c, dimensionless
    a: np.ndarray      # dimensionless
    b: np.ndarray      # dimensionless


class BackscatterComponents(NamedTuple):
    """Linear cross sections of :func:`bottom_backscatter`."""
    kirchhoff: np.ndarray
    composite: np.ndarray
    interface: np.ndarray
    volume: np.ndarray
    total: np.ndarray


def _wavenumber(frequency: ArrayLike, c_water: ArrayLike) -> np.ndarray:
    return 2.0 * np.pi * np.asarray(frequency, dtype=float) / np.asarray(c_water, dtype=float)


def _check_spectrum(spectral_strength: ArrayLike, spectral_exponent: ArrayLike):
    w2 = np.asarray(spectral_strength, dtype=float)
    g = np.asarray(spectral_exponent, dtype=float)
    if np.any(~(w2 >= 0)):
        raise ValueError("spectral strength w2 must be >= 0 (m^(4-gamma))")
    if np.any(~((g > 2.0) & (g < 4.0))):
        raise ValueError("spectral exponent gamma must lie in (2, 4) for TR 9407")
    return w2, g


def roughness_spectrum(wavenumber: ArrayLike, spectral_strength: ArrayLike,
                       spectral_exponent: ArrayLike) -> np.ndarray:
    """Isotropic 2-D power-law roughness spectrum W(K) = w2 K^−γ (m⁴).

    wavenumber K rad/m (> 0); spectral_strength w2 in m^(4−γ); spectral_exponent γ.
    """
    k = np.asarray(wavenumber, dtype=float)
    return np.asarray(spectral_strength, dtype=float) * k ** (-np.asarray(spectral_exponent,
                                                                          dtype=float))


def kirchhoff_parameters(frequency: ArrayLike, spectral_strength: ArrayLike,
                         spectral_exponent: ArrayLike, c_water: ArrayLike) -> KirchhoffParameters:
    """C_h², q_c, a, b of TR 9407 for the Kirchhoff term (PHYSICS.md section 4).

    C_h² = 2π w2 Γ(2−α) 2^{−2α} / [α(1−α) Γ(1+α)],  q_c = C_h² 2^{1−2α} k^{2(1−α)},
    a = [8α² Γ(1/(2α)+½) / (Γ(½) Γ(1/α) Γ(1/(2α)))]^{2α},  b = a^{(1+α)/(2α)} Γ(1/α)/(2α).
    frequency Hz; w2 m^(4−γ); γ in (2, 4); c_water m/s.
    """
    w2, g = _check_spectrum(spectral_strength, spectral_exponent)
    k = _wavenumber(frequency, c_water)
    al = g / 2.0 - 1.0
    ch2 = (2.0 * np.pi * w2 * gamma_fn(2.0 - al) * 2.0 ** (-2.0 * al)
           / (al * (1.0 - al) * gamma_fn(1.0 + al)))
    qc = ch2 * 2.0 ** (1.0 - 2.0 * al) * k ** (2.0 * (1.0 - al))
    a = (8.0 * al**2 * gamma_fn(1.0 / (2.0 * al) + 0.5)
         / (gamma_fn(0.5) * gamma_fn(1.0 / al) * gamma_fn(1.0 / (2.0 * al)))) ** (2.0 * al)
    b = a ** ((1.0 + al) / (2.0 * al)) * gamma_fn(1.0 / al) / (2.0 * al)
    return KirchhoffParameters(al, ch2, qc, a, b)


def sigma_kirchhoff(theta: ArrayLike, frequency: ArrayLike, rho: ArrayLike, nu: ArrayLike,
                    delta: ArrayLike, spectral_strength: ArrayLike,
                    spectral_exponent: ArrayLike, c_water: ArrayLike) -> np.ndarray:
    """Kirchhoff roughness backscatter σ_kr(θ) of TR 9407 (linear).

    θ grazing angle (rad); frequency Hz; ρ, ν, δ sediment ratios; w2 m^(4−γ); γ; c_water m/s.
    Its low-angle tail (≈ −35 dB at 5° for medium sand, 20 kHz) is not physical; use
    :func:`sigma_interface`, which hands over to the composite term there.
    """
    th = check_grazing_angle(theta)
    p = kirchhoff_parameters(frequency, spectral_strength, spectral_exponent, c_water)
    r90 = np.abs(reflection_coefficient(np.pi / 2, rho, nu, delta)) ** 2
    # w2 = 0 gives qc = 0 (and base = 0 where cosθ = 0 exactly): the limit is 0.
    with np.errstate(invalid="ignore", divide="ignore"):
        base = np.cos(th) ** (4.0 * p.alpha) + p.a * p.qc**2 * np.sin(th) ** 4
        out = p.b * p.qc * r90 / (8.0 * np.pi * base ** ((1.0 + p.alpha) / (2.0 * p.alpha)))
    return np.where(p.qc > 0, out, 0.0)


def _perturbation_k(th, k, rho, nu, delta, w2, g, k_cut):
    """σ_pr for wavenumber k (rad/m); no argument checks (internal)."""
    rho = np.asarray(rho, dtype=float)
    kap2 = kappa(nu, delta) ** 2
    p = vertical_wavenumber_ratio(th, nu, delta)
    s = np.sin(th)
    c = np.cos(th)
    num = (rho - 1.0) ** 2 * c * c + rho * rho - kap2
    den = rho * s + p
    zero = den == 0  # θ = 0 on a lossless ν = 1 sediment: sin²θ/(ρ sinθ + P)² → 1/(ρ+1)²
    with np.errstate(invalid="ignore", divide="ignore"):
        sy = np.where(zero, num / (rho + 1.0) ** 2,
                      s * s * num / np.where(zero, 1.0, den) ** 2)
    bragg = np.maximum(2.0 * k * np.abs(c), 1e-30 * k)
    w = np.where(bragg >= k_cut, w2 * bragg ** (-g), 0.0)
    return 4.0 * k**4 * np.abs(sy) ** 2 * w


def sigma_perturbation(theta: ArrayLike, frequency: ArrayLike, rho: ArrayLike, nu: ArrayLike,
                       delta: ArrayLike, spectral_strength: ArrayLike,
                       spectral_exponent: ArrayLike, c_water: ArrayLike,
                       k_cut: ArrayLike = 0.0) -> np.ndarray:
    """Small-roughness perturbation backscatter σ_pr(θ) = 4k⁴ sin⁴θ |Y|² W(2k cosθ).

    θ grazing angle (rad); frequency Hz; ρ, ν, δ; w2 m^(4−γ); γ; c_water m/s.
    k_cut (rad/m): W is taken as 0 below this Bragg wavenumber (the small-scale part of
    the spectrum used by :func:`sigma_composite`); 0 keeps the whole spectrum, for which
    σ_pr grows without bound toward normal incidence (the Bragg wavenumber → 0; it stays
    finite in floating point at θ = π/2). w2 = 0 gives 0.
    """
    th = check_grazing_angle(theta)
    w2, g = _check_spectrum(spectral_strength, spectral_exponent)
    k = _wavenumber(frequency, c_water)
    return _perturbation_k(th, k, rho, nu, delta, w2, g, np.asarray(k_cut, dtype=float))


def composite_cutoff_wavenumber(frequency: ArrayLike, spectral_strength: ArrayLike,
                                spectral_exponent: ArrayLike, c_water: ArrayLike,
                                rayleigh_parameter: float = 1.0) -> np.ndarray:
    """Large/small-scale split K_c (rad/m) of the composite model.

    Chosen so the small-scale (K > K_c) roughness has 2 k h_s = rayleigh_parameter:
    K_c = [2π w2 (2k)² / ((γ−2) rayleigh_parameter²)]^{1/(γ−2)}. frequency Hz; w2 m^(4−γ).
    """
    w2, g = _check_spectrum(spectral_strength, spectral_exponent)
    k = _wavenumber(frequency, c_water)
    return (2.0 * np.pi * w2 * (2.0 * k) ** 2 / ((g - 2.0) * rayleigh_parameter**2)) \
        ** (1.0 / (g - 2.0))


def large_scale_slope_variance(spectral_strength: ArrayLike, spectral_exponent: ArrayLike,
                               k_cut: ArrayLike) -> np.ndarray:
    """Variance of one slope component from the spectrum below K_c (dimensionless).

    s² = ½ ∫∫_{K<K_c} K² W(K) d²K = π w2 K_c^{4−γ}/(4−γ). k_cut rad/m; w2 m^(4−γ).
    """
    w2, g = _check_spectrum(spectral_strength, spectral_exponent)
    return np.pi * w2 * np.asarray(k_cut, dtype=float) ** (4.0 - g) / (4.0 - g)


def shadowing_factor(theta: ArrayLike, slope_rms: ArrayLike) -> np.ndarray:
    """Smith (1967) shadowing of a sonar-facing facet, S = 1/(1 + Λ(v)), v = tanθ/(√2 s).

    Λ(v) = [e^{−v²}/(√π v) − erfc v]/2. θ grazing angle (rad); slope_rms s (in-plane rms
    slope). S → 0 at θ = 0, S = 1 at θ = π/2 or for s = 0.
    """
    th = check_grazing_angle(theta)
    s = np.asarray(slope_rms, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        v = np.tan(th) / (np.sqrt(2.0) * s)
        lam = 0.5 * (np.exp(-v * v) / (np.sqrt(np.pi) * v) - erfc(v))
        out = 1.0 / (1.0 + lam)
    out = np.where(np.isinf(v) | (s <= 0), 1.0, out)
    return np.where(v == 0, 0.0, out)


@lru_cache(maxsize=8)
def _gauss_legendre(n: int):
    x, w = np.polynomial.legendre.leggauss(n)
    return x, w


def _integrate(lo, hi, func, n):
    """∫_lo^hi func(s') ds' by n-point Gauss–Legendre on a trailing axis (0 where hi ≤ lo)."""
    x, w = _gauss_legendre(n)
    lo = lo[..., None]
    hi = hi[..., None]
    width = np.maximum(hi - lo, 0.0)
    nodes = lo + 0.5 * (x + 1.0) * width
    vals = func(nodes)
    return np.sum(vals * w, axis=-1) * 0.5 * width[..., 0]


def sigma_composite(theta: ArrayLike, frequency: ArrayLike, rho: ArrayLike, nu: ArrayLike,
                    delta: ArrayLike, spectral_strength: ArrayLike,
                    spectral_exponent: ArrayLike, c_water: ArrayLike,
                    rayleigh_parameter: float = 1.0, n_quad: int = _N_QUAD) -> np.ndarray:
    """Composite-roughness perturbation backscatter σ_cr(θ) (linear); form in module doc.

    Slope-averaged small-scale σ_pr with Smith shadowing. θ grazing angle (rad);
    frequency Hz; ρ, ν, δ; w2 m^(4−γ); γ; c_water m/s; rayleigh_parameter sets K_c
    (see :func:`composite_cutoff_wavenumber`); n_quad Gauss–Legendre nodes per region.
    w2 = 0 gives 0.
    """
    th = check_grazing_angle(theta)
    w2, g = _check_spectrum(spectral_strength, spectral_exponent)
    k = _wavenumber(frequency, c_water)
    kc = composite_cutoff_wavenumber(frequency, w2, g, c_water, rayleigh_parameter)
    s2 = large_scale_slope_variance(w2, g, kc)
    s = np.sqrt(s2)
    th, k, kc, s, rho_b, nu_b, delta_b, w2_b, g_b = np.broadcast_arrays(
        th, k, kc, s, *(np.asarray(v, dtype=float) for v in (rho, nu, delta, w2, g)))
    # Local grazing angle where the Bragg wavenumber reaches the split: 2k cosθ_K = K_c.
    theta_k = np.arccos(np.clip(kc / (2.0 * k), 0.0, 1.0))
    span = _SLOPE_SPAN * s
    safe_s = np.where(s > 0, s, 1.0)

    def integrand(sp):
        thl = th[..., None] + np.arctan(sp)
        thl = 0.5 * np.pi - np.abs(0.5 * np.pi - thl)   # fold facets tilted past normal
        thl = np.clip(thl, 0.0, 0.5 * np.pi)
        sig = _perturbation_k(thl, k[..., None], rho_b[..., None], nu_b[..., None],
                              delta_b[..., None], w2_b[..., None], g_b[..., None],
                              kc[..., None])
        pdf = np.exp(-0.5 * (sp / safe_s[..., None]) ** 2) / (np.sqrt(2.0 * np.pi)
                                                               * safe_s[..., None])
        return sig * pdf

    # region A: 0 < θ_l ≤ θ_K  →  −tanθ < s' ≤ tan(θ_K − θ)
    lo_a = np.maximum(-np.tan(th), -span)
    hi_a = np.minimum(np.tan(theta_k - th), span)
    part_a = _integrate(lo_a, hi_a, integrand, n_quad)
    # region B: π − θ_K ≤ θ_l < π (facet tilted past normal) → s' ≥ tan(π − θ_K − θ)
    b_angle = np.pi - theta_k - th
    lo_b = np.where(b_angle < 0.5 * np.pi,
                    np.tan(np.minimum(b_angle, 0.5 * np.pi - 1e-12)), np.inf)
    lo_b = np.maximum(lo_b, lo_a)
    part_b = _integrate(np.minimum(lo_b, span), span, integrand, n_quad)
    out = shadowing_factor(th, s) * (part_a + part_b)
    return np.where((w2_b > 0) & (s > 0), out, 0.0)


def blend_weight(theta: ArrayLike, centre: float = BLEND_CENTRE,
                 steepness: float = BLEND_STEEPNESS) -> np.ndarray:
    """Kirchhoff weight f(θ) = 1/(1 + exp(β(θ_b − θ))) of the TR 9407-style blend.

    θ grazing angle (rad); centre θ_b (rad); steepness β (rad⁻¹). f → 1 near normal
    incidence, → 0 at low grazing; f(θ_b) = ½.
    """
    th = check_grazing_angle(theta)
    x = np.clip(steepness * (centre - th), -700.0, 700.0)
    return 1.0 / (1.0 + np.exp(x))


def sigma_interface(theta: ArrayLike, frequency: ArrayLike, rho: ArrayLike, nu: ArrayLike,
                    delta: ArrayLike, spectral_strength: ArrayLike,
                    spectral_exponent: ArrayLike, c_water: ArrayLike,
                    centre: float = BLEND_CENTRE, steepness: float = BLEND_STEEPNESS,
                    rayleigh_parameter: float = 1.0) -> np.ndarray:
    """Interface roughness backscatter σ_br = f σ_kr + (1 − f) σ_cr (linear).

    Arguments as :func:`sigma_kirchhoff`, plus the blend centre (rad), steepness (rad⁻¹)
    and the composite split (:func:`composite_cutoff_wavenumber`).
    """
    args = (theta, frequency, rho, nu, delta, spectral_strength, spectral_exponent, c_water)
    f = blend_weight(theta, centre, steepness)
    kr = sigma_kirchhoff(*args)
    cr = sigma_composite(*args, rayleigh_parameter=rayleigh_parameter)
    return f * kr + (1.0 - f) * cr


def sigma_volume(theta: ArrayLike, rho: ArrayLike, nu: ArrayLike, delta: ArrayLike,
                 sigma2: ArrayLike) -> np.ndarray:
    """Sediment volume backscatter seen through the interface, σ_bv(θ) (linear).

    σ_bv = 5 δ σ2 |1 − R²|² sin²θ / (ν ln10 |P|² Im P) (TR 9407); frequency independent
    for constant σ2 and δ. θ grazing angle (rad); ρ, ν, δ; σ2 = σ_v/α_dB (dimensionless).
    """
    th = check_grazing_angle(theta)
    nu_a = np.asarray(nu, dtype=float)
    d = np.asarray(delta, dtype=float)
    p = vertical_wavenumber_ratio(th, nu_a, d)
    r = reflection_coefficient(th, rho, nu_a, d)
    ap2 = np.abs(p) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        # δ/Im P, with its δ → 0 limit ν² Re P (finite above the critical angle).
        ratio = np.where(d > 0, d / np.where(p.imag > 0, p.imag, 1.0), nu_a**2 * p.real)
        ratio = np.where((d > 0) & ~(p.imag > 0), 0.0, ratio)
        geom = np.abs(1.0 - r * r) ** 2 * np.sin(th) ** 2 / np.where(ap2 > 0, ap2, 1.0)
    geom = np.where(ap2 > 0, geom, 0.0)
    return 5.0 * np.asarray(sigma2, dtype=float) * ratio * geom / (nu_a * math.log(10.0))


def sigma2_from_volume_strength(volume_strength_db: ArrayLike, frequency: ArrayLike,
                                sediment_sound_speed: ArrayLike,
                                loss_parameter: ArrayLike) -> np.ndarray:
    """σ2 = σ_v / α_dB from a volume scattering strength (dB re 1 m⁻¹) at a frequency.

    σ_v = 10^{S_v/10} m⁻¹; α_dB = sediment attenuation (dB/m) at that frequency (Hz).
    Medium sand, −20 dB/m at 20 kHz, α = 10.0 dB/m → σ2 ≈ 0.001 (the seed's pairing).
    """
    sv = 10.0 ** (np.asarray(volume_strength_db, dtype=float) / 10.0)
    alpha = sediment_attenuation_db_per_m(frequency, sediment_sound_speed, loss_parameter)
    return sv / alpha


def volume_strength_from_sigma2(sigma2: ArrayLike, frequency: ArrayLike,
                                sediment_sound_speed: ArrayLike,
                                loss_parameter: ArrayLike) -> np.ndarray:
    """Volume scattering strength (dB re 1 m⁻¹) at a frequency for a given σ2."""
    alpha = sediment_attenuation_db_per_m(frequency, sediment_sound_speed, loss_parameter)
    return power_to_db(np.asarray(sigma2, dtype=float) * alpha)


def sigma_total(theta: ArrayLike, frequency: ArrayLike, rho: ArrayLike, nu: ArrayLike,
                delta: ArrayLike, spectral_strength: ArrayLike, spectral_exponent: ArrayLike,
                sigma2: ArrayLike, c_water: ArrayLike, **blend) -> np.ndarray:
    """Total bottom backscatter σ_b = σ_br + σ_bv (linear). Arguments as above."""
    return (sigma_interface(theta, frequency, rho, nu, delta, spectral_strength,
                            spectral_exponent, c_water, **blend)
            + sigma_volume(theta, rho, nu, delta, sigma2))


def bottom_backscatter(theta: ArrayLike, frequency: ArrayLike, sediment,
                       water_density: float, water_sound_speed: float, *,
                       centre: float = BLEND_CENTRE, steepness: float = BLEND_STEEPNESS,
                       rayleigh_parameter: float = 1.0) -> BackscatterComponents:
    """All TR 9407 terms for a :class:`~.sediments.Sediment` (linear cross sections).

    θ grazing angle (rad); frequency Hz; water density kg/m³ and sound speed m/s define
    the ratios; blend and composite parameters as in :func:`sigma_interface`.
    """
    rho = sediment.density_ratio(water_density)
    nu = sediment.sound_speed_ratio(water_sound_speed)
    d = sediment.loss_parameter
    w2, g = sediment.spectral_strength, sediment.spectral_exponent
    args = (theta, frequency, rho, nu, d, w2, g, water_sound_speed)
    kr = sigma_kirchhoff(*args)
    cr = sigma_composite(*args, rayleigh_parameter=rayleigh_parameter)
    f = blend_weight(theta, centre, steepness)
    br = f * kr + (1.0 - f) * cr
    bv = sigma_volume(theta, rho, nu, d, sediment.sigma2())
    return BackscatterComponents(kr, cr, br, bv, br + bv)
