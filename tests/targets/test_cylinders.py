"""Cylinder form functions: Urick limit, seed Table 2, limits, aspect stability."""

import numpy as np
import pytest
from scipy.special import jv, jvp, yv, yvp

from sim_device.targets import (ElasticMaterial, cylinder_modal_series,
                                cylinder_rayleigh_form, disc_backscatter,
                                finite_cylinder_backscatter,
                                finite_cylinder_target_strength, infinite_cylinder_form,
                                infinite_cylinder_form_function, load_materials,
                                urick_cylinder_broadside_ts)

MAT = load_materials()
WATER = MAT.fluid("water_nominal")
AL = MAT.material("aluminium")
A = 0.152 / 2
BAND = np.linspace(20e3, 35e3, 301)


def _freq(ka, a=A):
    return np.asarray(ka) * WATER.sound_speed / (2 * np.pi * a)


@pytest.mark.parametrize("length, seed_ts", [(0.305, -11.9), (0.610, -5.9)])
def test_broadside_rigid_matches_urick_and_seed(length, seed_ts):
    """Band power average over 20–35 kHz of σ/σ_Urick (removes Urick's ∝ f trend)."""
    fb = finite_cylinder_backscatter(BAND, A, length, WATER)
    urick = 10 ** (urick_cylinder_broadside_ts(BAND, A, length, 1500.0) / 10)
    ratio_db = 10 * np.log10(np.mean(np.abs(fb) ** 2 / urick))
    assert abs(ratio_db) < 0.1                                   # measured −0.04 dB
    band_ts = 10 * np.log10(np.mean(np.abs(fb) ** 2))
    assert band_ts == pytest.approx(seed_ts, abs=1.0)            # measured −11.93/−5.91
    assert urick_cylinder_broadside_ts(27.5e3, A, length, 1500.0) == pytest.approx(
        seed_ts, abs=0.05)


@pytest.mark.parametrize("length, seed_ts", [(0.305, -11.9), (0.610, -5.9)])
def test_broadside_elastic_aluminium(length, seed_ts):
    """Solid aluminium: the single value at 27.5 kHz is within 1 dB of the seed's
    Urick value (measured −0.61 and −0.59 dB).  The band average sits 1.15 dB below Urick because
    aluminium reflects |R|² = −1.51 dB of a rigid body's specular echo; against
    Urick·|R|² the band average is within 0.5 dB (measured +0.37 dB)."""
    ts = finite_cylinder_target_strength(27.5e3, A, length, WATER, AL)
    assert ts == pytest.approx(seed_ts, abs=1.0)
    fb = finite_cylinder_backscatter(BAND, A, length, WATER, AL)
    urick = 10 ** (urick_cylinder_broadside_ts(BAND, A, length, 1500.0) / 10)
    r2 = abs(AL.normal_incidence_reflection(WATER)) ** 2
    assert abs(10 * np.log10(np.mean(np.abs(fb) ** 2 / (urick * r2)))) < 0.5


def test_infinite_rigid_form_function_high_ka():
    ka = np.linspace(200, 300, 101)
    ff = infinite_cylinder_form_function(_freq(ka), A, WATER)
    assert np.mean(ff) == pytest.approx(1.0, abs=0.01)
    assert np.all(np.isfinite(ff))


@pytest.mark.parametrize("name", [None, "aluminium", "tungsten_carbide", "granite"])
def test_rayleigh_limit(name):
    m = None if name is None else MAT.material(name)
    f = _freq(0.005)
    got = infinite_cylinder_form(f, A, WATER, m)
    ref = cylinder_rayleigh_form(f, A, WATER, m)
    assert abs(got - ref) / abs(ref) < 1e-3


def _fluid_cylinder_T(ka, x1, rho_ratio, nmax=40):
    total = 0j
    for n in range(nmax):
        h, hd = jv(n, ka) + 1j * yv(n, ka), jvp(n, ka) + 1j * yvp(n, ka)
        a_mat = np.array([[-h, jv(n, x1)], [-hd, rho_ratio * (x1 / ka) * jvp(n, x1)]])
        b = np.linalg.solve(a_mat, np.array([jv(n, ka), jvp(n, ka)]))[0]
        total += (1 if n == 0 else 2) * (-1) ** n * b
    return total


def test_fluid_target_and_rigid_limits():
    ka = np.array([0.6, 2.9, 8.8])
    oil = ElasticMaterial("oil", 900.0, 1300.0, 0.0)
    got = infinite_cylinder_form(_freq(ka), A, WATER, oil)
    ref = [_fluid_cylinder_T(k, k * 1500.0 / 1300.0, 1000.0 / 900.0) for k in ka]
    np.testing.assert_allclose(got, ref, rtol=1e-9)
    stiff = ElasticMaterial("stiff", 1e9, 1e8, 5e7)
    np.testing.assert_allclose(infinite_cylinder_form(_freq(ka), A, WATER, stiff),
                               infinite_cylinder_form(_freq(ka), A, WATER), rtol=1e-5)


@pytest.mark.parametrize("name", [None, "aluminium", "steel"])
def test_unitarity(name):
    m = None if name is None else MAT.material(name).lossless()
    s = cylinder_modal_series(np.linspace(2e3, 200e3, 30), A, WATER, m)
    n = np.arange(s.coefficients.shape[1])
    b = s.coefficients / np.where(n == 0, 1.0, 2.0)
    used = n[None, :] < s.n_terms[:, None]
    assert np.max(np.abs(np.abs(1 + 2 * b[used]) - 1)) < 1e-10


@pytest.mark.parametrize("name", [None, "aluminium"])
@pytest.mark.parametrize("end_caps", [True, False])
def test_all_aspects_finite_and_symmetric(name, end_caps):
    m = None if name is None else MAT.material(name)
    aspects = np.concatenate([np.linspace(0, np.pi, 91), [np.pi / 2, 0.0, np.pi]])
    f = np.array([20e3, 35e3])
    fb = finite_cylinder_backscatter(f, A, 0.61, WATER, m, aspect=aspects, end_caps=end_caps)
    assert fb.shape == (2, aspects.size)
    assert np.all(np.isfinite(fb))
    np.testing.assert_allclose(np.abs(fb[:, :91]), np.abs(fb[:, :91][:, ::-1]),
                               rtol=1e-9, atol=1e-14)
    # Broadside is the maximum over aspect at these ka, L/a.
    assert np.argmax(np.abs(fb[:, :91]), axis=1).tolist() == [45, 45]


def test_end_on_is_the_end_cap_disc():
    m = AL
    f = BAND[::50]
    end_on = finite_cylinder_backscatter(f, A, 0.61, WATER, m, aspect=0.0)
    disc = disc_backscatter(f, A, WATER, m, tilt=0.0)
    # the side term vanishes as (Ka)² → 0 at exactly end-on
    np.testing.assert_allclose(np.abs(end_on), np.abs(disc), rtol=1e-9)
    no_caps = finite_cylinder_backscatter(f, A, 0.61, WATER, m, aspect=0.0, end_caps=False)
    assert np.all(np.abs(no_caps) < 1e-9)
    # caps add nothing at broadside
    np.testing.assert_allclose(
        finite_cylinder_backscatter(f, A, 0.61, WATER, m, end_caps=True),
        finite_cylinder_backscatter(f, A, 0.61, WATER, m, end_caps=False), rtol=1e-12)


def test_first_sinc_null():
    """Side term: zero where Δ = kL cos ψ = π (first null of the length directivity)."""
    f, length = 27.5e3, 0.61
    k = 2 * np.pi * f / WATER.sound_speed
    psi = np.arccos(np.pi / (k * length))
    fb = finite_cylinder_backscatter(f, A, length, WATER, aspect=[np.pi / 2, psi],
                                     end_caps=False)
    assert abs(fb[1]) < 1e-12 * abs(fb[0])


def test_stability_ka_001_to_500():
    ka = np.logspace(-2, np.log10(500), 50)
    for m in (None, AL):
        s = cylinder_modal_series(_freq(ka), A, WATER, m)
        t = infinite_cylinder_form(_freq(ka), A, WATER, m)
        assert np.all(np.isfinite(t)) and np.all(s.converged)
        ray = cylinder_rayleigh_form(_freq(ka[0]), A, WATER, m)
        assert abs(t[0] - ray) / abs(ray) < 1e-3
    top = ka[-8:]
    f_inf = 2 * np.abs(infinite_cylinder_form(_freq(top), A, WATER)) / np.sqrt(np.pi * top)
    assert np.all(np.abs(f_inf - 1) < 0.05)
    with pytest.raises(ValueError):
        finite_cylinder_backscatter(30e3, A, -1.0, WATER)
    with pytest.raises(ValueError):
        finite_cylinder_backscatter(30e3, A, 1.0, WATER, aspect=np.nan)
