"""The complex-baseband phase convention, defined once.

s_bb(t) = s_analytic(t) * exp(-j 2 pi f_c t), with t the time since transmit. An echo with
two-way delay tau therefore carries the baseband phase exp(-j 2 pi f_c tau); an imager
removes it by multiplying by :func:`remodulation` (exp(+j 2 pi f_c tau)).
"""

from __future__ import annotations

import numpy as np


def baseband_carrier(t_s: np.ndarray, fc_hz: float) -> np.ndarray:
    """The factor exp(-j 2 pi f_c t) that brings an analytic signal to baseband."""
    return np.exp(-2j * np.pi * fc_hz * np.asarray(t_s, dtype=np.float64))


def echo_phase(tau_s: np.ndarray, fc_hz: float) -> np.ndarray:
    """Baseband phase factor of an echo with two-way delay tau: exp(-j 2 pi f_c tau)."""
    return np.exp(-2j * np.pi * fc_hz * np.asarray(tau_s, dtype=np.float64))


def remodulation(tau_s: np.ndarray, fc_hz: float) -> np.ndarray:
    """Factor exp(+j 2 pi f_c tau) that an imager applies at delay tau."""
    return np.exp(2j * np.pi * fc_hz * np.asarray(tau_s, dtype=np.float64))


#: sign of the phase of an echo at delay tau (exp(SIGN * j 2 pi f_c tau)); kernels that
#: compute the phase inline use this constant so that the convention stays in one place.
ECHO_PHASE_SIGN = -1.0

#: sign of the phase an imager applies at delay tau (exp(SIGN * j 2 pi f_c tau)).
REMODULATION_SIGN = -ECHO_PHASE_SIGN
