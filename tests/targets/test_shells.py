"""Spherical shells (sim_device.targets.shells) against independent limits: the solid
sphere's series (inner radius -> 0), the fluid sphere of the fill (wall -> 0), the rigid
sphere (stiff, dense wall), the Rayleigh limit of an empty shell from Lame's solution,
and energy conservation of the lossless modal amplitudes."""

from __future__ import annotations

import numpy as np
import pytest

from sim_device.targets import (ElasticMaterial, load_materials, sphere_backscatter,
                                sphere_modal_series)
from sim_device.targets.shells import shell_backscatter, shell_modal_series

MAT = load_materials()
WATER = MAT.fluid("water_nominal")
STEEL = MAT.material("steel")
TNT = MAT.fluid("tnt_like")
A = 0.05
FREQ = np.linspace(2e3, 60e3, 60)          # ka = 0.4 ... 12.6


def _rel(s1, s0):
    w = min(s0.coefficients.shape[1], s1.coefficients.shape[1])
    return (np.max(np.abs(s1.coefficients[:, :w] - s0.coefficients[:, :w]))
            / np.max(np.abs(s0.coefficients)))


@pytest.mark.parametrize("fill", ["vacuum", "water", "tnt"])
@pytest.mark.parametrize("lossy", [False, True])
def test_small_cavity_is_the_solid_sphere(fill, lossy):
    """b = a/1000: the cavity changes f by O((b/a)^3); the series agree to 1e-6."""
    m = STEEL if lossy else STEEL.lossless()
    fl = {"vacuum": "vacuum", "water": WATER, "tnt": TNT}[fill]
    s1 = shell_modal_series(FREQ, A, A * (1 - 1e-3), WATER, m, fl)
    assert _rel(s1, sphere_modal_series(FREQ, A, WATER, m)) < 1e-6
    # a wall as thick as the radius is the solid sphere exactly
    np.testing.assert_array_equal(shell_backscatter(FREQ, A, A, WATER, m, fl),
                                  sphere_backscatter(FREQ, A, WATER, m))


def test_vanishing_wall_is_the_fluid_sphere_of_the_fill():
    """Wall h -> 0: the fill alone (a fluid sphere, c_T = 0, of the solid-sphere code).
    The wall's mass loading is ~ omega rho_s h / (rho c), so the error falls like h."""
    fluid_sphere = ElasticMaterial("tnt", TNT.density, TNT.sound_speed, 0.0)
    ref = sphere_modal_series(FREQ, A, WATER, fluid_sphere)
    errs = [_rel(shell_modal_series(FREQ, A, A * h, WATER, STEEL.lossless(), TNT), ref)
            for h in (1e-4, 1e-5, 1e-6)]
    assert errs[-1] < 2e-3
    assert errs[0] / errs[1] > 5 and errs[1] / errs[2] > 5


def test_stiff_dense_wall_is_the_rigid_sphere():
    stiff = ElasticMaterial("stiff", 1e9, 1e8, 5e7)
    np.testing.assert_allclose(shell_backscatter(FREQ, A, 0.005, WATER, stiff, "vacuum"),
                               sphere_backscatter(FREQ, A, WATER), rtol=1e-5)


@pytest.mark.parametrize("fill", ["vacuum", "tnt"])
def test_lossless_shell_conserves_energy(fill):
    """|1 + 2 b_n| = 1 for every order (no absorption), thin and thick walls."""
    for h in (0.002, 0.01, 0.03):
        s = shell_modal_series(FREQ, A, h, WATER, STEEL.lossless(),
                               TNT if fill == "tnt" else "vacuum")
        n = np.arange(s.coefficients.shape[1])
        b = s.coefficients / (2 * n + 1)
        used = n[None, :] < s.n_terms[:, None]
        assert np.all(s.converged)
        assert np.max(np.abs(np.abs(1 + 2 * b[used]) - 1)) < 1e-9
    lossy = shell_modal_series(FREQ, A, 0.01, WATER, STEEL, "vacuum")
    n = np.arange(lossy.coefficients.shape[1])
    b = lossy.coefficients / (2 * n + 1)
    assert np.all(np.abs(1 + 2 * b) <= 1 + 1e-12)


def test_empty_shell_rayleigh_limit_from_lame():
    """ka = 0.01: f = -k^2 a^3 [(1 - kappa_e/kappa)/3 + (rho_e - rho)/(2 rho_e + rho)]
    with the mean density rho_e = rho_1 (1 - b^3/a^3) and the compressibility of a hollow
    sphere under external pressure (Lame: u = C r + D/r^2, sigma_rr(a) = -p,
    sigma_rr(b) = 0):  kappa_e = (a^3/K + 3 b^3/(4 mu)) / (a^3 - b^3)."""
    m = STEEL.lossless()
    h = 0.01
    b = A - h
    mu = m.density * m.c_t ** 2
    bulk = m.density * m.c_l ** 2 - 4 * mu / 3
    kappa_e = (A ** 3 / bulk + 3 * b ** 3 / (4 * mu)) / (A ** 3 - b ** 3)
    rho_e = m.density * (1 - (b / A) ** 3)
    kappa = 1 / (WATER.density * WATER.sound_speed ** 2)
    f = 0.01 * WATER.sound_speed / (2 * np.pi * A)
    k = 2 * np.pi * f / WATER.sound_speed
    ref = -k ** 2 * A ** 3 * ((1 - kappa_e / kappa) / 3
                              + (rho_e - WATER.density) / (2 * rho_e + WATER.density))
    got = shell_backscatter(np.array([f]), A, h, WATER, m, "vacuum")[0]
    assert got.real == pytest.approx(ref, rel=3e-4)          # measured 6e-5


def test_bad_arguments():
    with pytest.raises(ValueError, match="thickness"):
        shell_modal_series(FREQ, A, 0.0, WATER, STEEL)
    with pytest.raises(ValueError, match="thickness"):
        shell_modal_series(FREQ, A, 2 * A, WATER, STEEL)
    with pytest.raises(ValueError, match="shear"):
        shell_modal_series(FREQ, A, 0.01, WATER, ElasticMaterial("f", 1000.0, 1500.0, 0.0))
