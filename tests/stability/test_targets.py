"""Target form functions over ka = 1e-3 .. 1e3: the rigid sphere against an mpmath
modal sum, every model against its Rayleigh limit (ka << 1) and its geometric limit
(ka >> 1), finite and bounded everywhere in between."""

from __future__ import annotations

import math

import mpmath as mp
import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from sim_device.targets import (
    cylinder_rayleigh_form,
    disc_target_strength,
    elastic_sphere_rayleigh_backscatter,
    finite_cylinder_backscatter,
    infinite_cylinder_form,
    load_materials,
    rigid_sphere_rayleigh_backscatter,
    sphere_backscatter,
    urick_cylinder_broadside_ts,
)

from ._sweep import sweep

MAT = load_materials()
WATER = MAT.fluid("water_nominal")
SOLIDS = [None, MAT.material("aluminium"), MAT.material("tungsten_carbide")]


def freq(ka: float, a: float) -> float:
    return ka * WATER.sound_speed / (2 * math.pi * a)


log_ka = st.floats(-3.0, 3.0)
radii = st.floats(0.005, 1.0)


def rigid_sphere_mp(ka: float, a: float) -> complex:
    """f_bs of the rigid sphere, 30 digits: (-i/k) sum (2n+1)(-1)^n (-j_n'/h_n')."""
    with mp.workdps(30):
        x = mp.mpf(ka)
        k = x / a
        total = mp.mpc(0)
        for n in range(int(ka + 4 * ka ** (1 / 3) + 12)):
            def jd(m):
                return (mp.besselj(m - 0.5, x) - (m + 1) / x * mp.besselj(m + 0.5, x))

            def yd(m):
                return (mp.bessely(m - 0.5, x) - (m + 1) / x * mp.bessely(m + 0.5, x))
            # common factor sqrt(pi/2x) of j_n and y_n cancels in the ratio
            b = -jd(n) / (jd(n) + 1j * yd(n))
            total += (2 * n + 1) * (-1) ** n * b
        return complex(-1j / k * total)


@sweep(12)
@given(st.floats(-3.0, 1.5), radii)
def test_rigid_sphere_equals_mpmath_modal_sum(lk, a):
    ka = 10.0 ** lk
    f = complex(sphere_backscatter(freq(ka, a), a, WATER))
    ref = rigid_sphere_mp(ka, a)
    assert abs(f - ref) <= 1e-8 * abs(ref)


@sweep(30)
@given(log_ka, radii, st.sampled_from(range(len(SOLIDS))))
def test_sphere_finite_bounded_and_at_both_limits(lk, a, which):
    ka = 10.0 ** lk
    mat = SOLIDS[which]
    f = freq(ka, a)
    fb = complex(sphere_backscatter(f, a, WATER, mat))
    assert math.isfinite(fb.real) and math.isfinite(fb.imag)
    # bounded by the geometric a/2 times a resonance allowance (and the Rayleigh k^2 a^3)
    assert abs(fb) <= max(10 * a, 2 * (ka ** 2) * a)
    if ka <= 0.02:                                     # Rayleigh: error O((ka)^2)
        ray = (rigid_sphere_rayleigh_backscatter(f, a, WATER) if mat is None
               else elastic_sphere_rayleigh_backscatter(f, a, WATER, mat))
        assert abs(fb - complex(ray)) <= 10 * ka ** 2 * abs(complex(ray))
    if mat is None and ka >= 100:                      # geometric: |f| -> a/2
        assert abs(abs(fb) / (a / 2) - 1) <= 0.01


@sweep(30)
@given(log_ka, radii, st.sampled_from(range(len(SOLIDS))))
def test_infinite_cylinder_finite_and_at_both_limits(lk, a, which):
    ka = 10.0 ** lk
    mat = SOLIDS[which]
    f = freq(ka, a)
    t = complex(infinite_cylinder_form(f, a, WATER, mat))
    assert math.isfinite(t.real) and math.isfinite(t.imag)
    geometric = math.sqrt(math.pi * ka) / 2           # |T| of the rigid cylinder, ka >> 1
    assert abs(t) <= 10 * max(geometric, 1.0)
    if ka <= 0.02:
        ray = complex(cylinder_rayleigh_form(f, a, WATER, mat))
        assert abs(t - ray) <= 10 * ka ** 2 * max(1.0, abs(math.log(ka))) * abs(ray)
    if mat is None and ka >= 100:
        assert abs(abs(t) / geometric - 1) <= 0.01


@sweep(20)
@given(st.floats(1.0, 3.0), st.floats(0.01, 0.3), st.floats(2.0, 20.0))
def test_finite_cylinder_broadside_tends_to_urick(lk, a, aspect_ratio):
    ka = 10.0 ** lk
    length = a * aspect_ratio
    f = freq(ka, a)
    fb = complex(finite_cylinder_backscatter(f, a, length, WATER))
    ts = 20 * math.log10(abs(fb))
    assert abs(ts - float(urick_cylinder_broadside_ts(f, a, length, WATER.sound_speed))) <= (
        1.0 if ka >= 30 else 3.0)


@sweep(20)
@given(log_ka, radii, st.floats(0.0, math.pi))
def test_finite_cylinder_and_disc_finite_at_every_aspect(lk, a, aspect):
    ka = 10.0 ** lk
    f = freq(ka, a)
    fb = finite_cylinder_backscatter(f, a, 4 * a, WATER, SOLIDS[1], aspect=aspect)
    assert np.all(np.isfinite(fb)) and abs(complex(fb)) <= 10 * max(ka * 4 * a, a)
    ts = float(disc_target_strength(f, a, WATER))
    # a disc at normal incidence: at most its geometric k a^2 / 2 (TS = 20 log)
    assert math.isfinite(ts) and ts <= 20 * math.log10(ka * a / 2) + 0.5
