"""Elastic targets ringing in the pings (issue 51): no time-aliasing of long ringing into
the receive window, the decay set by the material's loss, buried targets in the
sediment's medium, shells and slabs from a scene file."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sim_device.environment_source import EnvironmentSource
from sim_device.scene import TargetModelConfig, load_scene
from sim_device.specular import SpectralSynthesiser
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


def direct_synthesis(src, i: int, finer: int = 10, form=None) -> np.ndarray:
    """The target's echo on ping i synthesised directly: every path's uncut response
    (a cylinder's with ``form`` for its form table) on an FFT grid ``finer`` times longer
    than the pings' own, with nothing cut."""
    echo, target, g = src.contributions[0], src.targets[0], src.frame(i)
    ch, tau, amp, beta, gamma, k_in, k_out = echo.paths(src, g, target)
    spec = src.spectral
    syn = SpectralSynthesiser(src.pulses.pulse_real, src.pulses.pad, spec.fs, spec.n,
                              spec.t0 + spec.lead / spec.fs,
                              tail_samples=(finer - 1) * spec.n_fft)
    assert syn.n_fft >= finer * spec.n_fft
    bins = syn.band()
    f = syn.f[bins]
    resp = (np.conj(amp)[:, None] * np.conj(target.amplitude(f, k_in, k_out, form=form))
            * np.exp(-beta[:, None] * f * f - gamma[:, None] * f))
    return syn.responses(g.rx.shape[0], ch, tau, resp, bins, src.p0)


def _check_window(src, p, ref, early_max=1e-12):
    """Nothing before the target's front face (wrapped ringing would put it there: at
    most ``early_max`` of the energy), and the window equal to the direct synthesis:
    returns the error (dB re its RMS)."""
    echo = src.contributions[0]
    syn = echo.grids[0][0]
    g = src.frame(0)
    pos = src.targets[0].position
    # earliest possible arrival: the nearest point of the target, both legs, minus
    # the pulse's lead before its nominal time
    r_min = (np.linalg.norm(pos - g.tx) + np.min(np.linalg.norm(g.rx - pos, axis=1))
             - 2 * src.targets[0].extent)
    t = syn.t0 + (syn.lead + np.arange(syn.n)) / syn.fs
    early = t < r_min / C_W - syn.n_pulse / syn.fs
    assert early.sum() > 100
    e_total = float(np.sum(p ** 2))
    assert e_total > 0 and float(np.sum(p[:, early] ** 2)) < early_max * e_total
    err = np.sqrt(np.mean((p - ref) ** 2) / np.mean(ref ** 2))
    return 20 * np.log10(err)


def test_lossless_ringing_cylinder_does_not_wrap_into_the_window(hardware):
    """The lossless 61 cm aluminium cylinder rings for far longer than the FFT period of
    the pings (its n = 2 resonance is ~5 Hz wide: tens of ms).  Its grid stays short
    (each path cut where the window ends, ringing/CylinderRinging); nothing arrives
    before its front face, and the window equals a direct synthesis of the uncut
    responses on a grid 10x longer than the pings'."""
    src0 = EnvironmentSource(hardware, water_scene())
    tgt = _cylinder(src0)
    sc = dataclasses.replace(water_scene(tgt), target_model=_model(loss=False))
    src = EnvironmentSource(hardware, sc)
    p = src.pressure(0)
    echo = src.contributions[0]
    syn, _, _, win, t_ring = echo.grids[0]
    assert win is None and echo.ringing[0] is not None
    assert t_ring == pytest.approx(echo.ring_cap)              # it rings past the cap
    assert syn.n_fft < src.spectral.n_fft + 0.003 * syn.fs     # the grid stays short
    # before the front face: the images of the cut form table's linear interpolation
    # (at s x 0.8 s, folded) leave -116 dB (the uncut table's -85 dB); no longer a hard
    # window per path on the synthesis grid, as before (1e-12), hence 1e-11.
    # The reference's table is cut at 60 ms (projected time; >= 58 ms real on these
    # paths): its 5 Hz step folds what rings past 0.2 s (the table's period, a limit of
    # the step), and its linear interpolation puts images of the uncut ringing at
    # -33 dB after 14 ms: that would wrap on the reference's own 134 ms grid
    ref = direct_synthesis(src, 0, form=src.targets[0]._form.cut(0.06))
    err = _check_window(src, p, ref, early_max=1e-11)
    print(f"cylinder: {err:.1f} dB re the direct synthesis")
    assert err < -60


def test_lossless_filled_shell_rings_past_the_period_without_folding(hardware):
    """A lossless TNT-filled steel shell (a = 5 cm, 1 cm wall) rings ~50 ms (60 dB),
    four times the pings' FFT period, and its echo starts 3-4 ms into the 12 ms window,
    so its ringing crosses the window's end: on the pings' period it would fold back
    into the window, ahead of the echo.  The modal responses are cut on a fine grid and
    each path where the window ends: nothing before the front face, and the window
    equals a direct synthesis of the uncut series on a grid 10x longer (-60 dB)."""
    src0 = EnvironmentSource(hardware, water_scene())
    g = src0.frame(0)
    tgt = target(kind="shell", material="steel", radius=0.05, thickness_m=0.01,
                 fill="tnt_like", along=g.tx[0] + 0.2, cross=g.tx[1], depth=1.2)
    sc = dataclasses.replace(water_scene(tgt), target_model=_model(loss=False))
    src = EnvironmentSource(hardware, sc)
    p = src.pressure(0)
    echo = src.contributions[0]
    syn, _, _, win, t_ring = echo.grids[0]
    ring = echo.ringing[0]
    assert win is None and ring is not None
    assert t_ring > 3 * src.spectral.n_fft / syn.fs                # rings > 3 periods
    assert ring.fold < 1e-8                                        # fine grid long enough
    assert syn.n_fft < src.spectral.n_fft + 0.003 * syn.fs
    ch, tau = echo.paths(src, g, src.targets[0])[:2]
    assert np.all(tau + 0.02 > syn.t0 + (syn.lead + syn.n) / syn.fs)  # rings out of it
    err = _check_window(src, p, direct_synthesis(src, 0))
    print(f"shell: {err:.1f} dB re the direct synthesis")
    assert err < -60


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
