"""The transmit pulse and the baseband convention."""

from __future__ import annotations

import numpy as np
import scipy.signal

from svss_daq.conventions import baseband_carrier, echo_phase, remodulation
from svss_daq.waveform import Waveform, make_waveform, taylor_coefficients


def test_taylor_window_matches_scipy():
    for nbar, sll in [(5, 40.0), (4, 30.0), (8, 60.0)]:
        n = 257
        wf = Waveform(35e3, 20e3, 1.0, 27.5e3, "taylor", taylor_coefficients(nbar, sll))
        x = (np.arange(n) + 0.5) / n
        ref = scipy.signal.windows.taylor(n, nbar=nbar, sll=sll, norm=True)
        np.testing.assert_allclose(wf.envelope(x), ref, atol=2e-3)


def test_chirp_sweeps_35_to_20_khz(hardware):
    wf = make_waveform(hardware.value.waveform)
    t = np.linspace(1e-6, wf.duration_s - 1e-6, 200)
    h = 1e-9
    f_inst = (wf.phase(t + h) - wf.phase(t - h)) / (2 * h) / (2 * np.pi)
    np.testing.assert_allclose(f_inst, 35e3 + (20e3 - 35e3) * t / wf.duration_s, rtol=1e-6)
    assert wf.real(-1e-9) == 0 and wf.real(wf.duration_s + 1e-9) == 0
    env = wf.envelope(np.linspace(0, wf.duration_s, 1001))
    assert abs(env.max() - 1.0) < 1e-3 and abs(env[500] - 1.0) < 1e-12


def test_pulse_spectrum_within_band(hardware):
    wf = make_waveform(hardware.value.waveform)
    fs = 1e6
    s = wf.replica(fs)
    spec = np.abs(np.fft.rfft(s, 1 << 16)) ** 2
    f = np.fft.rfftfreq(1 << 16, 1 / fs)
    in_band = spec[(f > 18e3) & (f < 37e3)].sum()
    assert in_band / spec.sum() > 0.98


def test_baseband_convention_echo_phase():
    fc, tau = 27.5e3, 2.3456e-3
    t = np.linspace(0, 5e-3, 11)
    # a CW echo cos(2 pi fc (t - tau)) has analytic exp(j 2 pi fc (t - tau)); at baseband
    # it is exp(-j 2 pi fc tau), and the imager's remodulation makes it real and positive
    bb = np.exp(2j * np.pi * fc * (t - tau)) * baseband_carrier(t, fc)
    np.testing.assert_allclose(bb, echo_phase(tau, fc) * np.ones_like(t), atol=1e-9)
    np.testing.assert_allclose(bb * remodulation(tau, fc), 1.0, atol=1e-9)
