"""Micronavigation inside the re-navigation of a recorded run: the echoes' ping-to-ping
increments (:mod:`.horizontal`) fused with the re-navigated poses' (:mod:`.fusion`),
each weighted by its own error estimate (docs/micronavigation.md, "In the
re-navigation").

1. **The navigation's increments and their sigma** (:func:`nav_increment_sigma`). A step
   between two pings the DVL carried (both poses fused with bottom lock) has the error
   of the DVL's velocity noise over the step, ``dvl_velocity_sigma_m_s`` x dt per axis
   (the filter's own process noise, ``svss_daq/nav/fusion.py``); a step without bottom
   lock at either end, the velocity held (within ``dvl_max_gap_s`` of a locked sample),
   has the filter's held-velocity sigma, ``dvl_gap_velocity_sigma_m_s`` x dt; a step
   whose poses come from the GPS alone (no ``NAV_FUSED``: a dropout longer than
   ``dvl_max_gap_s``, positions interpolated between fixes) has the GPS's,
   ``gps_sigma_m`` across and along and ``gps_height_sigma_m`` down. The increments
   are those of the array, which the fusion and the imaging place: to these the
   attitude's noise adds (:func:`attitude_increment_sigma`) the lever arm from the DVL
   head to the array turned by the change of the heading (HDT, ``heading_sigma_deg``)
   and of roll and pitch (``dvl_tilt_sigma_deg``) between the two pings, and the DVL's
   displacement over the step turned by one attitude's noise. The poses interpolate the
   attitude linearly between its samples (``heading_interval_s``, ``dvl_interval_s``),
   and the smoother does nothing else to it: white noise interpolated so has, between
   two times u sample intervals apart, 2u^2 - u^3 of the samples' variance (u <= 1;
   :func:`interpolated_noise_factor`). With the configured 0.17 deg at 5 Hz and the
   0.8 m lever arm, 1.5 mm across a ping step, against the DVL's 0.3 mm.
2. **The echoes' increments** (:func:`echo_increments`): for each pair of consecutive
   pings, :func:`~.horizontal.estimate_displacement` on their conditioned echoes, ping
   b placed for the pairing at ping a's pose plus a *seed* increment: the navigation's
   where its sigma is below ``max_seed_sigma_m``, else the last increment the echoes
   measured (a dropout's GPS-interpolated steps are centimetres off, beyond the
   estimator's reach of about 13 mm vertically). Where the navigation's step is that
   uncertain, ping a itself is placed where the chain of the echoes' increments (the
   seed where they refused) put it from the last ping the navigation placed well: the
   GPS heights (0.5 m) would put the array decimetres off its height above the seabed,
   and the patches would be focused at the wrong range. The seabed is the poses' bottom depth
   (body depth + altitude), interpolated across pings without one.
3. **Fusion** (:func:`fuse_poses`, :func:`~.fusion.fuse_increments`), at the array's
   reference point (each pose's lever arm to the array turned by its attitude added to
   its position and, differenced, to the echoes' body-origin increments: there the
   navigation's error is the DVL's plus the attitude's noise over the lever arm from
   the DVL head, modelled as the positions' noise, :func:`attitude_position_noise`, and
   the echoes' is their own): the positions minimising both sets of
   increments' weighted residuals, a weak anchor to the navigation's positions and the
   acceleration prior (``acceleration_sigma_m_s2`` x T^2 per second difference), so a
   step the echoes refused inside a dropout follows its neighbours. Attitude and the
   measured bottom depth are kept (the altitude moves with the fused depth).
   Before, the echoes' mean error per axis is measured against the navigation's
   increments on the steps with bottom lock where both exist (at least
   ``bias_min_steps`` of them) and taken out of every echo increment: the estimator's
   surge bias (-2 to -3.5 mm a step, docs/phase_centres.md, "Limits") chained over a 10 s
   dropout is 4 % of the distance run.
4. **Altitude through a dropout** (:func:`with_interpolated_bottom`): the navigation
   gives no altitude without bottom lock, and the ping gate refuses such pings. The
   fused poses take the bottom depth interpolated in time between the last and next
   measured ones (a flat or evenly sloping seabed over the gap: the estimator focused
   its patches on that plane), so the pings under the dropout can be imaged. Their
   flags still say no bottom lock.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections import Counter
from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np
import scipy.sparse as sp

from svss_daq.frames import body_to_ned
from svss_daq.geometry import array_geometry
from svss_daq.ping import (NAV_BOTTOM_LOCK, NAV_DVL_VELOCITY, NAV_FUSED, NAV_SIMULATED,
                           NavSnapshot)
from svss_daq.waveform import make_waveform
from svss_proc.conditioning import Conditioner

from .fusion import fuse_increments
from .horizontal import DisplacementEstimate, estimate_displacement

__all__ = ["EchoIncrements", "MicronavResult", "array_lever_m", "attitude_increment_sigma",
           "attitude_position_noise", "fuse_poses",
           "echo_increments", "fuse_with_navigation", "interpolated_noise_factor",
           "locked_steps", "nav_increment_sigma", "refusal_reason", "with_interpolated_bottom"]

log = logging.getLogger(__name__)


def locked_steps(poses: Sequence[NavSnapshot]) -> np.ndarray:
    """Per step between consecutive poses (n - 1,): both fused from the DVL with bottom
    lock (``NAV_FUSED`` and ``NAV_BOTTOM_LOCK``) and the DVL's velocity carrying the track
    (``NAV_DVL_VELOCITY``: a real DVL sends ranges without a valid velocity, RDI's
    -32768, and the navigation then holds the velocity: its altitude alone is no lock).
    The simulator's own poses (``NAV_SIMULATED``, a stream without navigation: the
    truth) count as locked."""
    need = NAV_FUSED | NAV_BOTTOM_LOCK | NAV_DVL_VELOCITY
    locked = np.array([(p.quality & need) == need or bool(p.quality & NAV_SIMULATED)
                       for p in poses], dtype=bool)
    return locked[:-1] & locked[1:]


def interpolated_noise_factor(dt_s: float, interval_s: float, difference: bool = True
                              ) -> float:
    """Variance, in units of the samples' variance, of white noise sampled every
    ``interval_s`` and interpolated linearly: of the difference between two times
    ``dt_s`` apart (``difference``), or of one interpolated value; averaged over where
    the two times fall between the samples. For dt < interval it is 2u^2 - u^3
    (u = dt / interval: 0.375 for pings at 10 /s between samples at 5 /s); one value:
    2/3."""
    u = dt_s / interval_s
    a = (np.arange(256) + 0.5) / 256                      # phase of the first time
    n = int(math.ceil(a[-1] + u)) + 2
    w = np.zeros((a.size, n))
    rows = np.arange(a.size)
    for sign, x in ((1.0, a + u), (-1.0, a)) if difference else ((1.0, a),):
        j = np.floor(x).astype(int)
        f = x - j
        np.add.at(w, (rows, j), sign * (1 - f))
        np.add.at(w, (rows, j + 1), sign * f)
    return float(np.mean((w ** 2).sum(axis=1)))


def _turned(poses: Sequence[NavSnapshot], vec_body: np.ndarray) -> np.ndarray:
    """d(R vec)/d(roll, pitch, heading) at each pose (n, 3 angles, 3 NED), R the pose's
    body-to-NED rotation; ``vec_body`` (3,) or per pose (n, 3)."""
    eps = 1e-6
    vec = np.broadcast_to(np.asarray(vec_body, dtype=np.float64), (len(poses), 3))
    out = np.zeros((len(poses), 3, 3))
    for k, p in enumerate(poses):
        ang = np.array([p.roll_rad, p.pitch_rad, p.heading_rad])
        for i in range(3):
            d = np.zeros(3)
            d[i] = eps
            out[k, i] = (body_to_ned(*(ang + d)) - body_to_ned(*(ang - d))) @ vec[k] / (2 * eps)
    return out


def attitude_increment_sigma(poses: Sequence[NavSnapshot], nav_cfg,
                             lever_m: Sequence[float], lever_term: bool = True
                             ) -> np.ndarray:
    """Per step between consecutive poses, the sigma (n - 1, 3) the attitude's noise adds
    to the increment of a point ``lever_m`` (body frame) from the DVL head, per NED axis,
    m (module docstring, 1): the lever arm turned by the change of the heading (HDT) and
    roll and pitch (DVL) noise between the two pings, and the DVL's displacement over the
    step turned by the noise of one interpolated attitude. ``lever_term`` False leaves the
    lever arm's part out (the fusion models it as the positions' noise:
    :func:`attitude_position_noise`)."""
    n = len(poses)
    if n < 2:
        return np.zeros((0, 3))
    t = np.array([p.time_ns for p in poses], dtype=np.float64) * 1e-9
    dt = np.diff(t)
    sh, st = math.radians(nav_cfg.heading_sigma_deg), math.radians(nav_cfg.dvl_tilt_sigma_deg)
    sig2_angles = lambda f_h, f_t: np.array([st ** 2 * f_t, st ** 2 * f_t,   # noqa: E731
                                             sh ** 2 * f_h])
    dtm = float(np.median(dt))
    lever_var = sig2_angles(interpolated_noise_factor(dtm, nav_cfg.heading_interval_s),
                            interpolated_noise_factor(dtm, nav_cfg.dvl_interval_s))
    one_var = sig2_angles(interpolated_noise_factor(dtm, nav_cfg.heading_interval_s, False),
                          interpolated_noise_factor(dtm, nav_cfg.dvl_interval_s, False))
    j_lever = _turned(poses[:-1], np.asarray(lever_m, dtype=np.float64))
    v_ned = np.array([[p.vel_north_m_s, p.vel_east_m_s, p.vel_down_m_s] for p in poses[:-1]])
    v_ned = np.where(np.isfinite(v_ned), v_ned, 0.0)
    v_body = np.einsum("kji,kj->ki", np.array([body_to_ned(p.roll_rad, p.pitch_rad,
                                                           p.heading_rad) for p in poses[:-1]]),
                       v_ned)
    j_vel = _turned(poses[:-1], v_body * dt[:, None])
    var = np.einsum("a,kai->ki", one_var, j_vel ** 2)
    if lever_term:
        var = var + np.einsum("a,kai->ki", lever_var, j_lever ** 2)
    return np.sqrt(var)


#: sub-samples per attitude interval of :func:`attitude_position_noise`'s white noise
POSITION_NOISE_SUBSAMPLES = 8


def attitude_position_noise(poses: Sequence[NavSnapshot], nav_cfg,
                            lever_m: Sequence[float]) -> sp.csr_matrix:
    """The array positions' error from the attitude's noise turning the lever arm
    ``lever_m`` (body frame, m) from the DVL head to the array, as a sparse (3 n, m)
    matrix S: the error of pose k (N, E, D) is rows 3k..3k+2 of S theta, theta m white
    unit-variance unknowns (docs/micronavigation.md, "Position noise"). Each angle
    (roll and pitch sampled every ``dvl_interval_s`` with ``dvl_tilt_sigma_deg``, the
    heading every ``heading_interval_s`` with ``heading_sigma_deg``) interpolated
    linearly to the poses' times (module docstring, 1) has, averaged over the samples'
    phase to the pings (not known here), the covariance sigma^2 R(tau / T) with
    R(u) = 2/3 - u^2 + |u|^3 / 2 (|u| <= 1), (2 - |u|)^3 / 6 (1 <= |u| <= 2), 0 beyond:
    that of white noise smoothed by the interpolation's hat, which S realises on
    :data:`POSITION_NOISE_SUBSAMPLES` sub-samples a sample interval. The steps' errors
    are then correlated between neighbours, which a step noise cannot say."""
    n = len(poses)
    t = np.array([p.time_ns for p in poses], dtype=np.float64) * 1e-9
    t = t - t[0]
    jac = _turned(poses, np.asarray(lever_m, dtype=np.float64))       # (n, 3 angles, 3)
    sub = POSITION_NOISE_SUBSAMPLES
    rows, cols, vals = [], [], []
    col0 = 0
    for a, (interval, sig_deg) in enumerate((
            (nav_cfg.dvl_interval_s, nav_cfg.dvl_tilt_sigma_deg),
            (nav_cfg.dvl_interval_s, nav_cfg.dvl_tilt_sigma_deg),
            (nav_cfg.heading_interval_s, nav_cfg.heading_sigma_deg))):
        sig = math.radians(sig_deg) / math.sqrt(sub)
        # sub-sample j at time (j - sub + 0.5) interval / sub: from one interval before
        u = t / interval * sub
        first = np.floor(u).astype(int)
        m = int(first.max()) + 2 * sub + 1
        for off in range(-sub, sub + 1):
            j = first + off                             # sub-sample index past -interval
            ts = (j + 0.5) / sub                       # its time, in intervals
            w = np.maximum(0.0, 1.0 - np.abs(t / interval - ts))
            keep = w > 0
            for i in range(3):
                rows.append(3 * np.flatnonzero(keep) + i)
                cols.append(col0 + j[keep] + sub)
                vals.append(sig * w[keep] * jac[keep, a, i])
        col0 += m + sub
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(3 * n, col0))


def nav_increment_sigma(poses: Sequence[NavSnapshot], nav_cfg,
                        lever_m: Sequence[float] | None = None,
                        lever_term: bool = True) -> np.ndarray:
    """Per step between consecutive poses, the sigma (n - 1, 3) of the navigation's
    increment per NED axis, m (module docstring, 1); with ``lever_m`` (body frame, m:
    the array's reference point less the DVL head's) the attitude's noise turning that
    lever arm (:func:`attitude_increment_sigma`) is added: the increments are those of
    the array. ``lever_term`` False: without the lever arm's part (the step noise
    independent from step to step; the fusion models the rest as the positions' noise,
    :func:`attitude_position_noise`)."""
    t = np.array([p.time_ns for p in poses], dtype=np.float64) * 1e-9
    dt = np.diff(t)
    sig = np.where(locked_steps(poses), nav_cfg.dvl_velocity_sigma_m_s,
                   nav_cfg.dvl_gap_velocity_sigma_m_s)
    out = np.repeat((sig * dt)[:, None], 3, axis=1)
    fused = np.array([bool(p.quality & (NAV_FUSED | NAV_SIMULATED)) for p in poses],
                     dtype=bool)
    gps = ~(fused[:-1] & fused[1:])
    out[gps] = [nav_cfg.gps_sigma_m, nav_cfg.gps_sigma_m, nav_cfg.gps_height_sigma_m]
    if lever_m is not None and len(poses) > 1:
        out = np.hypot(out, attitude_increment_sigma(poses, nav_cfg, lever_m, lever_term))
    return out


def array_lever_m(lever_arms) -> np.ndarray:
    """The array's reference point less the DVL head's, body frame (m): the lever arm
    the attitude's noise turns between the DVL-carried track and the array."""
    return np.asarray(lever_arms.array_m, dtype=np.float64) - np.asarray(lever_arms.dvl_m)


def refusal_reason(text: str) -> str:
    """The class of an estimator's refusal: its message up to the first colon."""
    return text.split(":", 1)[0]


@dataclass(frozen=True)
class EchoIncrements:
    """The echoes' increments between consecutive pings: ``estimates`` (n - 1) (None
    where the two pings are not consecutive in sequence), with the seed each started
    from."""
    estimates: list[DisplacementEstimate | None]
    seeded_from_echoes: int

    def increments(self) -> tuple[np.ndarray, np.ndarray]:
        """(n - 1, 3) increments, NaN rows where refused; (n - 1, 3, 3) covariances
        (identity where refused)."""
        n = len(self.estimates)
        inc = np.full((n, 3), np.nan)
        cov = np.repeat(np.eye(3)[None], n, axis=0)
        for k, e in enumerate(self.estimates):
            if e is not None and e.refused is None:
                inc[k] = e.displacement_m
                cov[k] = e.cov_m2
        return inc, cov

    def refusals(self) -> dict[str, int]:
        """Refused pairs counted by reason."""
        return dict(Counter("the pings are not consecutive" if e is None
                            else refusal_reason(e.refused)
                            for e in self.estimates if e is None or e.refused))


def _bottom_depth(poses: Sequence[NavSnapshot]) -> np.ndarray:
    """Body depth + altitude per pose, interpolated in time where there is none."""
    t = np.array([p.time_ns for p in poses], dtype=np.float64)
    b = np.array([p.down_m + p.altitude_m for p in poses], dtype=np.float64)
    ok = np.isfinite(b)
    if not ok.any():
        return b
    return np.interp(t, t[ok], b[ok])


def with_interpolated_bottom(poses: Sequence[NavSnapshot]) -> tuple[list[NavSnapshot], int]:
    """``poses`` with an altitude where they have none: the bottom depth interpolated in
    time (module docstring, 4) less the body depth; and how many were filled."""
    bottom = _bottom_depth(poses)
    out, n = [], 0
    for p, b in zip(poses, bottom):
        if not math.isfinite(p.altitude_m) and math.isfinite(b):
            p = dataclasses.replace(p, altitude_m=float(b - p.down_m))
            n += 1
        out.append(p)
    return out, n


def echo_increments(pings: Iterable, poses: Sequence[NavSnapshot], hardware, processing,
                    nav_sigma_m: np.ndarray, max_seed_sigma_m: float,
                    **options) -> EchoIncrements:
    """The echoes' increment for each consecutive pair of ``pings`` (the run's pings in
    order, their samples) posed by ``poses`` (module docstring, 2). ``hardware``:
    :class:`~svss_daq.config.HardwareConfig`; ``processing``:
    :class:`~svss_daq.config.ProcessingConfig` (its conditioning and water sound speed);
    ``nav_sigma_m`` (n - 1, 3) of :func:`nav_increment_sigma`; ``options``: of
    :func:`~.horizontal.estimate_displacement`."""
    geometry = array_geometry(hardware)
    cond = Conditioner(hardware.digitiser, make_waveform(hardware.waveform),
                       processing.conditioning.decimation, processing.conditioning.upsample)
    c = processing.imaging.water_sound_speed_m_s
    fc = hardware.waveform.center_hz
    bottom = _bottom_depth(poses)
    pos = np.array([p.ned for p in poses], dtype=np.float64)
    out: list[DisplacementEstimate | None] = []
    prev = None
    last_echo = None
    from_echoes = 0
    placed = pos.copy()         # where each ping was placed for the pairing
    for k, ping in enumerate(pings):
        if k >= len(poses):
            raise ValueError(f"{k + 1} pings for {len(poses)} poses")
        cur = (ping, cond.ping(ping), poses[k])
        if prev is not None:
            (pa, ca, na), (pb, cb, nb) = prev, cur
            if (pb.sequence != pa.sequence + 1 or not math.isfinite(bottom[k - 1])
                    or pa.damage or pb.damage):     # damaged on disk: no echo pair
                out.append(None)
            else:
                nav_inc = pos[k] - pos[k - 1]
                seed = nav_inc
                origin_a = pos[k - 1]
                uncertain = bool(np.max(nav_sigma_m[k - 1]) > max_seed_sigma_m)
                if uncertain and last_echo is not None:
                    seed = last_echo
                    from_echoes += 1
                    origin_a = placed[k - 1]
                ra = body_to_ned(na.roll_rad, na.pitch_rad, na.heading_rad)
                rb = body_to_ned(nb.roll_rad, nb.pitch_rad, nb.heading_rad)
                est = estimate_displacement(ca.data, cb.data, ca.t0_s, ca.dt_s, geometry,
                                            pa.projector, pb.projector, ra, origin_a, rb,
                                            origin_a + seed, float(bottom[k - 1]), c, fc,
                                            **options)
                out.append(est)
                if est.refused is None:
                    last_echo = est.displacement_m
                step = est.displacement_m if est.refused is None else seed
                if uncertain:
                    placed[k] = origin_a + step
        prev = cur
    if len(out) != len(poses) - 1:
        raise ValueError(f"{len(out) + 1} pings for {len(poses)} poses")
    return EchoIncrements(out, from_echoes)


@dataclass(frozen=True)
class MicronavResult:
    """The fused poses and what went into them."""
    poses: list[NavSnapshot]
    echoes: EchoIncrements
    nav_sigma_m: np.ndarray
    #: the fused steps' covariances (None: not computed, :func:`~.fusion.fuse_increments`)
    fused_cov_m2: np.ndarray | None
    #: poses given an altitude from the interpolated bottom depth (no bottom lock)
    altitude_filled: int = 0
    #: the echoes' mean error against the navigation's locked steps, taken out (3,), m;
    #: None where too few steps measured it
    echo_bias_m: np.ndarray | None = None

    @property
    def n_pairs(self) -> int:
        return len(self.echoes.estimates)

    @property
    def n_echo(self) -> int:
        return sum(1 for e in self.echoes.estimates if e is not None and e.refused is None)

    @property
    def description(self) -> str:
        """How many increments came from the echoes, how many pairs were refused and why
        (for the logs, the tiles' provenance and the manifest)."""
        ref = self.echoes.refusals()
        why = "; ".join(f"{n} {r}" for r, n in sorted(ref.items(), key=lambda x: -x[1]))
        return (f"fused with {self.n_echo} of {self.n_pairs} ping-to-ping increments from "
                f"the echoes (micronavigation; {self.n_pairs - self.n_echo} pairs refused"
                + (f": {why}" if why else "") + ")"
                + (f"; {self.altitude_filled} poses without bottom lock given the bottom "
                   "depth interpolated across" if self.altitude_filled else "")
                + ("" if self.echo_bias_m is None else "; echo bias removed " + ", ".join(
                    f"{v * 1e3:+.1f}" for v in self.echo_bias_m) + " mm (N, E, D)"))

    def summary(self) -> dict:
        """JSON-ready counts (the manifest's)."""
        return {"pairs": self.n_pairs, "from_echoes": self.n_echo,
                "refused": self.echoes.refusals(), "altitude_filled": self.altitude_filled,
                "echo_bias_removed_mm": None if self.echo_bias_m is None
                else [float(v) * 1e3 for v in self.echo_bias_m],
                "seeded_from_echoes": self.echoes.seeded_from_echoes}


def fuse_poses(poses: Sequence[NavSnapshot], inc: np.ndarray, cov: np.ndarray,
               lever_arms, nav_cfg, micronav_cfg
               ) -> tuple[list[NavSnapshot], np.ndarray | None, np.ndarray | None]:
    """The ``poses`` fused with the echoes' body-origin increments ``inc`` (n - 1, 3; NaN
    rows refused) of covariances ``cov`` (module docstring, 3): (fused poses, the fused
    steps' covariances (None: not computed), the echoes' bias taken out (None: too few
    locked steps)). ``lever_arms``: the hardware's ``[lever_arms]``."""
    # fused at the array's reference point (what the imaging places, and where the
    # navigation's error is the DVL's plus the attitude's noise over the lever arm from
    # the DVL head, and the echoes' is their own): each pose's lever arm to the array
    # turned by its attitude, added to the navigation's positions and, differenced, to
    # the echoes' body-origin increments (the estimator was given the same attitudes)
    arm = np.asarray(lever_arms.array_m, dtype=np.float64)
    to_array = np.array([body_to_ned(p.roll_rad, p.pitch_rad, p.heading_rad) @ arm
                         for p in poses])
    pos = np.array([p.ned for p in poses], dtype=np.float64) + to_array
    inc = inc + np.diff(to_array, axis=0)
    nav_inc = np.diff(pos, axis=0)
    both = locked_steps(poses) & np.all(np.isfinite(inc), axis=1)
    bias = None
    if both.sum() >= micronav_cfg.bias_min_steps:
        bias = np.mean(inc[both] - nav_inc[both], axis=0)
        inc = inc - bias
    # the steps' own noise (the DVL's, the velocity turned by one attitude) and the
    # attitude's noise turning the lever arm as the positions' noise
    lever = array_lever_m(lever_arms)
    step_sigma = nav_increment_sigma(poses, nav_cfg, lever, lever_term=False)
    ncov = np.einsum("ki,ij->kij", np.maximum(step_sigma, 1e-9) ** 2, np.eye(3))
    t = np.array([p.time_ns for p in poses], dtype=np.float64) * 1e-9
    interval = float(np.median(np.diff(t)))
    x, fcov = fuse_increments(pos, ncov, inc, cov, micronav_cfg.anchor_sigma_m,
                              micronav_cfg.acceleration_sigma_m_s2 * interval ** 2,
                              position_noise=attitude_position_noise(poses, nav_cfg, lever),
                              step_covariance=False)
    x = x - to_array                                     # back to the body origin
    fused = [dataclasses.replace(p, north_m=float(q[0]), east_m=float(q[1]),
                                 down_m=float(q[2]),
                                 altitude_m=float(p.altitude_m + p.down_m - q[2]))
             for p, q in zip(poses, x)]
    return fused, fcov, bias


def fuse_with_navigation(pings: Iterable, poses: Sequence[NavSnapshot], hardware,
                         processing, nav_cfg, micronav_cfg, **options) -> MicronavResult:
    """The re-navigated ``poses`` of ``pings`` fused with the echoes' increments (module
    docstring). ``nav_cfg``: the navigation configuration the poses were made with;
    ``micronav_cfg``: :class:`~svss_daq.config.MicronavConfig`."""
    poses = list(poses)
    sigma = nav_increment_sigma(poses, nav_cfg, array_lever_m(hardware.lever_arms))
    echoes = echo_increments(pings, poses, hardware, processing, sigma,
                             micronav_cfg.max_seed_sigma_m, **options)
    if len(poses) < 2:
        return MicronavResult(poses, echoes, sigma, np.zeros((0, 3, 3)))
    inc, cov = echoes.increments()
    fused, fcov, bias = fuse_poses(poses, inc, cov, hardware.lever_arms, nav_cfg,
                                   micronav_cfg)
    fused, filled = with_interpolated_bottom(fused)
    out = MicronavResult(fused, echoes, sigma, fcov, filled, bias)
    log.info("%d poses %s", len(fused), out.description)
    return out
