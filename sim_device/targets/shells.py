"""Spherical elastic shells, empty or filled: the exact modal series.

A shell of outer radius a and inner radius b of an isotropic (optionally lossy) solid in
a host fluid, filled with a fluid (water, an explosive-like fill) or empty (vacuum; an
air fill reflects like vacuum: its impedance is 0.03 % of water's).  Time dependence
exp(-iωt), the conventions of :mod:`.spheres`: f(θ) = (−i/k) Σ (2n+1) b_n P_n(cos θ), and
the coefficients are returned as a :class:`.spheres.SphereSeries` so that everything built
on the solid sphere's series (bistatic sums, echo synthesis) takes a shell unchanged.

Per order n (Goodman & Stern 1962's formulation: boundary conditions at both surfaces)
the unknowns are the scattered amplitude b_n, the solid's compressional potential
A_j j_n(k_L r) + A_y y_n(k_L r), its shear potential B_j j_n(k_T r) + B_y y_n(k_T r)
(u = ∇φ + ∇×∇×(r ψ)) and the fill's pressure E j_n(k_f r).  With x = k_L r, s = k_T r,
m = n(n+1) and F the radial function of each potential, the solid's
    r u_r            = A x F'(x) + B m F(s)
    r² σ_rr / μ      = A [(2m − s²) F(x) − 4x F'(x)] + B 2m [s F'(s) − F(s)]
    r² σ_rθ / μ      = A 2[x F'(x) − F(x)] + B [(2m − 2 − s²) F(s) − 2s F'(s)]
(per P_n and dP_n/dθ), the rows of the solid sphere's determinant (docs/targets.md §3).
The potentials are scaled by ρ₁ω² (pressure units), which turns the six conditions

    r = a:  r u_r = (ρ₁/ρ) ka [j_n' + b_n h_n'](ka),  r²σ_rr/μ = −(k_T a)² [j_n + b_n h_n](ka),
            σ_rθ = 0
    r = b:  r u_r = (ρ₁/ρ_f) k_f b E j_n'(k_f b),     r²σ_rr/μ = −(k_T b)² E j_n(k_f b),
            σ_rθ = 0

into a 6×6 linear system per (frequency, order), solved directly after scaling its rows
and columns (y_n of the inner surface grows like (2n−1)!!/(kb)^{n+1} as b → 0).  Empty
shell: E = 0 and no displacement condition at r = b.  n = 0 has no shear (B = 0).
"""

from __future__ import annotations

import numpy as np

from ._bessel import bessel_first
from ._series import DEFAULT_TOL, as_frequency, sum_modal_series
from .materials import ElasticMaterial, Fluid
from .spheres import SphereSeries

__all__ = ["VACUUM", "shell_modal_series", "shell_backscatter"]

#: fill name of an empty (vacuum- or air-filled) shell
VACUUM = "vacuum"


def spherical_y(nmax: int, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """y_n(z), y_n'(z) for n = 0..nmax and complex z (F,), by upward recurrence
    (stable for y_n); shape (F, nmax + 1)."""
    z = np.asarray(z, dtype=complex)[:, None]
    y = np.empty((z.shape[0], nmax + 2), dtype=complex)
    y[:, :1] = -np.cos(z) / z
    y[:, 1:2] = -np.cos(z) / z**2 - np.sin(z) / z
    for n in range(1, nmax + 1):
        y[:, n + 1:n + 2] = (2 * n + 1) / z * y[:, n:n + 1] - y[:, n - 1:n]
    n = np.arange(nmax + 1)[None, :]
    d = np.empty((z.shape[0], nmax + 1), dtype=complex)
    d[:, :1] = -y[:, 1:2]
    d[:, 1:] = y[:, :nmax] - (n[:, 1:] + 1) / z * y[:, 1:nmax + 1]
    return y[:, :nmax + 1], d


def _radial(nmax: int, z: np.ndarray):
    """(j, j', y, y') of order 0..nmax at complex z (F,)."""
    j, jd = bessel_first(nmax, np.asarray(z, dtype=complex), True)
    y, yd = spherical_y(nmax, z)
    return j, jd, y, yd


def _solid_rows(m, x, fx, fdx, s, gs, gds):
    """The three rows (r u_r, r²σ_rr/μ, r²σ_rθ/μ) for the A and B parts."""
    a1 = x * fdx
    a2 = (2 * m - s * s) * fx - 4 * x * fdx
    a3 = 2 * (x * fdx - fx)
    b1 = m * gs
    b2 = 2 * m * (s * gds - gs)
    b3 = (2 * m - 2 - s * s) * gs - 2 * s * gds
    return (a1, a2, a3), (b1, b2, b3)


def shell_modal_series(freq, radius: float, thickness: float, fluid: Fluid,
                       material: ElasticMaterial, fill: Fluid | str | None = VACUUM,
                       tol: float = DEFAULT_TOL, max_terms: int | None = None
                       ) -> SphereSeries:
    """Modal amplitudes (2n+1) b_n of a spherical shell at frequencies ``freq`` (Hz, 1-D).

    ``radius`` a (m, outer), ``thickness`` a − b (m, 0 < thickness ≤ a; equal to a is
    the solid sphere), ``fluid`` the host, ``material`` the shell's solid (its loss
    included), ``fill`` a :class:`Fluid` or ``"vacuum"``/None (empty)."""
    f = np.atleast_1d(as_frequency(freq)).ravel()
    a = float(radius)
    h = float(thickness)
    if not (np.isfinite(a) and a > 0 and np.isfinite(h) and 0 < h <= a):
        raise ValueError(f"shell needs radius > 0 and 0 < thickness <= radius (m), got "
                         f"radius {radius!r}, thickness {thickness!r}")
    if material is None or material.is_fluid:
        raise ValueError("a shell needs an elastic material with shear (c_t > 0)")
    b = a - h
    empty = fill is None or (isinstance(fill, str) and fill == VACUUM)
    if b <= 0:
        from .spheres import sphere_modal_series
        return sphere_modal_series(f, a, fluid, material, tol=tol, max_terms=max_terms)
    omega = 2 * np.pi * f
    k = omega / fluid.sound_speed
    k_l = omega / material.complex_c_l
    k_t = omega / material.complex_c_t
    k_f = omega / (1.0 if empty else fill.sound_speed)
    rho1 = material.density
    r_out = rho1 / fluid.density
    r_in = 0.0 if empty else rho1 / fill.density
    x_max = np.maximum(np.maximum(k * a, np.abs(k_l * a)), np.abs(k_t * a))

    def coef(n, rows):
        nmax = int(n[-1])
        m = (n * (n + 1.0))[None, :]
        x = (k * a)[rows]
        jw, jwd, yw, ywd = _radial(nmax, x)
        hw, hwd = jw + 1j * yw, jwd + 1j * ywd
        xw = x[:, None]
        mat = np.zeros((rows.size, n.size, 6, 6), dtype=complex)
        rhs = np.zeros((rows.size, n.size, 6), dtype=complex)
        for side, r in enumerate((a, b)):
            xl, xt = (k_l * r)[rows], (k_t * r)[rows]
            jl, jld, yl, yld = _radial(nmax, xl)
            jt, jtd, yt, ytd = _radial(nmax, xt)
            xl_, xt_ = xl[:, None], xt[:, None]
            (aj1, aj2, aj3), (bj1, bj2, bj3) = _solid_rows(m, xl_, jl, jld, xt_, jt, jtd)
            (ay1, ay2, ay3), (by1, by2, by3) = _solid_rows(m, xl_, yl, yld, xt_, yt, ytd)
            o = 3 * side
            for i, (cj, cy, dj, dy) in enumerate(((aj1, ay1, bj1, by1),
                                                  (aj2, ay2, bj2, by2),
                                                  (aj3, ay3, bj3, by3))):
                mat[..., o + i, 1], mat[..., o + i, 2] = cj, cy
                mat[..., o + i, 3], mat[..., o + i, 4] = dj, dy
            if side == 0:
                mat[..., 0, 0] = -r_out * xw * hwd
                rhs[..., 0] = r_out * xw * jwd
                mat[..., 1, 0] = xt_ ** 2 * hw
                rhs[..., 1] = -(xt_ ** 2) * jw
            elif empty:
                mat[..., 3, :] = 0.0
                mat[..., 3, 5] = 1.0                  # E = 0
            else:
                xf = (k_f * b)[rows]
                jf, jfd = bessel_first(nmax, xf.astype(complex), True)
                mat[..., 3, 5] = -r_in * xf[:, None] * jfd
                mat[..., 4, 5] = xt_ ** 2 * jf
        # n = 0: no shear wave; the tangential conditions are void
        for row, col in ((2, 3), (5, 4)):
            mat[:, 0, row, :] = 0.0
            mat[:, 0, row, col] = 1.0
        with np.errstate(all="ignore"):
            cs = np.max(np.abs(mat), axis=-2, keepdims=True)
            cs = np.where((cs > 0) & np.isfinite(cs), cs, 1.0)
            mat = mat / cs
            rs = np.max(np.abs(mat), axis=-1, keepdims=True)
            rs = np.where((rs > 0) & np.isfinite(rs), rs, 1.0)
            mat = mat / rs
            rhs = rhs / rs[..., 0]
            bad = ~np.all(np.isfinite(mat), axis=(-2, -1))
            mat[bad] = np.eye(6)
            sol = np.linalg.solve(mat, rhs[..., None])[..., 0, 0] / cs[..., 0, 0]
        sol[bad] = np.nan
        return (2 * n + 1)[None, :] * sol

    s = sum_modal_series(coef, x_max, tol=tol, max_terms=max_terms)
    return SphereSeries(s.coefficients, s.n_terms, s.converged, k)


def shell_backscatter(freq, radius: float, thickness: float, fluid: Fluid,
                      material: ElasticMaterial, fill: Fluid | str | None = VACUUM,
                      tol: float = DEFAULT_TOL) -> np.ndarray:
    """Monostatic backscatter amplitude f(π) (m, complex) of a shell, shape of ``freq``."""
    s = shell_modal_series(freq, radius, thickness, fluid, material, fill, tol=tol)
    n = np.arange(s.coefficients.shape[1])
    sign = np.where(n % 2 == 0, 1.0, -1.0)
    return ((-1j / s.k) * np.sum(s.coefficients * sign, axis=1)).reshape(np.shape(freq))
