"""Decibel conversions for power-like and amplitude-like quantities.

Power-like quantities (scattering cross sections σ, intensities, spectral densities)
use 10·log10; amplitude-like quantities (pressures, directivity gains, reflection
coefficients) use 20·log10. Zero maps to −inf without a floating-point warning.

The one definition of decibels in the project: the simulator, the products and the
``svss`` tool all use it (in the lowest package, which all the others import).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["power_to_db", "db_to_power", "amplitude_to_db", "db_to_amplitude",
           "amplitude_to_db_floored"]


def power_to_db(value: ArrayLike) -> np.ndarray:
    """10·log10(value) for a power-like, non-negative quantity (0 → −inf)."""
    v = np.asarray(value, dtype=float)
    with np.errstate(divide="ignore"):
        return 10.0 * np.log10(v)


def db_to_power(level_db: ArrayLike) -> np.ndarray:
    """Inverse of :func:`power_to_db`: 10**(level/10)."""
    return np.power(10.0, np.asarray(level_db, dtype=float) / 10.0)


def amplitude_to_db(value: ArrayLike) -> np.ndarray:
    """20·log10|value| for an amplitude-like quantity, real or complex (0 → −inf)."""
    v = np.abs(np.asarray(value))
    with np.errstate(divide="ignore"):
        return 20.0 * np.log10(v)


def db_to_amplitude(level_db: ArrayLike) -> np.ndarray:
    """Inverse of :func:`amplitude_to_db`: 10**(level/20)."""
    return np.power(10.0, np.asarray(level_db, dtype=float) / 20.0)


def amplitude_to_db_floored(value: ArrayLike, floor_db: float) -> np.ndarray:
    """:func:`amplitude_to_db` limited below at ``floor_db`` (zeros give the floor)."""
    return np.maximum(amplitude_to_db(value), floor_db)
