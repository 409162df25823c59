"""Conditioning: an echo A s(t - tau) comes out at tau with magnitude A and the
convention's phase exp(-j 2 pi f_c tau), whatever the window start and group delay."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.signal

from svss_daq.ping import SampleAxis
from svss_daq.scaling import counts_per_upa
from svss_daq.waveform import make_waveform
from svss_proc.conditioning import Conditioner


def _upsampled(cond, factor=16):
    """Band-limited (FFT) interpolation of the conditioned output: exact for a signal
    inside the baseband Nyquist band, so the checks below test conditioning alone."""
    n = cond.data.shape[1]
    return SimpleNamespace(data=scipy.signal.resample(cond.data, n * factor, axis=1),
                           t0_s=cond.t0_s, dt_s=cond.dt_s / factor)


def _interp(cond, ch, t):
    u = (t - cond.t0_s) / cond.dt_s
    i = int(np.floor(u))
    w = u - i
    return cond.data[ch, i] * (1 - w) + cond.data[ch, i + 1] * w


@pytest.mark.parametrize("decimation, window_start, group_delay",
                         [(1, 0.0, 0.0), (2, 0.0, 3.04e-4), (4, 1.3e-3, 1e-4)])
def test_echo_delay_amplitude_and_phase(hardware, decimation, window_start, group_delay):
    hw = hardware.value
    dig = dataclasses.replace(hw.digitiser, window_start_s=window_start,
                              group_delay_s=group_delay)
    wf = make_waveform(hw.waveform)
    fs = dig.sample_rate_hz
    t = window_start - group_delay + np.arange(dig.window_samples) / fs
    taus = np.array([2.1e-3, 3.3337e-3, 5.01234e-3, 7.777e-3])
    amps = np.array([1e6, 2.5e6, 4e5, 7e5])        # uPa
    x = np.zeros((taus.size, t.size))
    for i, (tau, a) in enumerate(zip(taus, amps)):
        x[i] = a * wf.real(t - tau) * counts_per_upa(dig)
    cond = Conditioner(dig, wf, decimation)(x, SampleAxis(window_start, 1 / fs, t.size))
    assert cond.data.dtype == np.complex64
    cond = _upsampled(cond)
    for i, (tau, a) in enumerate(zip(taus, amps)):
        y = _interp(cond, i, tau)
        expect = a * np.exp(-2j * np.pi * wf.center_hz * tau)
        assert abs(y - expect) / a < 0.005, (abs(y) / a, np.angle(y / expect))
        # the envelope's main lobe is centred on tau (within a twentieth of an ADC sample)
        tt = tau + np.linspace(-30e-6, 30e-6, 601)
        env2 = np.abs([_interp(cond, i, s) for s in tt]) ** 2
        centroid = (tt * env2).sum() / env2.sum()
        assert abs(centroid - tau) < 0.05 / fs


def test_range_resolution_is_c_over_2b(hardware):
    hw = hardware.value
    wf = make_waveform(hw.waveform)
    dig = hw.digitiser
    fs = dig.sample_rate_hz
    t = -dig.group_delay_s + np.arange(dig.window_samples) / fs
    tau = 4e-3
    x = (wf.real(t - tau) * counts_per_upa(dig))[None]
    cond = Conditioner(dig, wf, 1)(x)
    tt = tau + np.linspace(-60e-6, 60e-6, 2401)
    env = np.abs([_interp(cond, 0, s) for s in tt])
    env /= env.max()
    above = tt[env >= 10 ** (-3 / 20)]
    width = above[-1] - above[0]                    # -3 dB width of the envelope, s
    # a Taylor-tapered LFM's -3 dB width is a little over 1/B (rectangular: 0.886/B)
    assert 0.88 / wf.bandwidth_hz < width < 1.4 / wf.bandwidth_hz
