"""Digitiser scaling between acoustic pressure (uPa) at a hydrophone and ADC counts."""

from __future__ import annotations

import numpy as np

from .config import Digitiser


def counts_per_upa(dig: Digitiser) -> float:
    """ADC counts per micropascal of acoustic pressure at the hydrophone."""
    volts_per_upa = 10.0 ** ((dig.sensitivity_db_re_v_per_upa + dig.gain_db) / 20.0)
    full_scale_counts = 2 ** (dig.bits - 1) - 1
    return volts_per_upa * full_scale_counts / dig.full_scale_v


def full_scale_counts(dig: Digitiser) -> int:
    """Largest positive ADC code."""
    return 2 ** (dig.bits - 1) - 1


def quantise(pressure_upa: np.ndarray, dig: Digitiser) -> tuple[np.ndarray, int]:
    """Pressure (uPa) to int32 ADC codes, clipped at full scale.

    Returns the codes and the number of clipped samples.
    """
    x = np.rint(np.asarray(pressure_upa) * counts_per_upa(dig))
    fs = full_scale_counts(dig)
    clipped = int(np.count_nonzero(np.abs(x) > fs))
    return np.clip(x, -fs - 1, fs).astype(np.int32), clipped
