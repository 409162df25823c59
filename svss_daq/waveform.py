"""The transmit waveform: a tapered linear-FM pulse, evaluated exactly at any time.

The simulator evaluates it at fractional delays and the conditioning samples it as the
matched-filter replica, so both use the same definition. Time t = 0 is the start of
transmission; the pulse occupies 0 <= t <= duration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import WaveformConfig


def taylor_coefficients(nbar: int, sll_db: float) -> np.ndarray:
    """Cosine-series coefficients F_1..F_{nbar-1} of the Taylor window.

    The window is w(x) = 1 + 2 sum_m F_m cos(2 pi m (x - 1/2)) for x in [0, 1], with
    ``nbar`` nearly equal sidelobes at ``sll_db`` dB below the main lobe.
    """
    a = np.arccosh(10.0 ** (abs(sll_db) / 20.0)) / np.pi
    sigma2 = nbar**2 / (a**2 + (nbar - 0.5) ** 2)
    n = np.arange(1, nbar)
    f = np.empty(nbar - 1)
    for i, m in enumerate(n):
        num = np.prod(1.0 - m**2 / (sigma2 * (a**2 + (n - 0.5) ** 2)))
        others = n[n != m]
        den = np.prod(1.0 - m**2 / others**2.0)
        f[i] = (-1.0) ** (m + 1) * num / (2.0 * den)
    return f


@dataclass(frozen=True)
class Waveform:
    """Real transmit pulse s(t) = w(t/T) cos(2 pi (f0 t + (f1 - f0) t^2 / (2T))).

    ``w`` peaks at 1 mid-pulse; frequencies in Hz, times in s.
    """
    f_start_hz: float
    f_stop_hz: float
    duration_s: float
    center_hz: float
    window: str
    taylor: np.ndarray  # Taylor cosine coefficients (empty unless window == "taylor")

    @property
    def bandwidth_hz(self) -> float:
        return abs(self.f_stop_hz - self.f_start_hz)

    def envelope(self, t: np.ndarray) -> np.ndarray:
        """Amplitude taper w(t / T), zero outside the pulse."""
        t = np.asarray(t, dtype=np.float64)
        x = t / self.duration_s
        inside = (x >= 0.0) & (x <= 1.0)
        if self.window == "rect":
            w = np.ones_like(x)
        elif self.window == "hann":
            w = np.sin(np.pi * x) ** 2
        else:
            m = np.arange(1, self.taylor.size + 1)
            w = 1.0 + 2.0 * np.cos(2 * np.pi * np.multiply.outer(x - 0.5, m)) @ self.taylor
            w /= 1.0 + 2.0 * self.taylor.sum()
        return np.where(inside, w, 0.0)

    def phase(self, t: np.ndarray) -> np.ndarray:
        """Instantaneous phase 2 pi (f0 t + k t^2 / 2), rad."""
        t = np.asarray(t, dtype=np.float64)
        k = (self.f_stop_hz - self.f_start_hz) / self.duration_s
        return 2.0 * np.pi * (self.f_start_hz * t + 0.5 * k * t * t)

    def real(self, t: np.ndarray) -> np.ndarray:
        """The transmitted pressure waveform (unit peak envelope) at times t."""
        return self.envelope(t) * np.cos(self.phase(t))

    def analytic(self, t: np.ndarray) -> np.ndarray:
        """Analytic pulse w(t/T) exp(j phase(t)) (valid as the pulse is narrow-band
        relative to its carrier)."""
        return self.envelope(t) * np.exp(1j * self.phase(t))

    def replica(self, sample_rate_hz: float) -> np.ndarray:
        """The real pulse sampled at t = n / fs, n = 0 .. ceil(T fs)."""
        n = int(np.ceil(self.duration_s * sample_rate_hz)) + 1
        return self.real(np.arange(n) / sample_rate_hz)


def make_waveform(cfg: WaveformConfig) -> Waveform:
    """Build the transmit pulse from its configuration."""
    coeffs = (taylor_coefficients(cfg.taylor_nbar, cfg.taylor_sll_db)
              if cfg.window == "taylor" else np.zeros(0))
    return Waveform(cfg.f_start_hz, cfg.f_stop_hz, cfg.duration_s, cfg.center_hz,
                    cfg.window, coeffs)
