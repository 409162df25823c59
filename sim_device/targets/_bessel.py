"""Tables of Bessel functions of orders 0..N for vectors of arguments.

Private module.  Evaluating ``scipy.special`` functions for every (order, argument) pair
costs O(N) per element for the spherical functions and microseconds per element for
the cylindrical ones; the modal series need all orders 0..N at once, so they are
generated here by recurrence, vectorised over the arguments:

* second kind (Y_n, y_n): upward recurrence from the two lowest orders (stable: they are
  the dominant solution); overflow gives ±inf, which the series treats as its end;
* first kind (J_n, j_n): downward recurrence (Miller's algorithm) from an order M well
  above both N and |x|, rescaled against overflow and normalised by least squares on
  the two lowest orders computed by scipy;
* derivatives from f_n' = f_{n−1} − (n/x) f_n (cylindrical) or f_{n−1} − ((n+1)/x) f_n
  (spherical), with f_{−1} = −f_1 (cylindrical) — no cancellation for n ≫ x.

Arguments may be complex (lossy solids, |Im x| ≲ a few).
"""

from __future__ import annotations

import numpy as np
from scipy.special import j0, j1, jv, spherical_jn, spherical_yn, y0, y1, yv

_RESCALE = 1e250


def _start_order(nmax: int, x: np.ndarray) -> int:
    """Starting order of the downward recurrence: accurate to ~1e-16 at order nmax."""
    big = max(float(nmax), float(np.max(np.abs(x), initial=0.0)))
    return int(np.ceil(big + 12.0 * max(1.0, big) ** (1.0 / 3.0) + 20.0))


def _miller(nmax: int, x: np.ndarray, spherical: bool) -> np.ndarray:
    """Unnormalised minimal solution of the (spherical) Bessel recurrence, orders
    0..nmax+1, shape (F, nmax+2)."""
    m = max(_start_order(nmax + 1, x), nmax + 2)
    f_len = x.shape[0]
    out = np.zeros((f_len, nmax + 2), dtype=x.dtype)
    hi = np.zeros(f_len, dtype=x.dtype)          # order n+1
    cur = np.full(f_len, 1e-300, dtype=x.dtype)  # order n (= m at the start)
    for n in range(m, 0, -1):
        c = (2 * n + 1) if spherical else (2 * n)
        lo = c / x * cur - hi                    # order n−1
        hi, cur = cur, lo
        if n - 1 <= nmax + 1:
            out[:, n - 1] = cur
        scale = np.abs(cur) > _RESCALE
        if np.any(scale):
            s = np.where(scale, 1.0 / _RESCALE, 1.0)
            cur = cur * s
            hi = hi * s
            out *= s[:, None]
    return out


def _normalise(raw: np.ndarray, f0: np.ndarray, f1: np.ndarray) -> np.ndarray:
    """Scale each row so orders 0 and 1 match f0, f1 in the least-squares sense."""
    big = np.maximum(np.abs(raw[:, 0]), np.abs(raw[:, 1]))
    raw = raw / big[:, None]
    r0, r1 = raw[:, 0], raw[:, 1]
    den = np.abs(r0) ** 2 + np.abs(r1) ** 2
    scale = (np.conj(r0) * f0 + np.conj(r1) * f1) / den
    return raw * scale[:, None]


def _upward(nmax: int, x: np.ndarray, f0: np.ndarray, f1: np.ndarray,
            spherical: bool) -> np.ndarray:
    out = np.empty((x.shape[0], nmax + 2), dtype=np.result_type(x, f0))
    out[:, 0] = f0
    out[:, 1] = f1
    with np.errstate(over="ignore", invalid="ignore"):
        for n in range(1, nmax + 1):
            c = (2 * n + 1) if spherical else (2 * n)
            out[:, n + 1] = c / x * out[:, n] - out[:, n - 1]
    return out


def _derivative(table: np.ndarray, x: np.ndarray, spherical: bool) -> np.ndarray:
    """Derivatives of orders 0..N from a table of orders 0..N+1."""
    nmax = table.shape[1] - 2
    n = np.arange(nmax + 1)
    prev = np.empty_like(table[:, : nmax + 1])
    prev[:, 0] = -table[:, 1]                    # f_{-1} = −f_1 (cyl); j_0' = −j_1 (sph)
    prev[:, 1:] = table[:, :nmax]
    with np.errstate(over="ignore", invalid="ignore"):
        if spherical:
            d = prev - ((n + 1) / x[:, None]) * table[:, : nmax + 1]
            d[:, 0] = -table[:, 1]
        else:
            d = prev - (n / x[:, None]) * table[:, : nmax + 1]
    return d


def _first_two(x: np.ndarray, spherical: bool, kind: str):
    if spherical:
        f = spherical_jn if kind == "j" else spherical_yn
        return f(0, x), f(1, x)
    if np.iscomplexobj(x):
        f = jv if kind == "j" else yv
        return f(0, x), f(1, x)
    return (j0(x), j1(x)) if kind == "j" else (y0(x), y1(x))


def bessel_first(nmax: int, x, spherical: bool) -> tuple[np.ndarray, np.ndarray]:
    """J_n(x) (or j_n) and derivatives for n = 0..nmax; arrays (F, nmax+1)."""
    x = np.atleast_1d(np.asarray(x))
    x = x.astype(complex if np.iscomplexobj(x) else float)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore", under="ignore"):
        raw = _miller(nmax, x, spherical)
        f0, f1 = _first_two(x, spherical, "j")
        tab = _normalise(raw, f0, f1)
    return tab[:, : nmax + 1], _derivative(tab, x, spherical)


def bessel_second(nmax: int, x, spherical: bool) -> tuple[np.ndarray, np.ndarray]:
    """Y_n(x) (or y_n) and derivatives for n = 0..nmax (real x); arrays (F, nmax+1);
    overflow gives ±inf."""
    x = np.atleast_1d(np.asarray(x, dtype=float))
    f0, f1 = _first_two(x, spherical, "y")
    tab = _upward(nmax, x, f0, f1, spherical)
    return tab[:, : nmax + 1], _derivative(tab, x, spherical)
