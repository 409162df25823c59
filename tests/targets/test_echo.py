"""Target echoes in the simulated pings: propagation paths against brute-force Fermat
minimisation and image geometry, arrival times and levels of synthesised echoes against
independent sonar-equation figures, the phase convention, zero cost outside the beams,
and finite results at the extremes."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sim_device.acoustics import load_sediments, reflection_coefficient
from sim_device.environment_source import EnvironmentSource
from sim_device.scene import TargetConfig, load_scene
from sim_device.targets import Fluid, sphere_scattering_amplitude
from sim_device.targets.paths import refracted_legs
from svss_daq.config import ConfigError, config_path
from svss_daq.scaling import counts_per_upa
from svss_daq.waveform import make_waveform
from svss_proc.conditioning import Conditioner
from tests.references import layered_path
from tests.sim.test_specular import gain  # piston beams with the seed scenes' 2 deg taper
from tests.sim.test_specular import peak_time_and_level as peak

C_W = 1500.0
FS = 125e3


def quiet(sc, *, seabed=True):
    """``sc`` with no seabed scattering, no surface, no noise (targets only)."""
    out = dataclasses.replace(sc, surface=None, points=(), noise=dataclasses.replace(
        sc.noise, electronic_rms_counts=0.0, sea_state=None))
    if sc.scattering is not None:
        out = dataclasses.replace(out, scattering=dataclasses.replace(
            sc.scattering, interface=False, volume=False, specular=False))
    if not seabed:
        out = dataclasses.replace(out, seabed=None, scattering=None)
    return out


def target(kind="sphere", material="rigid", along=10.0, cross=0.0, depth=0.5, radius=0.01,
           **kw):
    fields = {f.name: None for f in dataclasses.fields(TargetConfig)}
    fields.update(kind=kind, material=material, along_m=along, cross_m=cross, depth_m=depth,
                  radius_m=radius, **kw)
    return TargetConfig(**fields)


def sand_scene(*targets):
    sc = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
    return dataclasses.replace(quiet(sc), targets=tuple(targets))


def water_scene(*targets):
    sc = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
    return dataclasses.replace(quiet(sc, seabed=False), targets=tuple(targets))


def compressed(hw, p):
    cond = Conditioner(hw.digitiser, make_waveform(hw.waveform), 1)
    return cond(p * counts_per_upa(hw.digitiser))


def pulse_power_spectrum(hw):
    wf = make_waveform(hw.waveform)
    ts = np.arange(0, wf.duration_s, 1 / 4e6)
    spec = np.abs(np.fft.rfft(wf.real(ts), 1 << 16)) ** 2
    f = np.fft.rfftfreq(1 << 16, 1 / 4e6)
    band = (f > 5e3) & (f < 60e3)
    return f[band], spec[band]


# ---------------------------------------------------------------------------- paths


@pytest.mark.parametrize("sediment", ["medium_sand", "very_fine_silt"])
def test_refracted_leg_times_match_brute_force_fermat(hardware, sediment):
    sc = sand_scene()
    sc = dataclasses.replace(sc, seabed=dataclasses.replace(sc.seabed, layers=(
        dataclasses.replace(sc.seabed.layers[0], sediment=sediment),)))
    media = EnvironmentSource(hardware, sc).media
    rng = np.random.default_rng(3)
    elements = np.column_stack([rng.uniform(-3, 3, 12), rng.uniform(-2, 2, 12),
                                rng.uniform(-3, -0.2, 12)])
    tgt = np.array([0.3, -0.2, 0.7])
    legs = refracted_legs(elements, tgt, 1, media, upward=False)
    for e, tau in zip(elements, legs.time):
        ref = layered_path(e, tgt, [media.c[0], media.c[1]], [0.0])
        assert tau == pytest.approx(ref, abs=1e-11)
    # Snell at the target: sin(phi_s) / c_s = sin(phi_w) / c_w
    sin_w = np.hypot(legs.look[:, 0], legs.look[:, 1])
    sin_s = np.hypot(legs.arrive[:, 0], legs.arrive[:, 1])
    np.testing.assert_allclose(sin_s / media.c[1], sin_w / media.c[0], rtol=1e-12)
    # the upward leg takes the same time
    up = refracted_legs(elements, tgt, 1, media, upward=True)
    np.testing.assert_array_equal(up.time, legs.time)


def test_refracted_leg_through_two_layers_matches_brute_force(hardware):
    sc = sand_scene()
    silt = dataclasses.replace(sc.seabed.layers[0], sediment="very_fine_silt",
                               thickness_m=0.4)
    clay = dataclasses.replace(sc.seabed.layers[0], sediment="clay")
    sc = dataclasses.replace(sc, seabed=dataclasses.replace(sc.seabed, layers=(silt, clay)))
    media = EnvironmentSource(hardware, sc).media
    elements = np.array([[0.0, 0.0, -2.0], [1.5, 0.4, -2.1], [-0.7, 2.0, -1.9]])
    tgt = np.array([0.2, 0.1, 0.9])
    legs = refracted_legs(elements, tgt, 2, media, upward=False)
    for e, tau in zip(elements, legs.time):
        ref = layered_path(e, tgt, list(media.c[:3]), [0.0, 0.4])
        assert tau == pytest.approx(ref, abs=1e-11)


# ----------------------------------------------------------------- synthesised echoes


def test_buried_point_like_target_echo_at_fermat_time_and_level(hardware):
    """A small rigid sphere 0.4 m deep in sand under the array: the compressed echo
    peaks at the brute-force Fermat two-way time, with the level of the sonar equation
    written independently: beams, (1 - R^2) at near-normal incidence, the normal-
    incidence spreading of each leg, the sand's attenuation and the sphere's f."""
    hw = hardware.value
    src0 = EnvironmentSource(hardware, sand_scene())
    g = src0.frame(0)
    tx = g.tx
    depth = 0.4
    a = 0.001       # ka < 0.15: the echo's group delay is that of the centre
    sc = sand_scene(target(along=tx[0], cross=tx[1], depth=depth, radius=a))
    src = EnvironmentSource(hardware, sc)
    p = src.pressure(0)
    assert src.last_stats["targets_in_view"] == 1
    y = compressed(hw, p)
    sand = load_sediments()["medium_sand"]
    c1 = sand.sound_speed
    tgt = np.array([tx[0], tx[1], depth])
    f, spec = pulse_power_spectrum(hw)
    p0 = 10 ** (hw.waveform.source_level_db / 20)
    rho, nu, d = sand.ratios(1000.0, C_W)
    r = reflection_coefficient(math.pi / 2, rho, nu, d)
    host = Fluid("sand", sand.density, c1)
    alpha_per_m = sand.attenuation_db_per_m(f) / (20 * math.log10(math.e))    # Np/m
    h_t = -tx[2]
    near = np.argsort(np.hypot(*(g.rx[:, :2] - tx[:2]).T))[:4]
    t1 = layered_path(tx, tgt, [C_W, c1], [0.0])
    for ch in near:
        t2, cross = layered_path(g.rx[ch], tgt, [C_W, c1], [0.0], crossings=True)
        tau = t1 + t2
        t_peak, level = peak(y.data[ch], y.t0_s, y.dt_s, tau, 1e-4)
        assert t_peak == pytest.approx(tau, abs=0.05 / FS), ch
        h_r = -g.rx[ch, 2]
        spread = 1 / ((h_t + depth * c1 / C_W) * (depth + h_r * C_W / c1))
        # scattering angle between the incident (straight down) and scattered directions
        up = cross[-1] - tgt
        theta = math.pi - math.acos(-up[2] / np.linalg.norm(up))
        fs_ = sphere_scattering_amplitude(f, a, host, None, theta)
        h = np.abs(fs_) * np.exp(-2 * alpha_per_m * depth)
        weight = np.sum(spec * h) / np.sum(spec)
        expect = p0 * abs(1 - r * r) * spread * weight * gain(1.0, 25) * gain(
            (g.rx[ch, 2] - tgt[2]) / -np.linalg.norm(g.rx[ch] - tgt), 50)
        assert 20 * np.log10(level / expect) == pytest.approx(0.0, abs=0.3), ch


def test_large_rigid_sphere_echo_leads_the_centre_by_2a_over_c(hardware):
    """Phase convention: a rigid sphere at ka ~ 30 returns its front face, 2a/c before
    the centre's delay, at level a/2 (spherical spreading both ways, in water)."""
    hw = hardware.value
    src0 = EnvironmentSource(hardware, water_scene())
    g = src0.frame(0)
    a = 0.25
    tgt = np.array([g.tx[0] + 0.3, g.tx[1] - 0.2, 1.0])
    src = EnvironmentSource(hardware, water_scene(target(along=tgt[0], cross=tgt[1],
                                                         depth=tgt[2], radius=a)))
    y = compressed(hw, src.pressure(0))
    p0 = 10 ** (hw.waveform.source_level_db / 20)
    for ch in (0, 37, 79):
        r1 = np.linalg.norm(tgt - g.tx)
        r2 = np.linalg.norm(tgt - g.rx[ch])
        centre = (r1 + r2) / C_W
        u1 = (g.tx - tgt) / r1
        u2 = (g.rx[ch] - tgt) / r2
        half_beta = 0.5 * math.acos(u1 @ u2)
        # the specular point, where the sphere's normal bisects the two directions, is
        # 2 a cos(beta/2) shorter than the centre's path
        lead = 2 * a * math.cos(half_beta) / C_W
        t_peak, level = peak(y.data[ch], y.t0_s, y.dt_s, centre - lead, 6e-5)
        assert t_peak == pytest.approx(centre - lead, abs=0.1 / FS), ch
        gains = gain(-u1 @ g.bore, 25) * gain(-u2 @ g.bore, 50)
        expect = p0 * gains * (a / 2) / (r1 * r2)       # far-field geometric optics
        assert 20 * np.log10(level / expect) == pytest.approx(0.0, abs=0.3), ch
        # and nothing comes at the centre's delay plus the lead (wrong sign convention)
        _, late = peak(y.data[ch], y.t0_s, y.dt_s, centre + lead, 1e-5)
        assert late < 0.1 * level


def test_proud_target_direct_and_interface_reflected_paths(hardware):
    """A small rigid sphere 0.3 m above smooth sand: direct-direct and reflected-
    reflected echoes at the image-source delays, with the Rayleigh coefficient of each
    bounce and the sphere's bistatic f; the mixed paths in between."""
    hw = hardware.value
    sc = sand_scene()
    smooth = dataclasses.replace(sc.seabed.layers[0], rms_roughness_m=0.0)
    sc = dataclasses.replace(sc, seabed=dataclasses.replace(sc.seabed, layers=(smooth,)))
    g = EnvironmentSource(hardware, sc).frame(0)
    a, height = 0.002, 0.3
    # horizontally midway between the projector and receiver 40 (same height), where
    # the two mixed paths have equal delays
    mid_xy = 0.5 * (g.tx[:2] + g.rx[40, :2])
    tgt = np.array([mid_xy[0], mid_xy[1], -height])
    src = EnvironmentSource(hardware, dataclasses.replace(sc, targets=(
        target(along=tgt[0], cross=tgt[1], depth=tgt[2], radius=a),)))
    y = compressed(hw, src.pressure(0))
    sand = load_sediments()["medium_sand"]
    rho, nu, d = sand.ratios(1000.0, C_W)
    water = Fluid("water", 1000.0, C_W)
    f, spec = pulse_power_spectrum(hw)
    p0 = 10 ** (hw.waveform.source_level_db / 20)
    mirror = np.array([1.0, 1.0, -1.0])

    def leg(e, reflected):
        """(length, look direction from e, direction of travel at the target, R)"""
        end = tgt * mirror if reflected else tgt
        v = end - e
        n = np.linalg.norm(v)
        arrive = v * mirror / n if reflected else v / n
        r = abs(reflection_coefficient(math.asin(abs(v[2]) / n), rho, nu, d)) if reflected \
            else 1.0
        return n, v / n, arrive, r

    def mixed_spread(ch):
        return abs(leg(g.tx, False)[0] + leg(g.rx[ch], True)[0]
                   - leg(g.tx, True)[0] - leg(g.rx[ch], False)[0]) / C_W

    best = min(range(g.rx.shape[0]), key=mixed_spread)
    checked = 0
    for ch in (3, 40, 77, best):
        levels = {}
        for kind in ("DD", "RR"):
            l1, look1, k_in, r1 = leg(g.tx, kind[0] == "R")
            l2, look2, k_back, r2 = leg(g.rx[ch], kind[1] == "R")
            tau = (l1 + l2) / C_W
            t_peak, level = peak(y.data[ch], y.t0_s, y.dt_s, tau, 3e-5)
            assert t_peak == pytest.approx(tau, abs=0.05 / FS), (ch, kind)
            theta = math.acos(np.clip(k_in @ -k_back, -1, 1))
            h = np.abs(sphere_scattering_amplitude(f, a, water, None, theta))
            expect = (p0 * gain(look1 @ g.bore, 25) * gain(look2 @ g.bore, 50) * r1 * r2
                      / (l1 * l2) * np.sum(spec * h) / np.sum(spec))
            assert 20 * np.log10(level / expect) == pytest.approx(0.0, abs=0.3), (ch, kind)
            levels[kind] = level
        # the mixed paths (direct one way, reflected the other) arrive together in
        # between; their sum, with the sphere's near-forward f, against the compressed
        # level at their mean delay (phases at the centre frequency)
        total = 0j
        taus = []
        for kind in ("DR", "RD"):
            l1, look1, k_in, r1 = leg(g.tx, kind[0] == "R")
            l2, look2, k_back, r2 = leg(g.rx[ch], kind[1] == "R")
            theta = math.acos(np.clip(k_in @ -k_back, -1, 1))
            fw = np.conj(sphere_scattering_amplitude(f, a, water, None, theta))
            taus.append((l1 + l2) / C_W)
            total += (p0 * gain(look1 @ g.bore, 25) * gain(look2 @ g.bore, 50) * r1 * r2
                      / (l1 * l2) * np.sum(spec * fw) / np.sum(spec)
                      * np.exp(-2j * np.pi * 27500.0 * taus[-1]))
        if abs(taus[0] - taus[1]) < 0.1 / FS:
            _, level = peak(y.data[ch], y.t0_s, y.dt_s, np.mean(taus), 3e-5)
            assert 20 * np.log10(level / abs(total)) == pytest.approx(0.0, abs=0.5), ch
            checked += 1
    assert checked >= 1


def test_target_outside_every_beam_costs_nothing(hardware):
    base = sand_scene()
    far = target(along=10.0, cross=30.0, depth=0.5, radius=0.1)
    src = EnvironmentSource(hardware, dataclasses.replace(base, targets=(far,)))
    ref = EnvironmentSource(hardware, base)
    assert ref.contributions == [] and ref.targets == []      # no targets: no model
    for i in (0, 100, 199):
        np.testing.assert_array_equal(src.pressure(i), ref.pressure(i))
        assert src.last_stats["targets_in_view"] == 0
    assert src.targets[0].evaluations == 0                   # form function never called
    # a target behind the receive window is not evaluated either
    deep = target(kind="sphere", material="steel", along=10.0, depth=20.0, radius=0.1)
    src = EnvironmentSource(hardware, dataclasses.replace(base, targets=(deep,)))
    for i in (60, 70):
        assert not np.any(src.pressure(i))
    assert src.targets[0].evaluations == 0


@pytest.fixture(scope="module")
def sand_frame_70(hardware):
    """The quiet sand scene without targets and its ping 70's geometry (the 30 extreme
    geometries below place their target from it)."""
    base = sand_scene()
    return base, EnvironmentSource(hardware, base).frame(70)


@pytest.mark.parametrize("kind,extra", [
    ("sphere", {}),
    ("cylinder", {"length_m": 0.61, "axis_heading_deg": 0.0, "axis_tilt_deg": 0.0}),
    ("cylinder", {"length_m": 0.61, "axis_heading_deg": 90.0, "axis_tilt_deg": 90.0}),
    ("disc", {"axis_heading_deg": 0.0, "axis_tilt_deg": 0.0}),
    ("disc", {"axis_heading_deg": 30.0, "axis_tilt_deg": 89.0}),
])
@pytest.mark.parametrize("depth", [-0.5, -1e-9, 0.0, 1e-9, 0.2, 1.9])
def test_echoes_stay_finite_at_extreme_geometries(hardware, sand_frame_70, kind, extra,
                                                  depth):
    """End-on cylinders, discs on edge, centres just above, on and just below the
    interface, deep burial: finite pressure, and an echo whenever a beam sees it."""
    base, g = sand_frame_70
    material = "aluminium" if kind == "cylinder" else "granite" if kind == "disc" else "steel"
    tg = target(kind=kind, material=material, along=g.tx[0] + 0.4, cross=g.tx[1] + 0.3,
                depth=depth, radius=0.0762, **extra)
    src = EnvironmentSource(hardware, dataclasses.replace(base, targets=(tg,)))
    p = src.pressure(70)
    assert np.all(np.isfinite(p))
    assert src.last_stats["targets_in_view"] == 1
    if not (kind == "disc" and extra["axis_tilt_deg"] > 80):     # a disc on edge: ~0
        assert np.max(np.abs(p)) > 0


def test_huge_sediment_attenuation_silences_a_buried_target(hardware):
    base = sand_scene()
    lossy = dataclasses.replace(base.seabed.layers[0], loss_parameter=1.0)
    sc = dataclasses.replace(base, seabed=dataclasses.replace(base.seabed, layers=(lossy,)))
    g = EnvironmentSource(hardware, sc).frame(0)
    tg = target(kind="sphere", material="steel", along=g.tx[0], cross=g.tx[1], depth=0.5,
                radius=0.1)
    p = EnvironmentSource(hardware, dataclasses.replace(sc, targets=(tg,))).pressure(0)
    clear = EnvironmentSource(hardware, dataclasses.replace(base, targets=(tg,))).pressure(0)
    assert np.all(np.isfinite(p))
    # 2 x 0.5 m at delta = 1: exp(-2 pi delta f / c) per metre is below -300 dB in the
    # band; what is left is the pulse's leakage at the lowest frequencies, which the
    # matched filter rejects
    hw = hardware.value
    level = np.max(np.abs(compressed(hw, p).data))
    assert level < 1e-6 * np.max(np.abs(compressed(hw, clear).data))    # < -120 dB


# ----------------------------------------------------------------------- scene files


def test_sayers_test_field_scene_builds_every_target(hardware):
    sc = load_scene(config_path("scenes/sayers_field.toml"))
    kinds = {t.kind for t in sc.targets}
    assert kinds == {"sphere", "cylinder", "disc"}
    along = sorted(t.along_m for t in sc.targets)
    assert np.allclose(np.diff(along), 2.0)                  # every 2 m along-track
    assert any(t.depth_m < 0 for t in sc.targets)            # proud
    assert max(t.depth_m for t in sc.targets) == pytest.approx(0.2, abs=0.05)
    src = EnvironmentSource(hardware, quiet(sc))
    assert [t.medium for t in src.targets] == [0 if t.depth_m < 0 else 1
                                               for t in sc.targets]
    # the clay under the silt reflects far more strongly than the silt's top
    m = src.media
    z = m.rho * m.c
    assert abs((z[2] - z[1]) / (z[2] + z[1])) > 3 * abs((z[1] - z[0]) / (z[1] + z[0]))


def test_scene_target_errors_name_the_key(hardware, tmp_path):
    text = open(config_path("scenes/seed_cylinder_sand.toml")).read()
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace('material = "aluminium"', 'material = "unobtainium"'))
    with pytest.raises(ValueError, match=r"targets\[0\]\.material.*unobtainium"):
        EnvironmentSource(hardware, load_scene(bad))
    bad.write_text(text.replace('kind = "cylinder"', 'kind = "sphere"'))
    with pytest.raises(ConfigError, match=r"targets\[0\]\.length_m"):
        load_scene(bad)


# ------------------------------------------------------------------ through the imager


def test_buried_target_echoes_image_at_the_target(hardware):
    """End to end: pings of a small buried rigid sphere (targets only, quantised ADC
    codes) imaged by svss_proc with the refraction table peak at the sphere's position
    in the imager's own tile frame (within half a voxel plus the radius)."""
    from svss_daq.config import ProcessingConfig, load
    from svss_proc.imaging.imager import TileImager
    from sim_device.track import truth_line

    sc = sand_scene()
    a, depth = 0.01, 0.3
    along = EnvironmentSource(hardware, sc).frame(30).tx[0]
    truth = np.array([along, 0.05, depth])
    src = EnvironmentSource(hardware, dataclasses.replace(sc, targets=(
        target(along=truth[0], cross=truth[1], depth=truth[2], radius=a),)))
    pings = [src.ping(i) for i in range(14, 47)]
    assert max(np.abs(p.samples).max() for p in pings) > 1000      # well above 1 count
    proc = load(ProcessingConfig, config_path("processing.toml"))
    proc = dataclasses.replace(
        proc, products=None,
        tile=dataclasses.replace(proc.tile, length_m=0.4, width_m=0.3, depth_m=0.3,
                                 top_m=0.15, voxel_m=0.01),
        imaging=dataclasses.replace(proc.imaging, delays="table", interpolation="linear",
                                    water_sound_speed_m_s=C_W,
                                    sediment_sound_speed_m_s=float(src.media.c[1])))
    imager = TileImager(hardware, proc)
    tiles = []
    for p in pings:
        tiles += imager.add(p)
    tiles += imager.finish()
    tile = max(tiles, key=lambda t: np.abs(t.image).max())
    mag = np.abs(tile.image)
    idx = np.unravel_index(mag.argmax(), mag.shape)
    pos = np.array([tile.grid.along[idx[0]], tile.grid.cross[idx[1]], tile.grid.depth[idx[2]]])
    expect = tile.line.ned_to_tile(truth_line(sc.track).tile_to_ned(truth[None, :]))[0]
    assert np.all(np.abs(pos - expect) <= 0.5 * 0.01 + a), (pos, expect)
