"""Elastic targets ringing in the pings (issue 51): no time-aliasing of long ringing into
the receive window, the decay set by the material's loss, buried targets in the
sediment's medium, shells and slabs from a scene file."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sim_device.environment_source import EnvironmentSource
from sim_device.scene import TargetModelConfig, load_scene
from sim_device.targets import Fluid, sphere_scattering_amplitude
from sim_device.targets.echo import ring_time
from svss_daq.config import ConfigError, config_path
from tests.targets.test_echo import quiet, sand_scene, target, water_scene

C_W = 1500.0


def _model(loss=True, ring=None, step=5.0):
    return TargetModelConfig(truncation_tol=1e-8, freq_step_hz=step, bistatic="kell",
                             material_loss=loss, ring_max_s=ring)


def _cylinder(src0, depth=1.2):
    g = src0.frame(0)
    return target(kind="cylinder", material="aluminium", along=g.tx[0] + 0.2,
                  cross=g.tx[1], depth=depth, radius=0.076, length_m=0.61,
                  axis_heading_deg=90.0, axis_tilt_deg=0.0)


def test_lossless_ringing_cylinder_does_not_wrap_into_the_window(hardware):
    """The lossless 61 cm aluminium cylinder rings for far longer than the FFT period of
    the pings (its n = 2 resonance is ~5 Hz wide: tens of ms).  Nothing may arrive
    before its front face (causality: wrapped ringing would), and the window must not
    depend on how long a ringing the synthesis keeps beyond it (default cap = window +
    pulse, against a 0.2 s cap, a grid 15x finer)."""
    src0 = EnvironmentSource(hardware, water_scene())
    tgt = _cylinder(src0)
    sc = dataclasses.replace(water_scene(tgt), target_model=_model(loss=False))
    src = EnvironmentSource(hardware, sc)
    p = src.pressure(0)
    echo = src.contributions[0]
    syn, _, _, win, t_ring = echo.grids[0]
    assert win is not None and t_ring == pytest.approx(echo.ring_cap)   # it was cut
    g = src.frame(0)
    pos = src.targets[0].position
    # earliest possible arrival: the nearest point of the cylinder, both legs, minus
    # the pulse's lead before its nominal time
    r_min = (np.linalg.norm(pos - g.tx) + np.min(np.linalg.norm(g.rx - pos, axis=1))
             - 2 * src.targets[0].extent)
    t = syn.t0 + (syn.lead + np.arange(syn.n)) / syn.fs
    early = t < r_min / C_W - syn.n_pulse / syn.fs
    assert early.sum() > 100
    e_early = float(np.sum(p[:, early] ** 2))
    e_total = float(np.sum(p ** 2))
    assert e_total > 0 and e_early < 1e-12 * e_total
    long = EnvironmentSource(hardware, dataclasses.replace(
        sc, target_model=_model(loss=False, ring=0.2)))
    q = long.pressure(0)
    assert long.contributions[0].grids[0][0].n_fft > 15 * syn.n_fft // 2
    err = np.sqrt(np.mean((p - q) ** 2) / np.mean(q ** 2))
    assert 20 * np.log10(err) < -60


def test_material_loss_shortens_the_ringing(hardware):
    """Loss (aluminium eta = 1e-4, the cast-iron 4e-4) shortens the ringing; with loss
    the ringing of the shot put ends (60 dB) well inside the window; a lossy, stiffer
    granite sphere rings less than the lossless one; the decay is in the synthesis:
    the late part of the lossy cylinder's echo is weaker than the lossless one's."""
    src0 = EnvironmentSource(hardware, water_scene())
    spec = src0.spectral
    from sim_device.targets.echo import build_targets
    sc = water_scene(target(kind="sphere", material="cast_iron", radius=0.051),
                     target(kind="sphere", material="granite", radius=0.051))
    lossy = build_targets(sc, src0.media)
    lossless = build_targets(dataclasses.replace(sc, target_model=_model(loss=False)),
                             src0.media)
    pulse = src0.pulses.pulse_real
    t_iron, _ = ring_time(lossy[0], spec, 0.05, pulse)
    t_iron0, _ = ring_time(lossless[0], spec, 0.05, pulse)
    assert t_iron <= t_iron0
    t_gr, cut = ring_time(lossy[1], spec, 0.05, pulse)
    t_gr0, _ = ring_time(lossless[1], spec, 0.05, pulse)
    assert not cut and t_gr <= t_gr0
    tgt = _cylinder(src0)
    late = []
    for loss in (False, True):
        s = EnvironmentSource(hardware, dataclasses.replace(water_scene(tgt),
                                                            target_model=_model(loss=loss)))
        p = s.pressure(0)
        peak = np.argmax(np.max(np.abs(p), axis=0))
        late.append(float(np.sum(p[:, peak + 250:] ** 2)))     # 2 ms after the peak on
    assert late[1] < late[0]


def test_buried_target_scatters_in_the_sediment(hardware):
    """A buried target's host medium is the sediment holding its centre (density and
    sound speed), as TIER: its form function is the sphere's in that fluid."""
    sc = sand_scene(target(kind="sphere", material="steel", radius=0.05, depth=0.3))
    src = EnvironmentSource(hardware, sc)
    t = src.targets[0]
    assert t.medium == 1
    assert t.host.density == pytest.approx(src.media.rho[1])
    assert t.host.sound_speed == pytest.approx(src.media.c[1])
    assert t.host.sound_speed != pytest.approx(src.media.c[0])
    f = np.linspace(20e3, 35e3, 16)
    k_in = np.array([[0.0, 0.0, 1.0]])
    got = t.amplitude(f, k_in, -k_in)[0]
    ref = sphere_scattering_amplitude(f, 0.05, Fluid("s", src.media.rho[1], src.media.c[1]),
                                      t.material, theta=np.pi)
    np.testing.assert_allclose(got, ref, rtol=1e-9)


def test_ordnance_field_scene_builds_shells_and_slabs(hardware):
    sc = load_scene(config_path("scenes/ordnance_field.toml"))
    src = EnvironmentSource(hardware, quiet(sc))
    kinds = [t.kind for t in src.targets]
    assert kinds.count("shell") == 3 and kinds.count("disc") == 3
    assert src.targets[0].fill.name == "tnt_like" and src.targets[1].fill == "vacuum"
    assert src.targets[2].thickness == pytest.approx(0.08)
    # every target echoes, finitely, on a ping that sees it
    for t in src.targets:
        i = int(np.argmin([abs(src.frame(j).tx[0] - t.position[0] + 0.3)
                           for j in range(0, sc.track.n_pings, 5)])) * 5
        p = src.contributions[0](src, i, src.frame(i))
        assert np.all(np.isfinite(p)) and np.any(p != 0), t.cfg.description


@pytest.mark.parametrize("change, key", [
    (dict(kind="shell", material="steel", radius=0.05), "thickness_m"),
    (dict(kind="shell", material="steel", radius=0.05, thickness_m=0.1), "thickness_m"),
    (dict(kind="sphere", material="steel", radius=0.05, thickness_m=0.01), "thickness_m"),
    (dict(kind="disc", material="granite", radius=0.1, fill="tnt_like"), "fill"),
])
def test_shell_and_slab_keys_are_checked(change, key):
    from sim_device.scene import check_scene
    sc = water_scene(target(**change))
    with pytest.raises(ConfigError, match=key):
        check_scene(sc)


def test_unknown_fill_and_fluid_shell_name_the_key(hardware):
    for change, key in ((dict(fill="mud"), "fill"), (dict(material="rigid"), "material")):
        args = dict(kind="shell", material="steel", radius=0.05, thickness_m=0.01)
        args.update(change)
        with pytest.raises(ValueError, match=key):
            EnvironmentSource(hardware, water_scene(target(**args)))
