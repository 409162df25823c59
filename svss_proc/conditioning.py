"""Signal conditioning: matched filtering, basebanding and decimation in one FFT pass.

Optional band-limited upsampling (zero-padding the kept band) refines the output grid
for interpolation. Input: real ADC codes (channels x samples) on the ping's sample axis
(:attr:`svss_daq.ping.Ping.sample_axis`); sample n holds the acoustic pressure that
arrived one group delay earlier (:func:`svss_daq.assembly.acoustic_axis`). Output: the
complex matched-filter output in uPa (the peak magnitude of an echo A s(t - tau) is A) on
the arrival-time axis t_m = t_first + m * D / (U fs) (D decimation, U upsampling).

The output is kept as the analytic correlation's samples a(t_m), which is what the
imaging kernels sum (:mod:`svss_proc.imaging.kernel_args`);
:attr:`Conditioned.data` gives the complex baseband of :mod:`svss_daq.conventions`. Each
is one multiplication away from the FFT's output: no conversion undoes another.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import scipy.fft as sfft

from svss_daq.assembly import acoustic_axis
from svss_daq.config import Digitiser
from svss_daq.conventions import baseband_carrier, remodulation
from svss_daq.ping import Ping, SampleAxis
from svss_daq.scaling import counts_per_upa
from svss_daq.waveform import Waveform


@dataclass(frozen=True)
class Conditioned:
    """Matched-filter output of one ping: ``analytic`` (channels, n) complex128, uPa, the
    analytic correlation at the arrival times of ``axis`` (s after transmit)."""
    analytic: np.ndarray
    axis: SampleAxis
    center_hz: float

    @classmethod
    def from_baseband(cls, data: np.ndarray, axis: SampleAxis,
                      center_hz: float) -> "Conditioned":
        """From complex baseband samples (the convention of :mod:`svss_daq.conventions`)."""
        analytic = np.asarray(data, dtype=np.complex128) * remodulation(axis.times(), center_hz)
        return cls(analytic, axis, center_hz)

    @functools.cached_property
    def data(self) -> np.ndarray:
        """Complex baseband (:mod:`svss_daq.conventions`), complex64, uPa."""
        return (self.analytic * baseband_carrier(self.axis.times(), self.center_hz)
                ).astype(np.complex64)

    @property
    def t0_s(self) -> float:
        return self.axis.start_s

    @property
    def dt_s(self) -> float:
        return self.axis.step_s


class Conditioner:
    """Matched filter + baseband + decimation for one hardware configuration."""

    def __init__(self, dig: Digitiser, waveform: Waveform, decimation: int, upsample: int = 1):
        self.digitiser = dig
        self.fs = dig.sample_rate_hz
        self.n_in = dig.window_samples
        #: the configured sample axis (window start, sample rate, window length)
        self.sample_axis = SampleAxis(dig.window_start_s, 1.0 / dig.sample_rate_hz,
                                      dig.window_samples)
        self.decimation = d = int(decimation)
        self.upsample = up = int(upsample)
        self.fc = waveform.center_hz
        replica = waveform.replica(self.fs)
        n = sfft.next_fast_len(self.n_in + replica.size)
        n = d * sfft.next_fast_len(-(-n // d))          # a multiple of the decimation
        self.n_fft = n
        m = n // d                                      # band kept around the carrier
        self.m_out = m * up                               # inverse FFT length
        self.n_out = -(-self.n_in // d) * up
        energy = float(replica @ replica)
        # matched filter, analytic (x2 on positive frequencies), scaled to uPa
        spec = np.conj(sfft.rfft(replica, n)) * (2.0 / energy / counts_per_upa(dig))
        k0 = int(round(self.fc * n / self.fs))
        self.f_shift = k0 * self.fs / n
        k = k0 + np.arange(-(m // 2), m - m // 2)
        keep = (k > 0) & (k < n // 2 + 1)
        self.bins = k[keep]                               # rfft bins kept
        self.slots = np.mod(k[keep] - k0, self.m_out)     # their place in the short ifft
        self.filter = (spec[self.bins] * (self.m_out / n)).astype(np.complex128)

    def output_axis(self, axis: SampleAxis | None = None) -> SampleAxis:
        """The conditioned samples' axis (arrival times at the array) for samples taken
        on ``axis`` (default: the configured window): from the header alone, what
        :meth:`__call__` gives with the samples."""
        axis = self.sample_axis if axis is None else axis
        arrival = acoustic_axis(axis, self.digitiser)
        return SampleAxis(arrival.start_s, self.decimation / (self.fs * self.upsample),
                          self.n_out)

    def checked_axis(self, axis: SampleAxis | None) -> SampleAxis:
        """``axis`` (None: the configured window), refused unless its samples are at the
        configured rate."""
        axis = self.sample_axis if axis is None else axis
        if abs(axis.step_s * self.fs - 1.0) > 1e-9:
            raise ValueError(f"conditioning: samples at {1 / axis.step_s:g} Hz, the "
                             f"digitiser is configured for {self.fs:g} Hz")
        return axis

    def operator(self) -> np.ndarray:
        """The conditioning as one matrix (``n_in`` x ``n_out``, complex128): the analytic
        samples of codes x of the configured length are ``x @ operator()`` (what
        :meth:`__call__` computes with FFTs, linear in the codes; the GPU conditions
        so, :mod:`svss_proc.imaging.gpu_conditioning`)."""
        return self(np.eye(self.n_in)).analytic

    def ping(self, ping: Ping) -> Conditioned:
        """Condition a ping on its own sample axis."""
        return self(ping.samples, ping.sample_axis)

    def __call__(self, codes: np.ndarray, axis: SampleAxis | None = None) -> Conditioned:
        """Condition ADC codes taken on ``axis`` (default: the configured window)."""
        axis = self.checked_axis(axis)
        x = sfft.rfft(np.asarray(codes, dtype=np.float64), self.n_fft, axis=-1)
        z = np.zeros((x.shape[0], self.m_out), dtype=np.complex128)
        z[:, self.slots] = x[:, self.bins] * self.filter
        y = sfft.ifft(z, axis=-1)[:, : self.n_out]
        out = self.output_axis(axis)
        # y holds a(t) exp(-j 2 pi f_shift (t - t_first)): bring back the analytic samples
        shift = np.exp(2j * np.pi * self.f_shift * (out.times() - out.start_s))
        return Conditioned(y * shift, out, self.fc)
