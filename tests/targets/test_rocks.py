"""Kirchhoff flat-disc (flat rock) model."""

import numpy as np
import pytest

from sim_device.targets import (disc_backscatter, disc_scattering_amplitude,
                                disc_target_strength, kirchhoff_disc_directivity,
                                load_materials)

MAT = load_materials()
WATER = MAT.fluid("water_nominal")
GRANITE = MAT.material("granite")


def test_normal_incidence_level():
    a, f = 0.1, 27.5e3
    k = 2 * np.pi * f / 1500.0
    r = (2650 * 4960 - 1.5e6) / (2650 * 4960 + 1.5e6)
    fb = disc_backscatter(f, a, WATER, GRANITE.lossless())
    assert fb == pytest.approx(-1j * r * k * a * a / 2)
    # rigid plate: TS = 20 log10(A/λ), the classic flat-plate value
    assert disc_target_strength(f, a, WATER) == pytest.approx(
        20 * np.log10(np.pi * a * a / (1500.0 / f)))


def test_tilt_pattern_null_edge_on_and_symmetry():
    a, f = 0.1, 30e3
    k = 2 * np.pi * f / 1500.0
    null = np.arcsin(3.831705970 / (2 * k * a))
    tilt = np.array([0.0, null, -null, np.pi / 2, 2.0, -np.pi / 2])
    fb = disc_backscatter(f, a, WATER, GRANITE, tilt=tilt)
    assert np.all(np.isfinite(fb))
    assert abs(fb[1]) < 1e-8 * abs(fb[0]) and abs(fb[2]) < 1e-8 * abs(fb[0])
    assert abs(fb[3]) < 1e-15 and fb[4] == 0 and abs(fb[5]) < 1e-15
    small = disc_backscatter(f, a, WATER, GRANITE, tilt=[0.05, -0.05])
    assert small[0] == pytest.approx(small[1])
    assert kirchhoff_disc_directivity(0.0) == 1.0
    assert kirchhoff_disc_directivity(1e-7) == pytest.approx(1.0)


def test_bistatic_disc_reduces_to_monostatic_and_specular():
    rng = np.random.default_rng(1)
    a, f = 0.08, 25e3
    normal = np.array([0.0, 0.0, -1.0])               # z down: normal points up to the water
    tilts = rng.uniform(0, 1.2, 20)
    az = rng.uniform(0, 2 * np.pi, 20)
    to_sonar = np.stack([np.sin(tilts) * np.cos(az), np.sin(tilts) * np.sin(az),
                         -np.cos(tilts)], axis=-1)
    bi = disc_scattering_amplitude(f, a, WATER, -to_sonar, to_sonar, normal, GRANITE)
    mono = disc_backscatter(f, a, WATER, GRANITE, tilt=tilts)
    np.testing.assert_allclose(bi, mono, rtol=1e-12)
    # specular direction: full aperture, |f| = |R| k a² cos γ / 2
    ki = np.array([np.sin(0.4), 0.0, np.cos(0.4)])
    ks = np.array([np.sin(0.4), 0.0, -np.cos(0.4)])
    spec = disc_scattering_amplitude(f, a, WATER, ki, ks, normal, GRANITE)
    k = 2 * np.pi * f / 1500.0
    r = GRANITE.normal_incidence_reflection(WATER)
    assert abs(spec) == pytest.approx(abs(r) * k * a * a * np.cos(0.4) / 2)
    # receiver behind the disc: not lit
    assert disc_scattering_amplitude(f, a, WATER, ki, -ks, normal, GRANITE) == 0


# ------------------------------------------------------------ elastic plates (slabs)


def _plate_direct(f, d, material, fluid, sin_t):
    """R, T of an elastic plate from the six boundary conditions solved directly
    (2-D P-SV, z down, potentials phi = A1 e^{i alpha z} + A2 e^{i alpha (d - z)},
    psi likewise; u = grad phi + curl(psi y); u_z and sigma_zz = -p continuous,
    sigma_xz = 0 on both faces) -- a first-principles reference for the closed form."""
    w = 2 * np.pi * f
    k = w / fluid.sound_speed
    xi = k * sin_t
    kz = np.sqrt(k * k - xi * xi + 0j)
    kl, kt = w / material.complex_c_l, w / material.complex_c_t
    al, be = np.sqrt(kl * kl - xi * xi + 0j), np.sqrt(kt * kt - xi * xi + 0j)
    al, be = (al if al.imag >= 0 else -al), (be if be.imag >= 0 else -be)
    mu = material.density * material.complex_c_t ** 2
    lam = material.density * material.complex_c_l ** 2 - 2 * mu

    def phi(q):      # (u_z, sigma_zz, sigma_xz) of e^{i(xi x + q z)} in phi
        return 1j * q, -lam * kl * kl - 2 * mu * q * q, -2 * mu * xi * q

    def psi(q):
        return 1j * xi, -2 * mu * xi * q, mu * (q * q - xi * xi)

    m = np.zeros((6, 6), complex)
    rhs = np.zeros(6, complex)
    ea, eb = np.exp(1j * al * d), np.exp(1j * be * d)
    for side in (0, 1):
        top = side == 0
        for col, vals, fac in ((2, phi(al), 1 if top else ea), (3, phi(-al), ea if top else 1),
                               (4, psi(be), 1 if top else eb), (5, psi(-be), eb if top else 1)):
            for i in range(3):
                m[3 * side + i, col] = vals[i] * fac
    g = 1j * kz / (fluid.density * w * w)        # fluid u_z per unit pressure amplitude
    m[0, 0], rhs[0] = g, g                       # u_z: solid = g (1 - R)
    m[1, 0], rhs[1] = 1.0, -1.0                  # sigma_zz = -(1 + R)
    m[3, 1], m[4, 1] = -g, 1.0                   # u_z = g T, sigma_zz = -T
    x = np.linalg.solve(m, rhs)
    return x[0], x[1]


@pytest.mark.parametrize("lossy", [False, True])
def test_plate_closed_form_matches_the_boundary_conditions(lossy):
    from sim_device.targets.rocks import plate_reflection
    g = GRANITE if lossy else GRANITE.lossless()
    for sin_t in (0.0, 0.1, 0.3, 0.5, 0.7, 0.95):
        for f in (5e3, 24.8e3, 31e3, 60e3):
            for d in (0.02, 0.1, 0.4):
                r, t = plate_reflection(f, d, g, WATER, np.sqrt(1 - sin_t ** 2))
                rd, td = _plate_direct(f, d, g, WATER, sin_t)
                assert abs(r - rd) < 1e-9 and abs(t - td) < 1e-9


def test_plate_energy_conservation_and_half_wavelength_zeros():
    """Lossless: |R|^2 + |T|^2 = 1 at every angle.  Normal incidence: the plate is the
    fluid layer of impedance ratio m = rho_1 c_L / (rho c) (no shear is excited),
    R = (m^2 - 1) sin P / ((m^2 + 1) sin P + 2 i m cos P), P = k_L d, zero at the
    half-wavelength resonances d = n lambda_L / 2."""
    from sim_device.targets.rocks import plate_reflection
    g = GRANITE.lossless()
    d = 0.1
    f = np.linspace(1e3, 80e3, 400)[:, None]
    mu = np.cos(np.radians(np.linspace(0, 89, 60)))[None, :]
    r, t = plate_reflection(f, d, g, WATER, mu)
    np.testing.assert_allclose(np.abs(r) ** 2 + np.abs(t) ** 2, 1.0, atol=1e-10)
    m = g.density * g.c_l / (WATER.density * WATER.sound_speed)
    p = 2 * np.pi * f[:, 0] * d / g.c_l
    ref = (m * m - 1) * np.sin(p) / ((m * m + 1) * np.sin(p) + 2j * m * np.cos(p))
    np.testing.assert_allclose(plate_reflection(f[:, 0], d, g, WATER, 1.0)[0], ref,
                               atol=1e-12)
    for n in (1, 2, 3):
        fn = n * g.c_l / (2 * d)                   # 24.8, 49.6, 74.4 kHz
        assert abs(plate_reflection(fn, d, g, WATER, 1.0)[0]) < 1e-10
    # lossy: some energy is absorbed, never created
    rl, tl = plate_reflection(f, d, GRANITE, WATER, mu)
    assert np.all(np.abs(rl) ** 2 + np.abs(tl) ** 2 <= 1 + 1e-12)


def test_thick_lossy_plate_is_the_half_space():
    """d = 200 m of lossy granite: no wave returns from the far face; R is the elastic
    half-space's (Z_L cos^2 2theta_T + Z_T sin^2 2theta_T - Z) / (... + Z) (Brekhovskikh),
    at normal incidence (Z_1 - Z)/(Z_1 + Z)."""
    from sim_device.targets.rocks import plate_reflection
    f = 30e3
    for deg in (0.0, 10.0, 20.0, 40.0, 70.0):
        th = np.radians(deg)
        w = 2 * np.pi * f
        st = np.sin(th) * GRANITE.complex_c_t / WATER.sound_speed
        sl = np.sin(th) * GRANITE.complex_c_l / WATER.sound_speed
        ct, cl = np.sqrt(1 - st * st + 0j), np.sqrt(1 - sl * sl + 0j)
        cl = cl if (w / GRANITE.complex_c_l * cl).imag >= 0 else -cl
        ct = ct if (w / GRANITE.complex_c_t * ct).imag >= 0 else -ct
        z = WATER.density * WATER.sound_speed / np.cos(th)
        zl = GRANITE.density * GRANITE.complex_c_l / cl
        zt = GRANITE.density * GRANITE.complex_c_t / ct
        c2t = 1 - 2 * st * st
        s2t = 2 * st * ct
        ztot = zl * c2t ** 2 + zt * s2t ** 2
        ref = (ztot - z) / (ztot + z)
        r = plate_reflection(f, 200.0, GRANITE, WATER, np.cos(th))[0]
        assert abs(r - ref) < 1e-9
    assert plate_reflection(f, 200.0, GRANITE, WATER, 1.0)[0] == pytest.approx(
        GRANITE.normal_incidence_reflection(WATER), abs=1e-12)


def test_slab_disc_rings_at_its_thickness_resonance_and_tends_to_the_half_space():
    """A 10 cm granite slab: its echo vanishes near c_L/(2d) = 24.8 kHz (the normal-
    incidence zero, widened by the loss); a thick slab gives the half-space disc;
    tilted and bistatic forms agree with the monostatic one."""
    a = 0.15
    f = np.array([20e3, 24.8e3, 30e3])
    slab = np.abs(disc_backscatter(f, a, WATER, GRANITE, thickness=0.1))
    half = np.abs(disc_backscatter(f, a, WATER, GRANITE))
    assert slab[1] < 0.05 * half[1]
    np.testing.assert_allclose(disc_backscatter(f, a, WATER, GRANITE, tilt=0.05,
                                                thickness=200.0),
                               disc_backscatter(f, a, WATER, GRANITE, tilt=0.05,
                                                reflection=GRANITE.normal_incidence_reflection(
                                                    WATER)), rtol=2e-3)
    tilt = np.radians(7.0)
    normal = np.array([np.sin(tilt), 0.0, -np.cos(tilt)])
    ki = np.array([0.0, 0.0, 1.0])
    bi = disc_scattering_amplitude(f, a, WATER, ki, -ki, normal, GRANITE, thickness=0.1)
    np.testing.assert_allclose(bi, disc_backscatter(f, a, WATER, GRANITE, tilt=tilt,
                                                    thickness=0.1), rtol=1e-12)
