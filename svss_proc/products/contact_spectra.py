"""The spectrum of the returns from each contact's position, from the pings that saw it
(issue 51; docs/contact_features.md, "Resonance lines from the pings").

An elastic object keeps ringing after its specular echo; its resonances are lines in the
spectrum of that late response, narrow for a ringing shell or cylinder, wide or absent
for a rock. The tile keeps only the image, so the lines are measured on the pings: per
ping that saw the contact (inside the projector's cone), the receive channels focused on
the contact's position by delay-and-sum (each channel's two-way time through the
water-sediment interface, the imaging's own refraction, :func:`one_way_time`), as a
time series from ``start_s`` after the contact's arrival to ``start_s + length_s``:

    e(t) = sum_ch w_ch b_ch(tau_ch + t) exp(+j 2 pi f_c tau_ch)

with ``b_ch`` the channel's matched-filtered complex baseband and ``w_ch`` the receive
apodisation: the baseband of the focused analytic response, the same for every channel
whatever its delay. The pings' series are the snapshots of
:func:`~.contact_features.resonance_lines` (a multi-snapshot matrix pencil, errors by a
jackknife over the pings); lines inside the transmitted band are kept.

Pure functions of arrays and poses (:func:`focused_echo`, :func:`contact_lines`) and one
streaming collector (:class:`EchoCollector`) fed one conditioned ping at a time; the
files are read by :mod:`svss_proc.run_worker`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from svss_daq.conventions import remodulation

from ..imaging.delays import layered_ray, one_way_time
from .contact_features import resonance_lines

#: the columns each contact gets (run contacts; NaN / 0: not measured)
SPECTRA_FIELDS = ("resonance_hz", "resonance_err_hz", "resonance_width_hz",
                  "resonance_width_err_hz", "late_over_background_db", "resonance_pings")
#: a contact's columns where they were not measured
NO_SPECTRA = {**{k: math.nan for k in SPECTRA_FIELDS}, "resonance_pings": 0}


@dataclass(frozen=True)
class Focus:
    """What focusing needs besides the ping: water and sediment speeds (m/s), the band's
    centre (Hz), the cones' cosines (projector, receivers; gating), the receive
    apodisation (None: uniform), the series' start after the arrival and length (s), and
    the sediment's layers as the imaging refracts through them (``tops`` m, ``speeds``
    m/s, :class:`~svss_proc.imaging.delays.SpeedProfile`; None: one half-space at
    ``sediment_m_s``)."""
    water_m_s: float
    sediment_m_s: float
    center_hz: float
    cos_tx: float
    cos_rx: float
    apod: np.ndarray | None
    start_s: float
    length_s: float
    tops: np.ndarray | None = None
    speeds: np.ndarray | None = None


def two_way_times(tx: np.ndarray, rx: np.ndarray, point: np.ndarray, cw: float,
                  cs: float, surface_m: float = 0.0, tops: np.ndarray | None = None,
                  speeds: np.ndarray | None = None) -> np.ndarray:
    """Two-way times (s) from projector ``tx`` to ``point`` and back to each receiver of
    ``rx`` (channels x 3), tile frame (z down from the frame's level; elements above
    it). ``point``'s depth is below the interface of its own column, which lies
    ``surface_m`` below the level (a sloping or rough bed), so each element's height
    above that interface is its own plus ``surface_m``, as the imaging kernels take
    them; refracted through the interface (and through ``tops``/``speeds`` layers where
    given) where the point is below it."""
    z = float(point[2])
    layered = tops is not None and speeds is not None and len(speeds) > 1

    def one(e):
        rho = math.hypot(float(point[0] - e[0]), float(point[1] - e[1]))
        h = float(surface_m) - float(e[2])
        if layered:
            return layered_ray(h, rho, z, cw, tops, speeds)[0]
        return one_way_time(h, rho, z, cw, cs)
    t_tx = one(tx)
    return np.array([t_tx + one(r) for r in rx])


def in_cone(origin: np.ndarray, bore: np.ndarray, point: np.ndarray, cos_half: float) -> bool:
    """The point lies inside the cone of half angle acos(``cos_half``) about ``bore``."""
    v = np.asarray(point, dtype=float) - origin
    return float(v @ bore) >= float(np.linalg.norm(v)) * cos_half


def focused_echo(baseband: np.ndarray, t0: float, dt: float, tx: np.ndarray,
                 rx: np.ndarray, bore: np.ndarray, point: np.ndarray,
                 focus: Focus, surface_m: float = 0.0) -> np.ndarray | None:
    """One ping's response at ``point`` (tile frame) as a complex baseband series,
    ``n = round(length_s / dt)`` samples from ``start_s`` after the arrival, at the
    conditioned rate ``1 / dt``: the channels of ``baseband`` (channels x samples, sample
    m at ``t0 + m dt``) at their two-way times, linearly interpolated, brought to a
    common phase and summed over the receivers whose cone holds the point (weights
    ``focus.apod``). None where the projector's cone does not hold the point, no
    receiver does, or the series leaves the record. ``surface_m``: the interface's depth
    below the frame's level at the point's column (:func:`two_way_times`)."""
    point = np.asarray(point, dtype=float)
    at = point + np.array([0.0, 0.0, surface_m])          # in the frame, for the cones
    if not in_cone(tx, bore, at, focus.cos_tx):
        return None
    tau = two_way_times(tx, rx, point, focus.water_m_s, focus.sediment_m_s, surface_m,
                        focus.tops, focus.speeds)
    w = np.ones(rx.shape[0]) if focus.apod is None else np.asarray(focus.apod, float)
    seen = np.array([in_cone(r, bore, at, focus.cos_rx) for r in rx]) & (w != 0)
    if not seen.any():
        return None
    n = max(2, int(round(focus.length_s / dt)))
    u = (tau[seen, None] + focus.start_s + dt * np.arange(n)[None, :] - t0) / dt
    i = np.floor(u).astype(np.int64)
    nt = baseband.shape[1]
    if i.min() < 0 or i.max() + 1 >= nt:
        return None
    f = u - i
    rows = np.flatnonzero(seen)[:, None]
    x = baseband[rows, i] * (1.0 - f) + baseband[rows, i + 1] * f
    phase = remodulation(tau[seen], focus.center_hz)
    return (w[seen, None] * phase[:, None] * x).sum(axis=0) / w[seen].sum()


@dataclass
class EchoCollector:
    """Each point's focused series over the pings fed to it (:meth:`add`), for
    :func:`contact_lines`, and the same at its references: ``reference_m`` along-track
    on either side, at its cross-track position and depth (the background's late
    response, :func:`late_over_background_db`). ``points``: tile-frame positions (n x 3),
    their depths below the interface of their own column; ``surface``: that interface's
    depth below the frame's level at (along, cross) (None: level everywhere,
    :meth:`~svss_proc.imaging.surface.InterfaceShape.depth`)."""
    points: np.ndarray
    focus: Focus
    reference_m: float = 0.6
    surface: object = None
    echoes: list[list[np.ndarray]] = field(default_factory=list)
    references: list[list[np.ndarray]] = field(default_factory=list)

    def __post_init__(self):
        self.points = np.asarray(self.points, dtype=float).reshape(-1, 3)
        self.echoes = [[] for _ in range(self.points.shape[0])]
        self.references = [[] for _ in range(self.points.shape[0])]
        step = np.array([self.reference_m, 0.0, 0.0])
        self._refs = [[(r, self._surface(r)) for r in (p - step, p + step)]
                      for p in self.points]
        self._own = [self._surface(p) for p in self.points]
        #: the points in the frame (their depths below its level), for the cones
        self._at = self.points + np.array([[0.0, 0.0, 1.0]]) * np.array(self._own)[:, None]

    def _surface(self, p) -> float:
        if self.surface is None:
            return 0.0
        s = float(self.surface(float(p[0]), float(p[1])))
        return s if math.isfinite(s) else 0.0

    def wants(self, tx: np.ndarray, bore: np.ndarray) -> np.ndarray:
        """Indices of the points inside this ping's projector cone (the ping need not be
        conditioned when there are none)."""
        return np.array([k for k, p in enumerate(self._at)
                         if in_cone(tx, bore, p, self.focus.cos_tx)], dtype=np.int64)

    def add(self, baseband: np.ndarray, t0: float, dt: float, tx: np.ndarray,
            rx: np.ndarray, bore: np.ndarray, which: np.ndarray | None = None) -> int:
        """Focus one conditioned ping on the points ``which`` (default: all) and on
        their references; returns how many series it gave at the points."""
        got = 0
        for k in (range(self.points.shape[0]) if which is None else which):
            e = focused_echo(baseband, t0, dt, tx, rx, bore, self.points[k], self.focus,
                             self._own[k])
            if e is None:
                continue
            self.echoes[k].append(e)
            got += 1
            for r, s in self._refs[k]:
                e = focused_echo(baseband, t0, dt, tx, rx, bore, r, self.focus, s)
                if e is not None:
                    self.references[k].append(e)
        return got


def late_over_background_db(echoes: list[np.ndarray], references: list[np.ndarray]
                            ) -> float:
    """Mean power of a contact's series over that of its references' (dB; NaN without
    references): how far its late response stands above the background's."""
    if not len(echoes) or not len(references):
        return math.nan
    p = float(np.mean(np.abs(np.asarray(echoes)) ** 2))
    b = float(np.mean(np.abs(np.asarray(references)) ** 2))
    return 10 * math.log10(p / b) if b > 0 and p > 0 else math.nan


def contact_lines(echoes: list[np.ndarray], dt: float, center_hz: float,
                  band_hz: tuple[float, float], min_pings: int = 3, max_lines: int = 4,
                  rel_threshold: float = 1e-2, references: list[np.ndarray] | None = None,
                  min_over_background_db: float | None = None) -> dict:
    """The strongest resonance line inside ``band_hz`` of one contact's focused series
    (pings x samples, complex baseband about ``center_hz``, rate ``1 / dt``): its
    frequency, full width at half power and their jackknife errors over the pings, Hz,
    the late response's power over its ``references``' (:func:`late_over_background_db`)
    and the pings used (:data:`SPECTRA_FIELDS`). The line is NaN where fewer than
    ``min_pings`` pings saw the contact, no line lies in the band, or the late response
    stands less than ``min_over_background_db`` over the background (the pencil finds
    lines in any band-limited series: the background's own)."""
    out = {**NO_SPECTRA, "resonance_pings": len(echoes)}
    if len(echoes) < max(1, min_pings):
        return out
    out["late_over_background_db"] = late = late_over_background_db(echoes, references or [])
    if min_over_background_db is not None and not late >= min_over_background_db:
        return out
    lines = resonance_lines(np.array(echoes), 1.0 / dt, max_lines=max_lines,
                            rel_threshold=rel_threshold, f_offset_hz=center_hz)
    lo, hi = min(band_hz), max(band_hz)
    inside = np.flatnonzero((lines.frequency_hz >= lo) & (lines.frequency_hz <= hi)
                            & (lines.width_hz > 0))
    if inside.size == 0:
        return out
    k = int(inside[0])                        # lines come strongest first
    out.update(resonance_hz=float(lines.frequency_hz[k]),
               resonance_err_hz=float(lines.frequency_err_hz[k]),
               resonance_width_hz=float(lines.width_hz[k]),
               resonance_width_err_hz=float(lines.width_err_hz[k]))
    return out
