"""The micronavigation's numba kernel (svss_proc/micronav/patch_focus.py) against the
numpy reference it replaces in the estimator (horizontal.focus_points and the
"numpy" kernel of displacement_pass): the same focused values to the Taylor series'
truncation, the same pairs, the same estimates."""

from __future__ import annotations


import numpy as np

from svss_proc.micronav.horizontal import focus_points
from svss_proc.micronav.patch_focus import SubAperture, focus, ping_taps
from svss_proc.micronav.phase_centres import near_pairs


def test_focus_equals_the_reference_sum_far_from_the_origin():
    """Random baseband, an array and seabed points about a survey-frame position 12 km
    from the origin: the reference focuses in that frame, the kernel in one centred on
    the array (as the estimator calls it)."""
    rng = np.random.default_rng(7)
    fc, c, dt, t0 = 27500.0, 1500.0, 1.6e-5, 0.5e-3
    bb = (rng.normal(size=(80, 750)) + 1j * rng.normal(size=(80, 750))).astype(np.complex64)
    where = np.array([12034.56, -8765.43, 0.37])
    tx = where + [0.52, -0.11, 0.5]
    chans = rng.choice(80, 44, replace=False)
    rx = where + np.column_stack([rng.uniform(-0.4, 0.4, 44), rng.uniform(-0.3, 0.3, 44),
                                  np.full(44, 0.5)])
    pts = where + np.column_stack([rng.uniform(-0.8, 0.8, 300), rng.uniform(-0.8, 0.8, 300),
                                   np.full(300, 2.5)])
    ref = focus_points(bb[chans], t0, dt, fc, c, tx, rx, pts)
    got = focus(ping_taps(bb, t0, dt, fc), SubAperture(chans, tx - where, rx - where),
                pts - where, c)
    assert np.abs(ref).min() > 0
    np.testing.assert_allclose(got, ref, rtol=0, atol=2e-6 * np.abs(ref).max())
    # points whose delays fall outside the samples count nothing, in both
    far = pts + [0.0, 0.0, 20.0]
    assert np.all(focus_points(bb[chans], t0, dt, fc, c, tx, rx, far) == 0)
    assert np.all(focus(ping_taps(bb, t0, dt, fc), SubAperture(chans, tx - where, rx - where),
                        far - where, c) == 0)


def test_near_pairs_are_the_reference_nonzero():
    rng = np.random.default_rng(2)
    pa, pb = rng.uniform(0, 0.5, (80, 3)), rng.uniform(0, 0.5, (80, 3))
    d = np.hypot(*(pb[None, :, :2] - pa[:, None, :2]).transpose(2, 0, 1))
    ia, ib = np.nonzero(d <= 0.034)
    got = near_pairs(pa, pb, 0.034)
    assert ia.size > 10
    np.testing.assert_array_equal(got[0], ia)
    np.testing.assert_array_equal(got[1], ib)


def test_the_estimates_of_both_kernels_agree_on_simulated_sand():
    """Two consecutive pings of the sand (interface only, as tests/micronav/
    test_live_stage.py synthesises them), placed by the straight track: the numba and
    numpy kernels give the same displacement to 1e-9 m and the same sigma and coherence
    to 1e-6."""
    from sim_device.environment_source import EnvironmentSource
    from sim_device.track import ping_pose

    from .posed_source import interface_sand_scene
    from svss_daq.config import HardwareConfig, config_path, load_with_text
    from svss_daq.frames import body_to_ned
    from svss_daq.waveform import make_waveform
    from svss_proc.conditioning import Conditioner
    from svss_proc.micronav.horizontal import estimate_displacement
    loaded = load_with_text(HardwareConfig, config_path("hardware.toml"))
    hw = loaded.value
    scene = interface_sand_scene()
    src = EnvironmentSource(loaded, scene)
    cond = Conditioner(hw.digitiser, make_waveform(hw.waveform), 2)
    (pa, ca), (pb, cb) = ((p, cond.ping(p)) for p in (src.ping(13), src.ping(14)))
    na, nb = (ping_pose(scene.track, hw, k, src.seed) for k in (13, 14))
    args = (ca.data, cb.data, ca.t0_s, ca.dt_s, src.geometry, pa.projector, pb.projector,
            body_to_ned(na.roll_rad, na.pitch_rad, na.heading_rad), na.ned,
            body_to_ned(nb.roll_rad, nb.pitch_rad, nb.heading_rad), nb.ned,
            na.down_m + na.altitude_m, scene.medium.sound_speed_m_s, hw.waveform.center_hz)
    ref = estimate_displacement(*args, kernel="numpy")
    got = estimate_displacement(*args, kernel="numba")
    assert ref.refused is None and got.refused is None
    np.testing.assert_allclose(got.displacement_m, ref.displacement_m, rtol=0, atol=1e-9)
    np.testing.assert_allclose(got.sigma_m, ref.sigma_m, rtol=1e-6)
    np.testing.assert_allclose(got.coherence, ref.coherence, rtol=0, atol=1e-6)
    assert got.n_pairs == ref.n_pairs
