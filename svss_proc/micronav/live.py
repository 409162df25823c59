"""Micronavigation as a stage of the tile worker (docs/worker.md, "Micronavigation";
docs/micronavigation.md, "Live").

As each ping arrives, in sequence order, its displacement from the previous ping is
estimated from their common phase centres (:func:`.horizontal.estimate_displacement`,
both pings placed by the navigation) and fused with the navigation's increment by the
forward fusion (:mod:`.forward_fusion`: the inverse-covariance mean of the two, anchored
to the navigation); the ping is then imaged at the fused position. Where the estimator
refuses (the phase centres do not overlap, no seabed, the echoes decorrelated), where
the previous ping is not the one before (a run's first ping, a gap, a ping refused) or
the estimate fails, the step is the navigation's: the correction carried so far decays
under the anchor, and with no correction at all the ping is imaged exactly as it came.

The stage conditions the ping through the imager's own accumulator and hands the same
:class:`~svss_proc.conditioning.Conditioned` to the imager (no second matched filter).
Its time is the clock's ``micronav`` stage; refusals are counted by reason.
"""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np

from svss_daq.frames import body_to_ned
from svss_daq.geometry import array_geometry
from svss_daq.ping import Ping
from svss_daq.ping_gate import reposed

from .forward_fusion import FusionState, fusion_start, fusion_step
from .horizontal import TapCache, estimate_displacement
from .patch_focus import warm_up
from .renav import array_lever_m, nav_increment_sigma

log = logging.getLogger(__name__)

#: why a step is the navigation's alone, besides the estimator's own reasons
NO_PREVIOUS = "no previous ping"
FAILED = "estimate failed"
#: pings whose fusion state is kept for the journal (the resume point is the first ping
#: of the earliest open tile: 15 m tiles at 1 m/s and 10 pings/s, 150 pings and the hold)
HISTORY = 2000


def reason_key(refused: str) -> str:
    """The kind of an estimator's refusal (its text before the first colon)."""
    return refused.split(":")[0].strip()


class LiveMicronav:
    """The stage: :meth:`pose` gives each ping (fed in sequence order) with its fused
    pose. ``config``: the processing configuration's ``[micronav]``; ``accumulator``:
    the imager's (its ``condition`` is memoised for the ping being posed); ``clock``:
    the worker's :class:`~svss_proc.live_clock.StageClock`."""

    def __init__(self, hardware, processing, config, accumulator, clock, nav_cfg):
        hw = hardware.value
        self.config = config
        #: the live navigation's configuration (devices.toml ``[navigation]``): its
        #: velocity and attitude sigmas weigh its steps
        self.nav_cfg = nav_cfg
        #: the array less the DVL head (body frame, m): the lever arm the attitude's
        #: noise turns (:func:`.renav.nav_increment_sigma`)
        self.lever_m = array_lever_m(hw.lever_arms)
        self.geometry = array_geometry(hw)
        self.sound_speed_m_s = processing.imaging.water_sound_speed_m_s
        self.clock = clock
        self.taps = TapCache()
        self.state: FusionState = fusion_start(config.anchor_sigma_m)
        self.prev: tuple | None = None           # (sequence, ping, conditioned)
        self.pairs = 0
        self.estimated = 0
        self.refused: dict[str, int] = {}
        self.max_correction_m = np.zeros(3)
        #: after each recent ping: (state, pairs, estimated, refused, largest correction),
        #: for the journal (:meth:`journal`); the last ``HISTORY`` pings
        self.history: dict[int, tuple] = {}
        self._resume_at: tuple | None = None     # (sequence, snapshot) from a journal
        self._acc = accumulator
        self._held = None                        # (samples, conditioned) of the ping posed
        condition = accumulator.condition

        def memo(ping):
            held = self._held
            if held is not None and held[0] is ping.samples:
                return held[1]
            return condition(ping)
        accumulator.condition = memo
        self._condition = condition
        warm_up()

    # ------------------------------------------------------------------ the stage
    def pose(self, ping: Ping) -> Ping:
        """``ping`` with the fused pose (itself where the fused correction is zero)."""
        cond = self._condition(ping)            # timed as the imager's conditioning
        self._held = (ping.samples, cond)
        if self._resume_at is not None and self._resume_at[0] == ping.sequence:
            # resumed: this ping's state as the interrupted run had it after this ping
            self._restore(self._resume_at[1])
            self._resume_at = None
            self.prev = (ping.sequence, ping, cond)
            self._remember(ping.sequence)
            return fused(ping, self.state.correction_m)
        with self.clock.stage("micronav"):
            corr, cov, why = None, None, None
            prev = self.prev
            seq = ping.sequence
            if prev is None or prev[0] != seq - 1:
                why = NO_PREVIOUS
            else:
                self.pairs += 1
                try:
                    est = self._estimate(prev[1], prev[2], ping, cond)
                except Exception:               # the ping is imaged on the navigation
                    why = FAILED
                    log.exception("ping %d: micronavigation failed", seq)
                else:
                    if est.refused:
                        why = reason_key(est.refused)
                    else:
                        corr, cov = est.correction_m, est.cov_m2
                        self.estimated += 1
            if why is not None:
                n = self.refused.get(why, 0) + 1
                self.refused[why] = n
                if why != NO_PREVIOUS and math.log10(n).is_integer():
                    log.info("ping %d: micronavigation refused (%d so far): %s", seq, n,
                             why)
            if prev is not None:
                self.state, _ = fusion_step(self.state, self._nav_cov(prev[1], ping), corr,
                                            cov, self.config.anchor_sigma_m)
            self.prev = (seq, ping, cond)
            e = self.state.correction_m
            self.max_correction_m = np.maximum(self.max_correction_m, np.abs(e))
            self._remember(seq)
            return fused(ping, e)

    # ------------------------------------------------------------------ resume
    def _remember(self, seq: int) -> None:
        self.history[seq] = (self.state, self.pairs, self.estimated, dict(self.refused),
                             self.max_correction_m.copy())
        if len(self.history) > HISTORY:
            for k in sorted(self.history)[:len(self.history) - HISTORY]:
                del self.history[k]

    def _restore(self, snap: tuple) -> None:
        self.state, self.pairs, self.estimated, refused, mx = snap
        self.refused = dict(refused)
        self.max_correction_m = np.array(mx, dtype=np.float64)

    def journal(self, resume_sequence: int | None) -> dict | None:
        """What a resumed worker needs to fuse on as this one did: the state after ping
        ``resume_sequence`` (the first it will be fed again), and the counts then; None
        when that ping was not posed here (a worker resumed with no open tile starts
        afresh)."""
        snap = self.history.get(resume_sequence) if resume_sequence is not None else None
        if snap is None:
            return None
        state, pairs, estimated, refused, mx = snap
        return {"sequence": int(resume_sequence),
                "correction_m": [float(v) for v in state.correction_m],
                "cov_m2": [[float(v) for v in row] for row in state.cov_m2],
                "pairs": pairs, "estimated": estimated, "refused": refused,
                "max_correction_m": [float(v) for v in mx]}

    def resume(self, saved: dict | None) -> None:
        """Take up a journal's :meth:`journal` entry: its ping is posed as it was."""
        if not saved:
            return
        try:
            state = FusionState(np.array(saved["correction_m"], dtype=np.float64).reshape(3),
                                np.array(saved["cov_m2"], dtype=np.float64).reshape(3, 3))
            snap = (state, int(saved["pairs"]), int(saved["estimated"]),
                    {str(k): int(v) for k, v in saved["refused"].items()},
                    np.array(saved["max_correction_m"], dtype=np.float64).reshape(3))
            self._resume_at = (int(saved["sequence"]), snap)
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            log.warning("journal's micronavigation state unreadable (%s): the fusion "
                        "starts afresh", exc)

    def _estimate(self, pa: Ping, ca, pb: Ping, cb):
        na, nb = pa.nav, pb.nav
        return estimate_displacement(
            ca.data, cb.data, ca.t0_s, ca.dt_s, self.geometry, pa.projector, pb.projector,
            body_to_ned(na.roll_rad, na.pitch_rad, na.heading_rad), na.ned,
            body_to_ned(nb.roll_rad, nb.pitch_rad, nb.heading_rad), nb.ned,
            na.down_m + na.altitude_m, self.sound_speed_m_s, ca.center_hz,
            passes=self.config.passes, translations=self.config.translations,
            taps=self.taps)

    def _nav_cov(self, pa: Ping, pb: Ping) -> np.ndarray:
        """The navigation's covariance of the step from ``pa`` to ``pb``: the
        re-navigation's own (:func:`.renav.nav_increment_sigma`: its lock rule, the DVL's
        velocity sigmas over the step's time, the GPS's without fusion, the attitude's
        noise turning the lever arm to the array), diagonal."""
        sigma = nav_increment_sigma([pa.nav, pb.nav], self.nav_cfg, self.lever_m)[0]
        return np.diag(np.maximum(sigma, 1e-9) ** 2)

    def summary(self) -> dict:
        """For the run's manifest: ping pairs tried, estimated, refusals by reason, the
        largest fused correction per axis (north, east, down, m) and the last one."""
        return {"pairs": self.pairs, "estimated": self.estimated,
                "refused": dict(sorted(self.refused.items())),
                "max_correction_m": [round(float(v), 6) for v in self.max_correction_m],
                "last_correction_m": [round(float(v), 6) for v in self.state.correction_m]}


def fused(ping: Ping, correction_m: np.ndarray) -> Ping:
    """``ping`` moved by ``correction_m`` (north, east, down, m); its altitude less by the
    downward part (the array moved, the seabed did not). Unchanged for a zero
    correction."""
    if not np.any(correction_m):
        return ping
    nav = ping.nav
    dn, de, dd = (float(v) for v in correction_m)
    return reposed(ping, dataclasses.replace(
        nav, north_m=nav.north_m + dn, east_m=nav.east_m + de, down_m=nav.down_m + dd,
        altitude_m=nav.altitude_m - dd))


def live_stage(hardware, processing, accumulator, clock, poses_live: bool, nav_cfg=None
               ) -> LiveMicronav | None:
    """The stage when the processing configuration's ``[micronav] live`` is set and the
    pings carry their live poses (``poses_live``; re-navigated poses are the
    re-navigation's to fuse); None otherwise. ``nav_cfg``: the navigation configuration
    (default: the project's devices.toml ``[navigation]``)."""
    cfg = processing.micronav
    if cfg is None or not cfg.live or not poses_live:
        return None
    if nav_cfg is None:
        from svss_daq.nav.renavigate import current_navigation_config
        nav_cfg = current_navigation_config()
    return LiveMicronav(hardware, processing, cfg, accumulator, clock, nav_cfg)
