"""Ringing targets on a short synthesis grid (issue 51; docs/targets_elastic.md §4).

An echo is synthesised on an FFT grid of period P; whatever a path's response still
rings after the window could wrap round into it.  Rather than lengthening P to hold a
target's whole ringing, each path's response is cut where it can no longer be seen: an
echo with delay tau reaches no sample of the window with its response after

    l_vis = t_end - tau,     t_end = t_first + (n + pad) / fs

(n window samples from t_first; the pulse starts pad samples before its nominal time),
so cutting it there (raised-cosine taper of RING_TAPER_S after the cut) changes nothing
in the window.  The response's front is kept from -pre (the front-face advance, with a
margin) and tapered over RING_TAPER_S before that (:func:`cut_window`).  The cut
response of every path then ends before t_first + P when

    P >= n + n_pulse + pre + 2 taper + delta (+ 2 b for a cylinder)     (samples)

which the target's grid holds (:func:`tail_samples`): nothing wraps, by construction.
The cut is quantised upwards in steps of CUT_STEP_S (delta) so that paths share tables:

* sphere or shell (:class:`ModalRinging`): the modal responses
  d_n(t) = IFT[conj((-i/k)(2n+1) b_n)] are computed once on a fine grid whose period is
  doubled until the energy (echo of the transmit pulse) in its last quarter is FOLD_DB
  below the total, so what folds from beyond that period is below that; a table of the
  modal responses cut at q delta, transformed on the target's own grid, serves every path
  with cut index q (its f(theta) = sum_n D_n(f) P_n(cos theta), as the series);
* cylinder with a form table (:class:`CylinderRinging`): T over projected frequency
  f s (s = sin psi, times cos(beta/2) with Kell's rule) maps projected time t_p to real
  time s t_p; the sinc of the length spreads it by b = L |cos psi| cos(beta/2) / c either
  side.  A path keeping l real seconds with s >= S_KEEP takes the table cut at
  c = (l + b)/s (projected, quantised upwards by delta; at most C_LIM of the table's
  period 1/step, less its front and tapers); a path with s < S_KEEP (psi more than 26 deg from
  broadside, where the sinc of the length is below 1/(kL |cos psi|): -30 dB for the
  61 cm cylinder at 30 kHz) takes c = l + b, so that the paths share a few tables: its
  ringing ends at s (l + b) in real time, before the window's end (dropped, never
  wrapped).
"""

from __future__ import annotations

import logging
import math
from collections import OrderedDict

import numpy as np
import scipy.fft as sfft

from ._series import complex_matmul, legendre_table

log = logging.getLogger(__name__)

#: step (s) by which a path's cut is quantised upwards (paths share its tables)
CUT_STEP_S = 2.5e-4
#: taper (s) of a cut
RING_TAPER_S = 5e-4
#: the fine grid is lengthened until the energy of its last quarter is this far below
#: the total (dB): a bound on what folds into the kept response from beyond its period
FOLD_DB = 80.0
#: longest fine period (s)
MAX_FINE_S = 1.7
#: a cylinder table's cut at most this fraction of the table's period (1/step)
C_LIM = 0.5
#: a cylinder's paths with a projected-frequency factor below this share the tables of
#: broadside (their late ringing is cut early; see the module docstring)
S_KEEP = 0.9
#: cut tables kept per target
TABLES = 16


def cut_window(t: np.ndarray, t_cut: float, taper: float = RING_TAPER_S,
               t_front: float | None = None) -> np.ndarray:
    """1 up to t_cut, a raised-cosine taper over ``taper``, 0 after; with ``t_front``,
    also 0 before t_front - taper and rising to 1 at t_front.  (A response sampled at fs
    has its front-face spike's band-limit tail, alternating at fs/2, ~-35 dB at 0.3 ms:
    cut hard, its step would leak into the band; tapered, it stays near fs/2, where the
    pulse has no energy.)"""
    t = np.asarray(t)
    w = 0.5 * (1.0 + np.cos(np.pi * np.clip((t - t_cut) / taper, 0.0, 1.0)))
    if t_front is not None:
        w = w * 0.5 * (1.0 + np.cos(np.pi * np.clip((t_front - t) / taper, 0.0, 1.0)))
    return w


def front_samples(fs: float) -> int:
    """Samples of the taper before a response's front (:func:`cut_window`)."""
    return int(math.ceil(RING_TAPER_S * fs))


def tail_samples(target, fs: float, pre: int) -> int:
    """Extra length of a ringing target's FFT period beyond the pings' own (window and
    two pulse leads): the front-face advance, the taper, the quantisation of the cut and,
    for a cylinder, twice the spread of the sinc of its length."""
    b = 2.0 * target.length / target.host.sound_speed if target.kind == "cylinder" else 0.0
    return (pre + front_samples(fs)
            + int(math.ceil((RING_TAPER_S + CUT_STEP_S + b) * fs)) + 2)


class _Tables:
    """A small least-recently-used cache of cut tables."""

    def __init__(self, make, size: int = TABLES):
        self.make, self.size = make, size
        self.store: OrderedDict = OrderedDict()

    def __call__(self, q):
        tab = self.store.get(q)
        if tab is None:
            tab = self.store[q] = self.make(q)
            if len(self.store) > self.size:
                self.store.popitem(last=False)
        else:
            self.store.move_to_end(q)
        return tab


def _modal(target, f: np.ndarray) -> np.ndarray:
    """conj((-i/k)(2n+1) b_n) (F, N): the modal far-field terms, numpy's convention."""
    s = target.series(f)
    return np.conj((-1j / s.k)[:, None] * s.coefficients)


class ModalRinging:
    """The cut modal responses of a sphere or shell on a synthesis grid (n_fft, bins).

    ``pulse``: the digitised transmit pulse (for the fold bound and the ring time);
    ``pre``: samples of the front-face advance (a taper of RING_TAPER_S before it);
    ``keep``: samples after the echo's nominal time to hold (the longest cut plus its
    taper); ``cap`` (s): longest cut."""

    def __init__(self, target, pulse: np.ndarray, fs: float, f_max: float, pre: int,
                 keep: int, n_fft: int, bins: np.ndarray, cap: float):
        self.front = pre / fs                   # the taper rises before -pre
        pre += front_samples(fs)
        self.fs, self.pre, self.keep, self.cap = fs, pre, keep, cap
        self.n_fft, self.bins = n_fft, bins
        n = sfft.next_fast_len(4 * (keep + pre))
        n += n % 2
        x = _modal(target, self._freq(n, 1, f_max))
        while True:
            h, ratio, t_ring = self._time(x, n, pulse, pre)
            if ratio <= 10.0 ** (-FOLD_DB / 10.0) or 2 * n / fs > MAX_FINE_S:
                break
            xo = _modal(target, self._freq(2 * n, 2, f_max))     # the new (odd) bins
            width = max(x.shape[1], xo.shape[1])
            y = np.zeros((x.shape[0] + xo.shape[0], width), dtype=complex)
            y[0::2, :xo.shape[1]] = xo
            y[1::2, :x.shape[1]] = x
            x, n = y, 2 * n
        if ratio > 10.0 ** (-FOLD_DB / 10.0):
            log.warning("target %d: %.0f dB of its response beyond the fine period "
                        "%.2f s", target.index, 10 * math.log10(ratio), n / fs)
        #: fine period (s), energy of its last quarter re the total, ring time (s)
        self.fine_s, self.fold, self.t_ring = n / fs, ratio, t_ring
        self.h = np.concatenate((h[n - pre:], h[:keep]))          # t = -pre .. keep
        self.n_terms = x.shape[1]
        self.tables = _Tables(self._table)

    def _freq(self, n: int, stride: int, f_max: float) -> np.ndarray:
        j = np.arange(1, n // 2 + 1, stride)
        return j[j * self.fs / n <= f_max * (1 + 1e-12)] * self.fs / n

    def _time(self, x: np.ndarray, n: int, pulse: np.ndarray, pre: int):
        big = np.zeros((n // 2 + 1, x.shape[1]), dtype=complex)
        big[1:1 + x.shape[0]] = x
        h = sfft.irfft(big, n, axis=0)
        y = sfft.irfft(big * sfft.rfft(pulse, n)[:, None], n, axis=0)
        e = np.sum(y * y, axis=1)
        total = float(e.sum())
        if not total > 0:
            return h, 0.0, 0.0
        ratio = float(e[3 * n // 4 - pre:n - pre].sum()) / total
        sign = np.where(np.arange(x.shape[1]) % 2 == 0, 1.0, -1.0)
        e_bs = (y @ sign)[:n - pre] ** 2                 # the monostatic echo
        after = np.cumsum(e_bs[::-1])[::-1]
        thr = float(e_bs.sum()) * 10.0 ** (-60.0 / 10.0)
        return h, ratio, float(np.argmax(after <= thr)) / self.fs

    def _table(self, q: int) -> np.ndarray:
        t = np.arange(-self.pre, self.keep) / self.fs
        w = cut_window(t, min(q * CUT_STEP_S, self.cap), t_front=-self.front)
        hw = self.h * w[:, None]
        x = np.zeros((self.n_fft, hw.shape[1]))
        x[:self.keep] = hw[self.pre:]
        x[self.n_fft - self.pre:] = hw[:self.pre]
        return sfft.rfft(x, axis=0)[self.bins]                   # (F, N)

    def form(self, k_in: np.ndarray, k_out: np.ndarray, keep_s: np.ndarray) -> np.ndarray:
        """conj(f) (M, F) of paths with directions k_in, k_out (M, 3), each cut
        ``keep_s`` (M,) s after its nominal time (quantised upwards)."""
        q = np.maximum(np.ceil(keep_s / CUT_STEP_S - 1e-9), 0).astype(np.int64)
        mu = np.clip(np.sum(k_in * k_out, axis=1), -1.0, 1.0)
        p = legendre_table(self.n_terms, mu)
        out = np.empty((mu.size, self.bins.size), dtype=complex)
        for qq in np.unique(q):
            sel = np.flatnonzero(q == qq)
            out[sel] = complex_matmul(self.tables(int(qq)), p[:, sel]).T
        return out


class CylinderRinging:
    """A cylinder's paths with its form table cut per path in projected time."""

    def __init__(self, target, f_max: float):
        self.target = target
        self.table = target._form
        self.table.ensure(f_max)
        period = 1.0 / self.table.step
        self.c_max = max(C_LIM * period - self.table.pre - 2 * RING_TAPER_S, CUT_STEP_S)
        self.tables = _Tables(lambda q: self.table.cut(q * CUT_STEP_S), 2 * TABLES)

    def form(self, freq: np.ndarray, k_in: np.ndarray, k_out: np.ndarray,
             keep_s: np.ndarray) -> np.ndarray:
        """conj(f) (M, F) of paths, each keeping ``keep_s`` (M,) real seconds."""
        t = self.target
        s, b = t.cylinder_scales(k_in, k_out)
        lb = np.maximum(keep_s, 0.0) + b
        c = np.where(s >= S_KEEP, lb / np.maximum(s, 1e-9), lb)
        q = np.minimum(np.ceil(c / CUT_STEP_S - 1e-9),
                       math.floor(self.c_max / CUT_STEP_S)).astype(np.int64)
        out = np.empty((s.size, freq.size), dtype=complex)
        for qq in np.unique(q):
            sel = np.flatnonzero(q == qq)
            out[sel] = np.conj(t.amplitude(freq, k_in[sel], k_out[sel],
                                           form=self.tables(int(qq))))
        return out
