"""The autofocus as a stage of ``svss process`` and ``svss batch`` (docs/autofocus.md,
"Turning it on").

Per run: the run's pings, posed as the re-navigation (or the micronavigation's fusion,
or the recording) posed them, are imaged in memory as the tiles image them; the
isolated responses of those tiles are focused on (:func:`.autofocus.autofocus_image`,
its guard included) and, where the guard accepts the corrections, the run is imaged
again for its tiles with the corrected poses; where it refuses, with the poses it
started from. What happened (:class:`AutofocusOutcome`) goes into the manifest
(``autofocus``), the tiles' provenance (their ``poses``) and the log.

Per run and not per tile: the corrections are smooth in time over the pings that see
the points, which straddle the tiles' seams, and one set of poses for the run keeps the
tiles continuous across them. The run's pings are held in memory for it (a run of
minutes; a survey's hours are batched as runs).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Iterable

import numpy as np

from svss_daq.ping import NavSnapshot, Ping
from svss_daq.ping_gate import PingRejected

from .autofocus import autofocus_image, autofocus_settings

log = logging.getLogger(__name__)

__all__ = ["AutofocusOutcome", "autofocus_wanted", "focus_run"]


@dataclass(frozen=True)
class AutofocusOutcome:
    """What the autofocus stage did to a run (the manifest's ``autofocus``)."""
    applied: bool
    reason: str
    points: int = 0
    #: mean and worst change of the focused points' peaks (dB), corrected over navigated
    gain_db_mean: float | None = None
    gain_db_worst: float | None = None
    #: rms of the corrections over the pings, m (tile frame: cross-track, down)
    cross_rms_m: float = 0.0
    down_rms_m: float = 0.0

    def summary(self) -> dict:
        """JSON-ready (the manifest's ``autofocus``)."""
        r = lambda v, n: None if v is None else round(float(v), n)   # noqa: E731
        return {"enabled": True, "applied": self.applied, "reason": self.reason,
                "points": self.points, "gain_db_mean": r(self.gain_db_mean, 3),
                "gain_db_worst": r(self.gain_db_worst, 3),
                "corrections_rms_mm": {"cross": r(self.cross_rms_m * 1e3, 3),
                                       "down": r(self.down_rms_m * 1e3, 3)}}

    @property
    def description(self) -> str:
        """For the logs and the tiles' provenance."""
        if not self.applied:
            return f"autofocus refused ({self.reason}); the navigation kept"
        return (f"autofocus applied on {self.points} points (peaks {self.gain_db_mean:+.2f} "
                f"dB mean, corrections rms {self.cross_rms_m * 1e3:.1f} mm cross, "
                f"{self.down_rms_m * 1e3:.1f} mm down)")


#: the manifest's ``autofocus`` where the stage was off
OFF = {"enabled": False}


def autofocus_wanted(flag: bool | None, processing) -> bool:
    """The stage on: ``flag`` (``--autofocus`` / ``--no-autofocus``), else the processing
    configuration's ``[autofocus] enabled``."""
    if flag is not None:
        return bool(flag)
    cfg = getattr(processing, "autofocus", None)
    return bool(cfg is not None and cfg.enabled)


def focus_run(pings: Iterable[Ping], hardware, processing
              ) -> tuple[list[NavSnapshot], AutofocusOutcome]:
    """Every ping's pose after the autofocus (the input's where refused, and for pings
    the imager refuses) and what it did (module docstring). ``pings``: the run's, in
    order, posed as they are to be imaged; ``hardware``: the run's
    :class:`~svss_daq.config.Loaded` hardware configuration; ``processing``:
    :class:`~svss_daq.config.ProcessingConfig` (its ``[autofocus]`` the settings)."""
    from ..imaging.imager import TileImager
    settings = autofocus_settings(processing)
    pings = list(pings)
    navs = [p.nav for p in pings]
    imager = TileImager(hardware, processing, method="exact")   # estimation: the exact sum
    tiles, used, where = [], [], []
    for k, p in enumerate(pings):
        try:
            tiles += imager.add(p)
        except PingRejected as exc:
            log.debug("autofocus: %s", exc)
            continue
        used.append(p)
        where.append(k)
    tiles += imager.finish()
    if imager.line is None or not tiles:
        out = AutofocusOutcome(False, "no ping imaged")
    else:
        res, pick = autofocus_image(imager.accumulator, processing, imager.line, used, tiles,
                                    settings)
        n_points = len(pick.points)
        gain = res.gain_db if len(res.before) else np.zeros(0)
        g_mean = float(np.mean(gain)) if gain.size else None
        g_worst = float(np.min(gain)) if gain.size else None
        if res.kept:
            for k, p in zip(where, res.pings):
                navs[k] = p.nav
        out = AutofocusOutcome(
            bool(res.kept), res.reason, n_points, g_mean, g_worst,
            float(np.sqrt(np.mean(res.cross_m ** 2))) if res.kept else 0.0,
            float(np.sqrt(np.mean(res.down_m ** 2))) if res.kept else 0.0)
    log.info("%s", out.description)
    return navs, out
