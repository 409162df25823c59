"""Shared machinery for modal (partial-wave) series: truncation and summation.

Private module: the public models live in :mod:`spheres` and :mod:`cylinders`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Callable

import numpy as np

from svss_daq.decibels import amplitude_to_db

from ._bessel import bessel_first, bessel_second

log = logging.getLogger(__name__)

#: Default relative truncation tolerance of the modal series.
DEFAULT_TOL = 1e-10

#: Frequencies are processed in chunks of this many (sorted by size parameter) to bound
#: memory and avoid evaluating high orders for small size parameters.
_CHUNK = 256

#: |value| above which a Bessel function of the second kind is treated as overflowing.
_OVERFLOW = 1e250

#: Below this norm a regular Bessel pair (x f'(x), f(x)) is treated as underflowed.
_UNDERFLOW = 1e-280


def truncation_start(x: np.ndarray) -> np.ndarray:
    """Starting truncation order N = x + 4 x^(1/3) + 2 (x = largest size parameter)."""
    x = np.abs(np.asarray(x, dtype=complex)).astype(float)
    return np.ceil(x + 4.0 * np.cbrt(x) + 2.0).astype(np.int64)


@dataclass(frozen=True)
class ModalSeries:
    """Modal amplitudes of a series, padded with zeros beyond each row's truncation.

    ``coefficients[i, n]``: the n-th modal amplitude for frequency i (model-specific
    normalisation); ``n_terms[i]``: terms used; ``converged[i]``: tolerance reached.
    """

    coefficients: np.ndarray
    n_terms: np.ndarray
    converged: np.ndarray


def sum_modal_series(coef_fn: Callable[[np.ndarray, np.ndarray], np.ndarray],
                     x_max: np.ndarray, tol: float = DEFAULT_TOL,
                     max_terms: int | None = None) -> ModalSeries:
    """Evaluate modal amplitudes until convergence.

    ``coef_fn(n, rows)`` returns the complex amplitudes, shape (len(rows), len(n)), of
    orders ``n`` (always 0, 1, …, len(n) − 1) for the frequency indices ``rows``;
    non-finite entries mark overflow.
    A row stops at the first order n >= N_min where terms n and n+1 both satisfy
    |C| <= tol·|partial sum|.  N_min is the start rule N_start (see
    :func:`truncation_start`) for tol <= DEFAULT_TOL (the default), so the default and
    tighter tolerances never use fewer terms than the rule; for looser tolerances
    N_min = ceil(x) + 2 (past the turning point n ≈ x, beyond which the terms decay
    monotonically), so that a loose tol uses fewer terms.  A row also stops before the
    first non-finite term (Bessel overflow), in which case ``converged`` is False and a
    warning is logged.  ``max_terms`` caps the order (default 2·N_start + 40).
    """
    if not (tol > 0 and np.isfinite(tol)):
        raise ValueError(f"tol must be a positive finite number, got {tol!r}")
    x_max = np.atleast_1d(np.asarray(x_max))
    nf = x_max.size
    n_rule = truncation_start(x_max)
    cap_all = (2 * n_rule + 40) if max_terms is None else np.full(nf, int(max_terms))
    n0_all = n_rule if tol <= DEFAULT_TOL else np.ceil(np.abs(x_max)).astype(np.int64) + 2
    order = np.argsort(np.abs(x_max), kind="stable")
    blocks: list[tuple[np.ndarray, np.ndarray]] = []
    n_terms = np.zeros(nf, dtype=np.int64)
    converged = np.zeros(nf, dtype=bool)

    for start in range(0, nf, _CHUNK):
        pending = order[start:start + _CHUNK]
        rows = pending.copy()
        block = np.zeros((rows.size, int(cap_all[rows].max())), dtype=complex)
        where_in_block = np.empty(nf, dtype=np.int64)
        where_in_block[rows] = np.arange(rows.size)
        extra = 8
        while pending.size:
            n0 = n0_all[pending]
            cap = cap_all[pending]
            n_eval = int(min(n0.max() + extra, cap.max()))
            n = np.arange(n_eval)
            with np.errstate(all="ignore"):
                c = np.asarray(coef_fn(n, pending), dtype=complex)
            finite = np.isfinite(c)
            first_bad = np.where(finite.all(axis=1), n_eval, np.argmax(~finite, axis=1))
            c = np.where(finite, c, 0.0)
            partial = np.abs(np.cumsum(c, axis=1))
            small = np.abs(c) <= tol * partial
            ok = small[:, :-1] & small[:, 1:]
            ok &= n[None, :-1] >= n0[:, None]
            ok &= n[None, 1:] < first_bad[:, None]
            ok &= n[None, 1:] < cap[:, None]
            found = ok.any(axis=1)
            stop = np.where(found, np.argmax(ok, axis=1) + 2, 0)  # number of terms
            overflowed = ~found & (first_bad < n_eval)
            capped = ~found & ~overflowed & (n_eval >= cap)
            done = found | overflowed | capped
            stop = np.where(overflowed, first_bad, stop)
            stop = np.where(capped, np.minimum(cap, n_eval), stop)
            keep = n[None, :] < stop[:, None]
            block[where_in_block[pending[done]], :n_eval] = np.where(keep, c, 0.0)[done]
            n_terms[pending[done]] = stop[done]
            converged[pending[done]] = found[done]
            if np.any(overflowed | capped):
                bad = pending[overflowed | capped]
                log.warning("modal series not converged to tol=%g for %d frequencies "
                            "(size parameter up to %.4g): stopped at %s terms "
                            "(Bessel overflow or max_terms)", tol, bad.size,
                            float(np.max(np.abs(x_max[bad]))), n_terms[bad].max())
            pending = pending[~done]
            extra *= 2
        blocks.append((rows, block))

    width = int(n_terms.max()) if nf else 0
    coefs = np.zeros((nf, width), dtype=complex)
    for rows, block in blocks:
        w = min(width, block.shape[1])
        coefs[rows, :w] = block[:, :w]
    return ModalSeries(coefficients=coefs, n_terms=n_terms, converged=converged)


def regular_pair(value: np.ndarray, deriv: np.ndarray, x: np.ndarray,
                 n: np.ndarray, nu_offset: float) -> tuple[np.ndarray, np.ndarray]:
    """Homogeneous pair (u, v) ∝ (x f'(x), f(x)) of a regular Bessel function, scaled to
    unit norm so that their ratio (the logarithmic derivative) can be infinite or the
    functions underflow without producing NaN.

    Where both underflow (order ≫ x), the small-argument limit of the logarithmic
    derivative x f'/f = n − x²/(2(n + nu_offset) + 2) is used (``nu_offset`` = 0.5 for
    spherical, 0 for cylindrical functions).
    """
    u = x * deriv
    v = value
    s = np.maximum(np.abs(u), np.abs(v))
    tiny = ~(s > _UNDERFLOW) | ~np.isfinite(s)
    s_safe = np.where(tiny, 1.0, s)
    u = u / s_safe
    v = v / s_safe
    nn = np.broadcast_to(n, u.shape).astype(float)
    xx = np.broadcast_to(x, u.shape)
    u_lim = nn - xx * xx / (2.0 * (nn + nu_offset) + 2.0)
    u = np.where(tiny, u_lim, u)
    v = np.where(tiny, 1.0, v)
    norm = np.maximum(np.abs(u), np.abs(v))
    return u / norm, v / norm


def legendre_table(n_max: int, mu: np.ndarray) -> np.ndarray:
    """Legendre polynomials P_n(mu) for n < n_max, shape (n_max,) + mu.shape (upward
    recurrence, stable for |mu| <= 1)."""
    mu = np.asarray(mu, dtype=float)
    p = np.empty((max(n_max, 1),) + mu.shape)
    p[0] = 1.0
    if n_max > 1:
        p[1] = mu
    for n in range(1, n_max - 1):
        p[n + 1] = ((2 * n + 1) * mu * p[n] - n * p[n - 1]) / (n + 1)
    return p[:n_max]


def complex_matmul(c: np.ndarray, p: np.ndarray) -> np.ndarray:
    """c @ p for complex ``c`` and real ``p`` (two real products: numpy's mixed
    complex-real matmul avoids BLAS and is ~20× slower)."""
    return c.real @ p + 1j * (c.imag @ p)


def as_frequency(freq) -> np.ndarray:
    """Validate a frequency argument (Hz): finite and positive; returns a float array."""
    f = np.asarray(freq, dtype=float)
    if not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise ValueError("frequencies must be finite and positive (Hz)")
    return f


def target_strength(amplitude) -> np.ndarray:
    """Target strength TS = 20 log10 |f| (dB re 1 m²) from a scattering amplitude f (m)."""
    return amplitude_to_db(amplitude)


def modal_amplitudes(f: np.ndarray, a: float, fluid, material, spherical: bool,
                     elastic_ratio: Callable, weight: Callable[[np.ndarray], np.ndarray],
                     tol: float = DEFAULT_TOL, max_terms: int | None = None
                     ) -> tuple[ModalSeries, np.ndarray]:
    """Modal amplitudes weight(n) b_n of a sphere (``spherical``) or an infinite cylinder
    of radius ``a`` (m) at frequencies ``f`` (Hz, 1-D) in ``fluid``: rigid when
    ``material`` is None, else elastic with the shape's ``elastic_ratio(n, x, x1, x2,
    rho_ratio, is_fluid) -> (num, den)``. Returns the series and the wavenumbers (rad/m).
    """
    k = 2.0 * np.pi * f / fluid.sound_speed
    x_all = k * a
    if material is None:
        x_max = x_all

        def coef(n, rows):
            _, jd = bessel_first(int(n[-1]), x_all[rows], spherical)
            _, yd = bessel_second(int(n[-1]), x_all[rows], spherical)
            return weight(n[None, :]) * (-jd / (jd + 1j * yd))
    else:
        omega = 2.0 * np.pi * f
        x1_all = omega * a / material.complex_c_l
        x2_all = (omega * a / material.complex_c_t if not material.is_fluid
                  else np.zeros_like(x1_all))
        x_max = np.maximum(np.maximum(x_all, np.abs(x1_all)), np.abs(x2_all))
        rho_ratio = fluid.density / material.density

        def coef(n, rows):
            nn = n[None, :]
            num, den = elastic_ratio(nn, x_all[rows][:, None], x1_all[rows][:, None],
                                     x2_all[rows][:, None], rho_ratio, material.is_fluid)
            j, jd = bessel_first(int(n[-1]), x_all[rows], spherical)
            y, yd = bessel_second(int(n[-1]), x_all[rows], spherical)
            b = -(den * j + num * jd) / (den * (j + 1j * y) + num * (jd + 1j * yd))
            return weight(nn) * b

    return sum_modal_series(coef, x_max, tol=tol, max_terms=max_terms), k
