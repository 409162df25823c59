"""Linear Kalman filters (two states, and n) with a Rauch-Tung-Striebel smoother, for the
navigation's fusion (``docs/navigation.md``, "Fusion").

Each axis of the navigation is one such filter on the grid of DVL sample times: the
state is (position of the DVL head, a companion) where the companion is the DVL's
velocity bias on a horizontal axis and the bottom's depth on the vertical one. From grid
point k to k + 1 the model is

    x[k+1] = F[k] x[k] + (u[k], 0),   F[k] = [[1, f01[k]], [0, f11[k]]],
    Q[k] = diag(qp[k], qc[k])

(u: the displacement the DVL's velocities integrate to; f01 = dt couples a velocity bias,
0 for the bottom depth; f11 = exp(-dt / T) for a Gauss-Markov bias, 1 for a random walk).
Scalar measurements z = h0 x0 + h1 x1 + noise (variance r) are applied at their grid
point, in the given order (Joseph form: the covariance stays symmetric and positive).

:func:`filter_smooth_n` is the same for n states with a full transition matrix per step
(the down axis: head depth, the bed's depth and its gradient north and east, the
gradient entering the bed's depth through the head's horizontal displacement).

The filter is causal; the smoother uses the whole record. Both are pure functions of
their arrays, compiled with numba (on-disk cache): a minute of a 5 Hz DVL is 300 steps,
a few microseconds.
"""

from __future__ import annotations

import numba as nb
import numpy as np

__all__ = ["filter_smooth", "filter_smooth_n", "warm_up"]


@nb.njit(cache=True)
def _run(x0, p0, u, f01, f11, qp, qc, m_step, m_h0, m_h1, m_z, m_r, smooth):
    """Forward filter (and, with ``smooth``, the RTS pass); returns the states (K, 2)
    and covariances (K, 2, 2) at the grid points, filtered or smoothed, and the
    predicted ones (before each point's measurements; the first is the prior)."""
    k_n = u.shape[0] + 1
    xf = np.empty((k_n, 2))
    pf = np.empty((k_n, 2, 2))
    xp = np.empty((k_n, 2))
    pp = np.empty((k_n, 2, 2))
    x = x0.copy()
    p = p0.copy()
    xp[0] = x
    pp[0] = p
    j = 0
    n_m = m_step.shape[0]
    for k in range(k_n):
        # measurements at grid point k (sequential scalar updates, Joseph form)
        while j < n_m and m_step[j] == k:
            h0, h1 = m_h0[j], m_h1[j]
            ph0 = p[0, 0] * h0 + p[0, 1] * h1
            ph1 = p[1, 0] * h0 + p[1, 1] * h1
            s = h0 * ph0 + h1 * ph1 + m_r[j]
            if s > 0.0:
                g0, g1 = ph0 / s, ph1 / s
                innov = m_z[j] - (h0 * x[0] + h1 * x[1])
                x[0] += g0 * innov
                x[1] += g1 * innov
                # P = (I - g h) P (I - g h)^T + g r g^T
                a00, a01 = 1.0 - g0 * h0, -g0 * h1
                a10, a11 = -g1 * h0, 1.0 - g1 * h1
                b00 = a00 * p[0, 0] + a01 * p[1, 0]
                b01 = a00 * p[0, 1] + a01 * p[1, 1]
                b10 = a10 * p[0, 0] + a11 * p[1, 0]
                b11 = a10 * p[0, 1] + a11 * p[1, 1]
                r = m_r[j]
                n00 = b00 * a00 + b01 * a01 + g0 * r * g0
                n01 = b00 * a10 + b01 * a11 + g0 * r * g1
                n11 = b10 * a10 + b11 * a11 + g1 * r * g1
                p[0, 0], p[0, 1], p[1, 0], p[1, 1] = n00, n01, n01, n11
            j += 1
        xf[k] = x
        pf[k] = p
        if k == k_n - 1:
            break
        # predict to k + 1
        a, c = f01[k], f11[k]
        x = np.array([x[0] + a * x[1] + u[k], c * x[1]])
        m00 = p[0, 0] + 2.0 * a * p[0, 1] + a * a * p[1, 1] + qp[k]
        m01 = c * (p[0, 1] + a * p[1, 1])
        m11 = c * c * p[1, 1] + qc[k]
        p = np.empty((2, 2))
        p[0, 0], p[0, 1], p[1, 0], p[1, 1] = m00, m01, m01, m11
        xp[k + 1] = x
        pp[k + 1] = p
    if not smooth:
        return xf, pf, xp, pp
    xs = xf.copy()
    ps = pf.copy()
    for k in range(k_n - 2, -1, -1):
        a, c = f01[k], f11[k]
        # C = Pf[k] F^T Pp[k+1]^-1
        q00 = pf[k, 0, 0] + a * pf[k, 0, 1]
        q01 = c * pf[k, 0, 1]
        q10 = pf[k, 1, 0] + a * pf[k, 1, 1]
        q11 = c * pf[k, 1, 1]
        a00, a01, a11 = pp[k + 1, 0, 0], pp[k + 1, 0, 1], pp[k + 1, 1, 1]
        d = a00 * a11 - a01 * a01
        if d > 1e-12 * a00 * a11:
            i00, i01, i10, i11 = a11 / d, -a01 / d, -a01 / d, a00 / d
        elif a00 > 0.0:   # a companion without uncertainty (e.g. no bias): invert the rest
            i00, i01, i10, i11 = 1.0 / a00, 0.0, 0.0, 0.0
        else:
            continue
        c00 = q00 * i00 + q01 * i10
        c01 = q00 * i01 + q01 * i11
        c10 = q10 * i00 + q11 * i10
        c11 = q10 * i01 + q11 * i11
        e0 = xs[k + 1, 0] - xp[k + 1, 0]
        e1 = xs[k + 1, 1] - xp[k + 1, 1]
        xs[k, 0] = xf[k, 0] + c00 * e0 + c01 * e1
        xs[k, 1] = xf[k, 1] + c10 * e0 + c11 * e1
        # Ps = Pf + C (Ps[k+1] - Pp[k+1]) C^T
        d00 = ps[k + 1, 0, 0] - pp[k + 1, 0, 0]
        d01 = ps[k + 1, 0, 1] - pp[k + 1, 0, 1]
        d11 = ps[k + 1, 1, 1] - pp[k + 1, 1, 1]
        t00 = c00 * d00 + c01 * d01
        t01 = c00 * d01 + c01 * d11
        t10 = c10 * d00 + c11 * d01
        t11 = c10 * d01 + c11 * d11
        ps[k, 0, 0] = pf[k, 0, 0] + t00 * c00 + t01 * c01
        ps[k, 0, 1] = pf[k, 0, 1] + t00 * c10 + t01 * c11
        ps[k, 1, 0] = ps[k, 0, 1]
        ps[k, 1, 1] = pf[k, 1, 1] + t10 * c10 + t11 * c11
    return xs, ps, xp, pp


def filter_smooth(x0, p0, u, f01, f11, qp, qc, measurements, smooth: bool = True,
                  predicted: bool = False):
    """States (K, 2) and covariances (K, 2, 2) of one axis at its K grid points (and,
    with ``predicted``, the filter's before each point's measurements, everything
    earlier taken in: ``(xs, ps, xp, pp)``).

    ``x0`` (2,), ``p0`` (2, 2): the prior at grid point 0; ``u``, ``f01``, ``f11``,
    ``qp``, ``qc``: (K - 1,) arrays of the model from each point to the next (module
    docstring); ``measurements``: (step, h0, h1, z, r) arrays, ``step`` the grid point
    each applies to (non-decreasing). ``smooth``: RTS smoothed, else filtered (causal)."""
    m_step, m_h0, m_h1, m_z, m_r = (np.asarray(a) for a in measurements)
    order = np.argsort(m_step, kind="stable")
    f = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    out = _run(f(x0), f(p0), f(u), f(f01), f(f11), f(qp), f(qc),
               np.ascontiguousarray(m_step[order], dtype=np.int64), f(m_h0[order]),
               f(m_h1[order]), f(m_z[order]), f(m_r[order]), bool(smooth))
    return out if predicted else out[:2]


@nb.njit(cache=True)
def _mm(a, b):
    """a @ b for small matrices (loops: no BLAS to compile)."""
    n, m, k = a.shape[0], b.shape[1], a.shape[1]
    out = np.zeros((n, m))
    for i in range(n):
        for j in range(m):
            acc = 0.0
            for q in range(k):
                acc += a[i, q] * b[q, j]
            out[i, j] = acc
    return out


@nb.njit(cache=True)
def _mv(a, x):
    """a @ x."""
    out = np.zeros(a.shape[0])
    for i in range(a.shape[0]):
        for q in range(a.shape[1]):
            out[i] += a[i, q] * x[q]
    return out


@nb.njit(cache=True)
def _inv_psd(a):
    """The inverse of a small symmetric positive semi-definite matrix by Gauss-Jordan
    elimination with pivoting on the diagonal; a direction without variance (a pivot
    below 1e-12 of the largest diagonal) gets zero rows and columns, as a pseudo-inverse
    gives a state that cannot move."""
    n = a.shape[0]
    m = a.copy()
    inv = np.eye(n)
    used = np.zeros(n, dtype=np.bool_)
    scale = 0.0
    for i in range(n):
        scale = max(scale, abs(a[i, i]))
    dead = np.zeros(n, dtype=np.bool_)
    for _ in range(n):
        piv, best = -1, 0.0
        for i in range(n):
            if not used[i] and abs(m[i, i]) > best:
                piv, best = i, abs(m[i, i])
        if piv < 0 or best <= 1e-12 * scale:
            for i in range(n):
                if not used[i]:
                    dead[i] = True
            break
        used[piv] = True
        d = m[piv, piv]
        for j in range(n):
            m[piv, j] /= d
            inv[piv, j] /= d
        for i in range(n):
            if i != piv and m[i, piv] != 0.0:
                f = m[i, piv]
                for j in range(n):
                    m[i, j] -= f * m[piv, j]
                    inv[i, j] -= f * inv[piv, j]
    for i in range(n):
        if dead[i]:
            for j in range(n):
                inv[i, j] = 0.0
                inv[j, i] = 0.0
    return inv


@nb.njit(cache=True)
def _run_n(x0, p0, u, f, q, m_step, m_h, m_z, m_r, smooth):
    """:func:`_run` for n states with a full transition ``f`` (K-1, n, n), input ``u``
    (K-1, n), process noise ``q`` (K-1, n, n) and measurement rows ``m_h`` (M, n)."""
    k_n = u.shape[0] + 1
    n = x0.shape[0]
    xf = np.empty((k_n, n))
    pf = np.empty((k_n, n, n))
    xp = np.empty((k_n, n))
    pp = np.empty((k_n, n, n))
    x = x0.copy()
    p = p0.copy()
    xp[0] = x
    pp[0] = p
    j = 0
    n_m = m_step.shape[0]
    for k in range(k_n):
        while j < n_m and m_step[j] == k:
            h = m_h[j]
            ph = _mv(p, h)
            s = m_r[j]
            for i in range(n):
                s += h[i] * ph[i]
            if s > 0.0:
                g = ph / s
                innov = m_z[j]
                for i in range(n):
                    innov -= h[i] * x[i]
                x = x + g * innov
                # Joseph form: (I - g h) P (I - g h)^T + g r g^T
                a = np.eye(n)
                for r_ in range(n):
                    for c_ in range(n):
                        a[r_, c_] -= g[r_] * h[c_]
                p = _mm(_mm(a, p), a.T)
                for r_ in range(n):
                    for c_ in range(n):
                        p[r_, c_] += g[r_] * g[c_] * m_r[j]
                p = 0.5 * (p + p.T)
            j += 1
        xf[k] = x
        pf[k] = p
        if k == k_n - 1:
            break
        x = _mv(f[k], x) + u[k]
        p = _mm(_mm(f[k], p), f[k].T) + q[k]
        xp[k + 1] = x
        pp[k + 1] = p
    if not smooth:
        return xf, pf, xp, pp
    xs = xf.copy()
    ps = pf.copy()
    for k in range(k_n - 2, -1, -1):
        # C = Pf[k] F^T Pp[k+1]^-1 (a state without variance cannot move)
        c = _mm(_mm(pf[k], f[k].T), _inv_psd(pp[k + 1]))
        xs[k] = xf[k] + _mv(c, xs[k + 1] - xp[k + 1])
        ps[k] = pf[k] + _mm(_mm(c, ps[k + 1] - pp[k + 1]), c.T)
        ps[k] = 0.5 * (ps[k] + ps[k].T)
    return xs, ps, xp, pp


def filter_smooth_n(x0, p0, u, f, q, measurements, smooth: bool = True,
                    predicted: bool = False):
    """:func:`filter_smooth` for n states: the model from each grid point to the next is
    x[k+1] = f[k] x[k] + u[k] with noise q[k] (``f``, ``q``: (K-1, n, n); ``u``:
    (K-1, n)); ``measurements``: (step, h, z, r) with ``h`` (M, n) the rows, z = h x +
    noise of variance r."""
    m_step, m_h, m_z, m_r = (np.asarray(a) for a in measurements)
    order = np.argsort(m_step, kind="stable")
    g = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    n = np.asarray(x0).size
    out = _run_n(g(x0), g(p0), g(u).reshape(-1, n), g(f).reshape(-1, n, n),
                 g(q).reshape(-1, n, n),
                 np.ascontiguousarray(m_step[order], dtype=np.int64),
                 g(m_h).reshape(-1, n)[order], g(m_z[order]), g(m_r[order]), bool(smooth))
    return out if predicted else out[:2]


def warm_up() -> None:
    """Compile (or load from numba's cache) the filter before it is needed: the daemon
    calls this before it starts the sonar, so that a first run's compile (seconds) never
    stalls the posing of the first pings (a cold cache once held navigation records
    back 12 s, and the first 50 pings of the demo were posed on held navigation)."""
    z = np.zeros(1)
    filter_smooth(np.zeros(2), np.eye(2), z, z, np.ones(1), z, z,
                  (np.array([1]), np.ones(1), z, z, np.ones(1)), smooth=True)
    filter_smooth_n(np.zeros(4), np.eye(4), np.zeros((1, 4)), np.eye(4)[None],
                    np.eye(4)[None], (np.array([1]), np.ones((1, 4)), z, np.ones(1)))
