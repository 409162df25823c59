"""Bistatic geometry and the monostatic-equivalent approximation for targets.

The SVSS projector and receivers are not co-located: for a projector at P, a receiver
at R and a target at T the incident direction is k̂_i = (T − P)/|T − P|, the scattered
direction k̂_s = (R − T)/|R − T|, the scattering angle θ = arccos(k̂_i·k̂_s) (π for
backscatter) and the bistatic angle β = π − θ (the angle at the target between the
directions to projector and receiver).

Spheres have an exact bistatic series (:func:`.spheres.sphere_scattering_amplitude` at
θ = π − β).  For other targets (cylinders, discs) the monostatic result is evaluated
along the bisector b̂ = normalise(û_P + û_R) (û: unit vectors from the target), either

* ``"bisector"``: at the true frequency, or
* ``"kell"``: at the scaled frequency f·cos(β/2) (Kell 1965's bistatic equivalence
  theorem; it reproduces the specular path length, hence the phase, of convex bodies at
  high frequency).

:func:`sphere_bisector_error` measures both against the exact sphere series; see
``docs/targets.md`` for figures over the SVSS geometry.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from svss_daq.decibels import amplitude_to_db

from ._series import DEFAULT_TOL, as_frequency
from .materials import ElasticMaterial, Fluid
from .spheres import sphere_backscatter, sphere_scattering_amplitude

__all__ = [
    "BistaticGeometry",
    "angle_between",
    "bistatic_geometry",
    "bistatic_from_directions",
    "equivalent_monostatic_frequency",
    "max_bistatic_angle",
    "sphere_bisector_error",
]

_METHODS = ("bisector", "kell")


def _unit(v: np.ndarray, what: str) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    if np.any(n == 0) or not np.all(np.isfinite(n)):
        raise ValueError(f"{what}: zero-length or non-finite vector")
    return v / n


@dataclass(frozen=True)
class BistaticGeometry:
    """Directions and angles of one or many projector–target–receiver triples.

    ``incident_dir`` (…, 3): unit vector projector → target; ``scattered_dir`` (…, 3):
    unit vector target → receiver; ``scattering_angle`` θ (rad, π = backscatter);
    ``bistatic_angle`` β = π − θ (rad); ``bisector`` (…, 3): unit vector from the target
    along the bisector of the directions to projector and receiver (the look direction
    of the equivalent monostatic sonar).
    """

    incident_dir: np.ndarray
    scattered_dir: np.ndarray
    scattering_angle: np.ndarray
    bistatic_angle: np.ndarray
    bisector: np.ndarray


def bistatic_geometry(projector, receiver, target) -> BistaticGeometry:
    """Bistatic geometry from positions (m, arrays (…, 3) broadcast together; any
    Cartesian frame, float64)."""
    p = np.asarray(projector, dtype=np.float64)
    r = np.asarray(receiver, dtype=np.float64)
    t = np.asarray(target, dtype=np.float64)
    return bistatic_from_directions(-_unit(p - t, "projector - target"),
                                    _unit(r - t, "receiver - target"))


def bistatic_from_directions(incident_dir, scattered_dir) -> BistaticGeometry:
    """Bistatic geometry from the directions of travel at the target (unit vectors
    (…, 3)): incident (towards the target) and scattered (away from it). Refracted paths
    give these, not straight lines to the elements."""
    to_p = -np.asarray(incident_dir, dtype=np.float64)
    to_r = np.asarray(scattered_dir, dtype=np.float64)
    cos_beta = np.clip(np.sum(to_p * to_r, axis=-1), -1.0, 1.0)
    # atan2 form: accurate for small β (arccos loses precision near 1).
    cross = np.linalg.norm(np.cross(to_p, to_r), axis=-1)
    beta = np.arctan2(cross, cos_beta)
    s = to_p + to_r
    ns = np.linalg.norm(s, axis=-1, keepdims=True)
    bis = np.where(ns > 1e-12, s / np.where(ns > 0, ns, 1.0), np.nan)
    return BistaticGeometry(incident_dir=-to_p, scattered_dir=to_r,
                            scattering_angle=np.pi - beta, bistatic_angle=beta,
                            bisector=bis)


def angle_between(direction, axis) -> np.ndarray:
    """Angle (rad, 0..π) between ``direction`` and ``axis`` (arrays (…, 3)); e.g. the
    cylinder aspect ψ from the bisector and the cylinder axis, or a disc's tilt from the
    bisector and its normal."""
    d = _unit(np.asarray(direction, dtype=np.float64), "direction")
    a = _unit(np.asarray(axis, dtype=np.float64), "axis")
    c = np.sum(d * a, axis=-1)
    s = np.linalg.norm(np.cross(d, a), axis=-1)
    return np.arctan2(s, c)


def equivalent_monostatic_frequency(freq, bistatic_angle, method: str = "kell"):
    """Frequency (Hz) at which to evaluate the monostatic model along the bisector:
    ``freq`` for ``"bisector"``, ``freq·cos(β/2)`` for ``"kell"``.
    Shape ``np.shape(freq) + np.shape(bistatic_angle)``."""
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS}, got {method!r}")
    f = as_frequency(freq)
    beta = np.asarray(bistatic_angle, dtype=float)
    scale = np.cos(beta / 2.0) if method == "kell" else np.ones_like(beta)
    return np.multiply.outer(f, scale)


def max_bistatic_angle(separation: float, min_range: float) -> float:
    """Largest bistatic angle (rad) for a projector–receiver separation (m) when both are
    at least ``min_range`` (m) from the target: 2 arcsin(d / (2 R))."""
    return float(2.0 * np.arcsin(min(1.0, separation / (2.0 * min_range))))


def sphere_bisector_error(freq, radius: float, fluid: Fluid,
                          material: ElasticMaterial | None, bistatic_angle,
                          method: str = "kell",
                          tol: float = DEFAULT_TOL) -> tuple[np.ndarray, np.ndarray]:
    """Error of the monostatic-equivalent approximation for a sphere.

    Compares the exact bistatic series f(π − β) with the monostatic f_bs evaluated at
    :func:`equivalent_monostatic_frequency`.  Returns ``(ts_error_db, rel_error)``, each
    of shape ``np.shape(freq) + np.shape(bistatic_angle)``: TS(approx) − TS(exact) (dB)
    and |f_approx − f_exact| / |f_exact| (complex, includes phase).
    """
    f = as_frequency(freq)
    beta = np.asarray(bistatic_angle, dtype=float)
    exact = sphere_scattering_amplitude(f, radius, fluid, material,
                                        theta=np.pi - beta, tol=tol)
    f_eq = equivalent_monostatic_frequency(f, beta, method)
    approx = sphere_backscatter(f_eq.ravel(), radius, fluid, material,
                                tol=tol).reshape(f_eq.shape)
    ts_err = amplitude_to_db(np.abs(approx) / np.abs(exact))
    rel = np.abs(approx - exact) / np.abs(exact)
    return ts_err, rel
