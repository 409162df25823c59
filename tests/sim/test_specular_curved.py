"""Coherent returns of an undulating interface (sim_device.specular_curved): over a
surface of zero amplitude they are the level interface's image-source paths; their sum
over the stationary points agrees with a Kirchhoff surface integral evaluated directly
on a fine grid (written out here); the stationary points and their delays are those a
brute-force search of the path length finds; the simulator's coherent paths use them.

The Kirchhoff integral for a surface of constant reflection coefficient R (physics
convention exp(-i omega t), unit point source exp(i k r) / r):

    p(B) = -(i k / 4 pi) Int R (N . (e_1 + e_2)) exp(i k (r_1 + r_2)) / (r_1 r_2) dx dy,

the high-frequency form of the Helmholtz-Kirchhoff integral with the tangent-plane
boundary values (p = R p_i, dp/dn = -R dp_i/dn) and d/dn exp(i k r)/r ~ i k cos exp(i k r)/r;
N = (u_x, u_y, -1) is the upward normal times the area element dS / (dx dy), e_j the unit
vectors from the surface point to A and B. Over a plane it is R exp(i k L) / L, the image
source (checked below).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.optimize import brentq, root

from sim_device.beams import BeamTable, beam_table
from sim_device.environment import Media
from sim_device.environment_source import EnvironmentSource
from sim_device.multipath import CoherentPath, coherent_paths
from sim_device.scene import UndulationTerm, load_scene
from sim_device.specular import interface_paths, select
from sim_device.specular_curved import curved_interface_paths
from svss_daq.config import config_path

F = 27500.0                      # Hz
C0 = 1500.0                      # m/s
K = 2.0 * math.pi * F / C0       # rad/m
#: the 1-D test surface: 10 cm over a 4 m wavelength along x, trough (deepest) at x = 0
AMP, LAM = 0.10, 4.0
KU = 2.0 * math.pi / LAM
OMNI = BeamTable(np.ones(2), np.zeros(0), -1.0, 2.0, math.pi)
LOSSLESS = Media(c=np.array([C0, 1700.0]), rho=np.array([1000.0, 2000.0]),
                 delta=np.zeros(2), alpha=np.zeros(2), z_top=np.array([-np.inf, 0.0]),
                 rough=np.zeros(2))
#: a density ratio for which the Rayleigh coefficient is 1 to 1e-12 at every angle
RIGID = (1e12, 1.0, 0.0)
DOWN = np.array([0.0, 0.0, 1.0])
#: the scene's two-dimensional surface (config/scenes/seabed_sand_undulating.toml)
SCENE_TERMS = [(0.10, 4.0, 0.0, 20.0), (0.04, 2.5, 90.0, 60.0)]


def rows_of(terms):
    """(amplitude, kx, ky, phase) rows written out from (a, wavelength, direction, phase)."""
    return np.array([(a, 2 * math.pi / lam * math.cos(math.radians(d)),
                      2 * math.pi / lam * math.sin(math.radians(d)), math.radians(p))
                     for a, lam, d, p in terms])


ROWS_1D = np.array([[AMP, KU, 0.0, 0.0]])


# ------------------------------------------------------------------ 1. zero amplitude

def test_zero_amplitude_gives_the_level_image_source_paths():
    """Realistic beams (piston, taper, back lobe), loss, roughness, a tilted array and
    surface multipath: the same PathSet as interface_paths."""
    rng = np.random.default_rng(5)
    tx = np.array([0.3, 0.2, -2.0])
    rx = np.column_stack([rng.uniform(-0.6, 0.6, 80) + 0.1, rng.uniform(-0.5, 0.5, 80),
                          -2.0 + rng.uniform(-0.05, 0.05, 80)])
    t = math.radians(8.0)
    bore = np.array([math.sin(t), 0.0, math.cos(t)])
    media = Media(c=np.array([C0, 1767.0]), rho=np.array([1000.0, 2000.0]),
                  delta=np.array([0.0, 0.015]), alpha=np.array([3e-5, 1.6]),
                  z_top=np.array([-np.inf, 0.0]), rough=np.array([0.0, 0.01]))
    tb = beam_table(math.radians(25), "piston", math.radians(2), -20.0, F, C0)
    rb = beam_table(math.radians(50), "piston", math.radians(2), -20.0, F, C0)
    seqs = [CoherentPath(s) for s in ("B", "BS", "SB", "SBS")]
    args = (tx, rx, bore, media, 2.5, -1.0, seqs, tb, rb, 1.9, 1.18, 0.015)
    ref = interface_paths(*args)
    zero = rows_of(SCENE_TERMS)
    zero[:, 0] = 0.0
    got = curved_interface_paths(*args, zero, F)
    assert got.label == ref.label
    np.testing.assert_array_equal(got.order, ref.order)
    np.testing.assert_allclose(got.tau, ref.tau, rtol=0, atol=1e-12)
    assert np.all(np.abs(ref.amp) > 0)
    np.testing.assert_allclose(got.amp, ref.amp, rtol=1e-9, atol=0)
    np.testing.assert_allclose(got.beta, ref.beta, rtol=1e-9, atol=0)
    np.testing.assert_array_equal(got.gamma, ref.gamma)


def test_two_seabed_bounces_are_refused():
    with pytest.raises(ValueError, match="one seabed bounce"):
        curved_interface_paths(np.array([0, 0, -2.0]), np.array([[0.2, 0, -2.0]]), DOWN,
                               LOSSLESS, 2.5, -1.0, coherent_paths(2, True), OMNI, OMNI,
                               *RIGID, ROWS_1D, F)


# ------------------------------------------------------------------ 2. Kirchhoff

def smoothstep(s):
    """0 -> 0, 1 -> 1, infinitely differentiable (the window's edges)."""
    s = np.clip(s, 0.0, 1.0)
    f0 = np.where(s > 0, np.exp(-1.0 / np.where(s > 0, s, 1.0)), 0.0)
    f1 = np.where(s < 1, np.exp(-1.0 / np.where(s < 1, 1.0 - s, 1.0)), 0.0)
    return f0 / (f0 + f1)


def kirchhoff(a, b, amp, flat, taper, dx=0.01):
    """The Kirchhoff integral (module docstring) for R = 1 over the surface
    z = amp cos(KU x), on a dx grid about the midpoint of A and B: weight 1 within
    ``flat`` (m) of it in x and y, falling smoothly to 0 over ``taper`` (m)."""
    c = 0.5 * (a + b)
    s = np.arange(-flat - taper, flat + taper + dx / 2, dx)
    w = 1.0 - smoothstep((np.abs(s) - flat) / taper)
    x, y = np.meshgrid(c[0] + s, c[1] + s, indexing="ij")
    u = amp * np.cos(KU * x)
    ux = -amp * KU * np.sin(KU * x)
    d1 = (a[0] - x, a[1] - y, a[2] - u)
    d2 = (b[0] - x, b[1] - y, b[2] - u)
    r1 = np.sqrt(d1[0] ** 2 + d1[1] ** 2 + d1[2] ** 2)
    r2 = np.sqrt(d2[0] ** 2 + d2[1] ** 2 + d2[2] ** 2)
    # N . e with N = (ux, 0, -1)
    ndot = (ux * d1[0] - d1[2]) / r1 + (ux * d2[0] - d2[2]) / r2
    total = np.sum(ndot * np.exp(1j * K * (r1 + r2)) / (r1 * r2) * w[:, None] * w[None, :])
    return -1j * K / (4.0 * math.pi) * total * dx * dx


def stationary_phase(a, b, rows):
    """The coherent paths' field at ``F``: sum of amp exp(i omega tau)."""
    p = curved_interface_paths(a, b[None, :], DOWN, LOSSLESS, None, 0.0, [CoherentPath("B")],
                               OMNI, OMNI, *RIGID, rows, F)
    return np.sum(p.amp[0] * np.exp(2j * math.pi * F * p.tau[0])), int(np.sum(p.amp[0] != 0))


def pair(x0, h):
    """Projector and receiver h above the mean plane about x0, 0.3 m apart along x and
    0.1 m across (bistatic)."""
    return np.array([x0 - 0.15, -0.05, -h]), np.array([x0 + 0.15, 0.05, -h])


def test_kirchhoff_integral_over_a_plane_is_the_image_source():
    a, b = pair(0.3, 2.5)
    img = np.array([a[0], a[1], -a[2]])
    length = np.linalg.norm(b - img)
    got = kirchhoff(a, b, 0.0, 1.0, 1.5)
    ref = np.exp(1j * K * length) / length
    assert 20 * math.log10(abs(got / ref)) == pytest.approx(0.0, abs=0.01)
    assert abs(np.angle(got / ref)) < 0.01          # the O(1 / kL) term: 0.0035 rad


#: (x0 (m), height (m), stationary points): above the trough (x = 0), the crest (2 m) and
#: the flank between them 2.5 m up (one point each); 5 and 6 m up above the trough
#: (beyond its centre of curvature, 1 / (a k^2) = 4.05 m up: three points) and beside it
KIRCHHOFF_CASES = [(0.0, 2.5, 1), (2.0, 2.5, 1), (1.0, 2.5, 1), (0.0, 5.0, 3),
                   (0.03, 5.0, 3), (0.02, 6.0, 3), (0.4, 5.0, 1)]
#: stationary phase against the integral away from caustics. Measured: 0.02 dB, 0.02 rad
#: with one point 2.5 m up; 0.5 dB, 0.015 rad (5 m) and 0.85 dB, 0.03 rad (6 m) with
#: three points a fraction of a Fresnel zone apart (leading-order stationary phase)
TOL_DB, TOL_RAD = 1.0, 0.2


@pytest.mark.parametrize("x0, h, n_points", KIRCHHOFF_CASES)
def test_stationary_phase_agrees_with_the_kirchhoff_integral(x0, h, n_points):
    a, b = pair(x0, h)
    ref = kirchhoff(a, b, AMP, 1.0 if h < 3 else 2.0, 1.5 if h < 3 else 2.0)
    got, n = stationary_phase(a, b, ROWS_1D)
    assert n == n_points
    assert 20 * math.log10(abs(got / ref)) == pytest.approx(0.0, abs=TOL_DB)
    assert abs(np.angle(got / ref)) < TOL_RAD


def test_the_curvature_factor_matters_above_a_trough():
    """The level interface's image-source amplitude at the curved surface's specular
    point (no focusing) misses the Kirchhoff integral by more than 3 dB 2.5 m above the
    trough: the agreement above is the curvature factor's."""
    a, b = pair(0.0, 2.5)
    ref = kirchhoff(a, b, AMP, 1.0, 1.5)
    p = curved_interface_paths(a, b[None, :], DOWN, LOSSLESS, None, 0.0,
                               [CoherentPath("B")], OMNI, OMNI, *RIGID, ROWS_1D, F)
    level_amp = 1.0 / (C0 * p.tau[0, 0])            # R / L
    assert 20 * math.log10(abs(ref) / level_amp) > 3.0


# ------------------------------------------------------------------ 3. brute force

def path_length(x, y, a, b, rows):
    u = sum(r[0] * np.cos(r[1] * x + r[2] * y + r[3]) for r in rows)
    return (np.sqrt((x - a[0]) ** 2 + (y - a[1]) ** 2 + (u - a[2]) ** 2)
            + np.sqrt((x - b[0]) ** 2 + (y - b[1]) ** 2 + (u - b[2]) ** 2))


def gradient(xy, a, b, rows):
    """dL/dx, dL/dy, written out."""
    x, y = xy
    u = sum(r[0] * math.cos(r[1] * x + r[2] * y + r[3]) for r in rows)
    ux = sum(-r[0] * r[1] * math.sin(r[1] * x + r[2] * y + r[3]) for r in rows)
    uy = sum(-r[0] * r[2] * math.sin(r[1] * x + r[2] * y + r[3]) for r in rows)
    g = np.zeros(2)
    for q in (a, b):
        d = np.array([x - q[0], y - q[1], u - q[2]])
        r = np.linalg.norm(d)
        g += [(d[0] + d[2] * ux) / r, (d[1] + d[2] * uy) / r]
    return g


def curved_times(a, b, rows):
    p = curved_interface_paths(a, b[None, :], DOWN, LOSSLESS, None, 0.0, [CoherentPath("B")],
                               OMNI, OMNI, *RIGID, rows, F)
    return np.sort(p.tau[0][p.amp[0] != 0])


@pytest.mark.parametrize("x0, h", [(0.0, 2.5), (1.0, 2.5), (0.0, 5.0), (0.05, 5.0),
                                   (-0.04, 6.0)])
def test_stationary_times_against_a_root_search_along_a_line(x0, h):
    """A and B in the plane y = 0 over the 1-D surface: the stationary points lie on
    y = 0; dL/dx written out, bracketed on a 1 mm grid over 6 m and refined (brentq)."""
    a = np.array([x0 - 0.15, 0.0, -h])
    b = np.array([x0 + 0.15, 0.0, -h])
    xs = np.arange(x0 - 3.0, x0 + 3.0, 1e-3)
    g = np.array([gradient((x, 0.0), a, b, ROWS_1D)[0] for x in xs])
    roots = [brentq(lambda x: gradient((x, 0.0), a, b, ROWS_1D)[0], xs[i], xs[i + 1],
                    xtol=1e-14)
             for i in np.flatnonzero(np.sign(g[:-1]) != np.sign(g[1:]))]
    ref = np.sort([path_length(x, 0.0, a, b, ROWS_1D) / C0 for x in roots])
    got = curved_times(a, b, ROWS_1D)
    assert got.size == ref.size
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12)


@pytest.mark.parametrize("seed, h", [(1, 2.0), (2, 2.5), (3, 4.0), (4, 6.0), (5, 7.0)])
def test_stationary_times_against_a_grid_search_over_the_scene_surface(seed, h):
    """The scene's two-term surface, bistatic at random: stationary points from every
    local minimum of |grad L| on a 1 cm grid over 5 m x 5 m, refined by a root search of
    the gradient written out; the same points, to 1e-12 s."""
    rng = np.random.default_rng(seed)
    rows = rows_of(SCENE_TERMS)
    a = np.array([rng.uniform(-2, 2), rng.uniform(-2, 2), -h])
    b = a + [rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6), rng.uniform(-0.2, 0.2)]
    c = 0.5 * (a + b)
    s = np.arange(-2.5, 2.5, 0.01)
    x, y = np.meshgrid(c[0] + s, c[1] + s, indexing="ij")
    length = path_length(x, y, a, b, rows)
    gx, gy = np.gradient(length, 0.01)
    g2 = gx * gx + gy * gy
    inner = g2[1:-1, 1:-1]
    local = np.ones_like(inner, dtype=bool)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            if di or dj:
                local &= inner <= g2[1 + di:g2.shape[0] - 1 + di, 1 + dj:g2.shape[1] - 1 + dj]
    found = []
    for i, j in zip(*np.nonzero(local & (inner < 1e-2))):
        sol = root(gradient, [x[i + 1, j + 1], y[i + 1, j + 1]], args=(a, b, rows),
                   tol=1e-14)
        # judged by the gradient (at 1e-14 the solver may report no further progress)
        if np.max(np.abs(gradient(sol.x, a, b, rows))) < 1e-12:
            if not any(np.hypot(*(sol.x - f)) < 1e-6 for f in found):
                found.append(sol.x)
    ref = np.sort([path_length(p[0], p[1], a, b, rows) / C0 for p in found])
    got = curved_times(a, b, rows)
    assert ref.size >= 1
    assert got.size == ref.size
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12)


# ------------------------------------------------------------------ wiring

def test_the_simulator_uses_the_curved_paths(hardware):
    """The undulating scene's coherent paths are the curved ones; with the amplitude set
    to zero they are the level scene's."""
    sc = load_scene(config_path("scenes/seabed_sand_undulating.toml"))
    src = EnvironmentSource(hardware, sc)
    i = 40
    g = src.frame(i)
    got = src.coherent_paths(i, g)
    rho, nu, d = src.top_sediment.ratios(src.env.water_density, src.env.water_sound_speed)
    args = (g.tx, g.rx, g.bore, src.media, src.water_depth, src.env.surface_reflection,
            src.sequences, src.tx_beam, src.rx_beam, rho, nu, d)
    ref = curved_interface_paths(*args, src.undulation.rows, src.fc)
    keep = np.array([lbl in got.label for lbl in ref.label])
    ref = select(ref, keep)
    assert got.label == ref.label
    np.testing.assert_array_equal(got.tau, ref.tau)
    np.testing.assert_array_equal(got.amp, ref.amp)
    # the undulation moves the specular return by tens of microseconds
    assert np.max(np.abs(got.tau[:, 0] - interface_paths(*args).tau[:, 0])) > 1e-5

    zero = tuple(UndulationTerm(0.0, t.wavelength_m, t.direction_deg, t.phase_deg)
                 for t in sc.seabed.undulation)
    flat = EnvironmentSource(hardware, dataclasses.replace(
        sc, seabed=dataclasses.replace(sc.seabed, undulation=())))
    curved0 = EnvironmentSource(hardware, dataclasses.replace(
        sc, seabed=dataclasses.replace(sc.seabed, undulation=zero)))
    a = flat.coherent_paths(i)
    b = curved0.coherent_paths(i)
    assert a.label == b.label
    np.testing.assert_allclose(b.tau, a.tau, rtol=0, atol=1e-12)
    np.testing.assert_allclose(b.amp, a.amp, rtol=1e-9, atol=0)
