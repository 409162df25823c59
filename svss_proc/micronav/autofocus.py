"""Autofocus on prominent points: smooth cross-track and vertical corrections of the
array's track that bring the pings of strong, isolated responses back into phase
(docs/autofocus.md).

A synthetic aperture focuses a point when every ping's contribution to its voxel,
c_k = sum over channels of the weighted, remodulated echo at the voxel's delays, arrives
with the same phase. A displacement d_k of ping k's array from where the navigation put
it changes the two-way path to the point by about -(u_tx + u_rx) . d_k and so turns c_k
by a phase g_k . d_k (g_k ~ 4 pi / lambda along the look direction). The corrections are
found where the navigation is least sure and the data are sharpest:

1. For each point p (the brightest isolated responses of the image, or given) and each
   ping k that reaches it, the imaging kernel itself gives c_pk at the navigated pose and
   at poses displaced by ``PROBE_M`` cross-track and vertically: the phase slopes
   g_pk = (dphi/dy, dphi/dz) come from the same chain as the image (refraction table,
   delays, conventions), not from a model of it.
2. The corrections are piecewise linear in time between knots ``knot_s`` apart (one per
   ping by default; cross-track y and vertical z in the tile frame), a = (y_j, z_j).
   They maximise the sharpness J(a) = sum_p |sum_k c_pk exp(j g_pk . d_k(a))|^2 / E_p
   (E_p = sum_k |c_pk|^2, so that each point counts alike, at most 1) less two
   penalties, each about one point's sharpness when the corrections are as rough
   (second differences between knots, ``rough_m``) and as large (``prior_m``) as
   expected: what the points cannot tell apart (cross-track against vertical under a
   near-vertical look) stays near the navigation. L-BFGS with the analytic gradient,
   from one knot over the whole span to the requested spacing, halving it (coarse to
   fine, past the phase wraps a direct fine solve stops at).
3. **Guard.** The points are imaged again with the corrected poses (the kernel, not the
   phase model), each point's peak the largest magnitude within ``peak_search_m`` of it
   (the points are moved to their peaks before the fit: the value at a fixed voxel
   beside a peak grows when the response is only moved onto it, and the guard would
   take a shifted image for a focused one); the corrections are kept only if every
   point's peak is no lower than
   ``1 - guard`` of its level with the navigated poses and the sum of the points' peak
   powers has grown; where given, every held-out point (responses not used in the fit)
   keeps ``1 - holdout_guard`` of its peak and their summed power does not fall; and
   the image's sharpness below the interface over the points' span (the region the
   corrections move) does not fall. Otherwise the navigation is kept and the result
   says why.

The points (:func:`isolated_points`) must be isolated responses: a local maximum below
the interface's clearance whose peak stands ``min_contrast_db`` over the median of the
image around it and ``min_isolation_db`` over the brightest voxel of that box outside
its own main lobe. On a seabed the brightest voxels are the interface and the volume's
speckle, whose neighbours are as bright; focusing on them made the image worse
(docs/autofocus.md; benchmarks/RESULTS.md, 2026-11-27, "Autofocus"). Where no response qualifies, :func:`autofocus_image` refuses
and says why. Settings: ``[autofocus]`` of the processing configuration
(:class:`~svss_daq.config.AutofocusConfig`; config/processing.toml's where it has none).

Along-track errors and rotations are not estimated (the points constrain them weakly and
the navigation's along-track is good to millimetres over an aperture); the corrections
are meant for the vertical and cross-track wander of a noisy or missing DVL.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from svss_daq.frames import TrackLine
from svss_daq.ping import Ping

from ..imaging.sampler import PointSampler as _Sampler

log = logging.getLogger(__name__)

#: displacement used for the phase slopes (m): small against a wavelength (5.5 cm)
PROBE_M = 1e-3
#: what corrections as large (``prior_m``) and as rough (``rough_m``) as expected cost,
#: in sharpness (each point's is at most 1)
PRIOR_WEIGHT = 1.0
ROUGH_WEIGHT = 1.0

__all__ = ["AutofocusResult", "PointPick", "accept", "autofocus", "autofocus_image",
           "autofocus_settings", "bright_points", "image_sharpness", "isolated_points",
           "point_contributions", "shifted"]


def autofocus_settings(processing=None):
    """The ``[autofocus]`` settings of ``processing`` (a
    :class:`~svss_daq.config.ProcessingConfig`), else config/processing.toml's."""
    cfg = getattr(processing, "autofocus", None)
    if cfg is not None:
        return cfg
    from svss_daq.config import ProcessingConfig, config_path, load_with_text
    path = config_path("processing.toml")
    cfg = load_with_text(ProcessingConfig, path).value.autofocus
    if cfg is None:
        from svss_daq.config import ConfigError
        raise ConfigError(f"{path}: no [autofocus] table (the autofocus's settings)")
    return cfg


@dataclass(frozen=True)
class AutofocusResult:
    """What :func:`autofocus` found: the corrected pings (the input pings when it
    refused), the corrections per ping (m, tile frame: cross-track, down), the points'
    peak levels before and after (linear, same points), and whether it kept them."""
    pings: list
    cross_m: np.ndarray
    down_m: np.ndarray
    before: np.ndarray
    after: np.ndarray
    kept: bool
    reason: str
    #: the held-out points' peaks before and after (linear; empty without any)
    holdout_before: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    holdout_after: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    #: the image's sharpness below the interface over the points' span (None: not judged)
    sharpness_before: float | None = None
    sharpness_after: float | None = None

    @property
    def gain_db(self) -> np.ndarray:
        """Per point, the peak's change (dB) of the corrected poses over the navigated."""
        return 20 * np.log10(np.maximum(self.after, 1e-300) / np.maximum(self.before, 1e-300))


def shifted(ping: Ping, line: TrackLine, cross_m: float, down_m: float) -> Ping:
    """``ping`` with its body origin moved ``cross_m`` across the track line and
    ``down_m`` down (its altitude above the seabed less by as much: the array moved, the
    seabed did not)."""
    nav = ping.nav
    ch, sh = math.cos(line.heading), math.sin(line.heading)
    return dataclasses.replace(ping, nav=dataclasses.replace(
        nav, north_m=nav.north_m - cross_m * sh, east_m=nav.east_m + cross_m * ch,
        down_m=nav.down_m + down_m, altitude_m=nav.altitude_m - down_m))


def point_contributions(sampler: _Sampler, pings: list, points: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For every point (rows) and ping (columns): the contribution c at the navigated
    pose and its phase slopes (rad/m) for a cross-track and a vertical displacement
    (zero where the ping does not reach the point)."""
    n_p, n_k = len(points), len(pings)
    c = np.zeros((n_p, n_k), dtype=np.complex128)
    gy = np.zeros((n_p, n_k))
    gz = np.zeros((n_p, n_k))
    for k, p in enumerate(pings):
        x0, reach = sampler.reach(p)
        near = [i for i, pt in enumerate(points) if abs(pt[0] - x0) <= reach]
        if not near:
            continue
        py = shifted(p, sampler.line, PROBE_M, 0.0)
        pz = shifted(p, sampler.line, 0.0, PROBE_M)
        for i in near:
            v0 = sampler.value(p, points[i])
            if v0 == 0:
                continue
            c[i, k] = v0
            gy[i, k] = np.angle(sampler.value(py, points[i]) / v0) / PROBE_M
            gz[i, k] = np.angle(sampler.value(pz, points[i]) / v0) / PROBE_M
    return c, gy, gz


def _hat_basis(t: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """(len(t), len(knots)) piecewise-linear interpolation weights of ``t`` between the
    ``knots`` (constant beyond the ends)."""
    b = np.zeros((t.size, knots.size))
    if knots.size == 1:
        b[:, 0] = 1.0
        return b
    j = np.clip(np.searchsorted(knots, t, side="right") - 1, 0, knots.size - 2)
    w = np.clip((t - knots[j]) / (knots[j + 1] - knots[j]), 0.0, 1.0)
    rows = np.arange(t.size)
    b[rows, j] = 1.0 - w
    b[rows, j + 1] += w
    return b


def _solve(c, gy, gz, basis, rough_m, prior_m, start):
    """Knot values (y_j then z_j) maximising the phase-model sharpness from ``start``;
    ``rough_m`` and ``prior_m``: the (cross, down) expected rms second difference of the
    corrections between knots and their expected rms size (m)."""
    weight = 1.0 / np.maximum((np.abs(c) ** 2).sum(axis=1), 1e-300)      # per point
    nk = basis.shape[1]
    d2 = np.diff(np.eye(nk), 2, axis=0) if nk > 2 else np.zeros((0, nk))
    # roughness, and a pull toward the navigation (what the points cannot tell apart,
    # e.g. cross-track against vertical under a near-vertical look, stays put): each
    # costs about one point's sharpness when the corrections are as rough and as large
    # as expected
    pen = [ROUGH_WEIGHT / nk * (d2.T @ d2) / rough_m[i] ** 2
           + PRIOR_WEIGHT / nk * np.eye(nk) / prior_m[i] ** 2 for i in (0, 1)]

    def cost(a):
        y, z = basis @ a[:nk], basis @ a[nk:]
        e = c * np.exp(1j * (gy * y + gz * z))
        s = e.sum(axis=1)
        j = float((weight * np.abs(s) ** 2).sum())
        # dJ/dd_k = sum_p w_p 2 Re(conj(s_p) j g_pk e_pk)
        common = weight[:, None] * 2 * np.real(np.conj(s)[:, None] * 1j * e)
        grad_y = basis.T @ (common * gy).sum(axis=0)
        grad_z = basis.T @ (common * gz).sum(axis=0)
        pen_y, pen_z = a[:nk] @ pen[0] @ a[:nk], a[nk:] @ pen[1] @ a[nk:]
        f = -j + pen_y + pen_z
        g = np.concatenate([-grad_y + 2 * pen[0] @ a[:nk], -grad_z + 2 * pen[1] @ a[nk:]])
        return f, g

    def scaled(u):                   # in millimetres: a well-scaled problem for L-BFGS
        f, g = cost(u * 1e-3)
        return f, g * 1e-3

    res = minimize(scaled, np.asarray(start) * 1e3, jac=True, method="L-BFGS-B",
                   options={"maxiter": 2000})
    return res.x * 1e-3


def bright_points(tiles: list, n: int, *, min_separation_m: float = 0.5,
                  min_contrast_db: float = 20.0) -> np.ndarray:
    """Up to ``n`` of the brightest voxels of the tiles (tile frame: along, cross,
    depth) at least ``min_separation_m`` apart and ``min_contrast_db`` above the
    median magnitude of their tile: the strong, isolated responses to focus on."""
    cands = []
    for t in tiles:
        mag = np.abs(t.image)
        floor = float(np.median(mag[mag > 0])) if np.any(mag > 0) else 0.0
        flat = np.argsort(mag, axis=None)[::-1][:2000]
        for f in flat:
            ia, ic, iz = np.unravel_index(int(f), mag.shape)
            level = float(mag[ia, ic, iz])
            if floor <= 0 or 20 * math.log10(level / floor) < min_contrast_db:
                break
            cands.append((level, np.array([t.grid.along[ia], t.grid.cross[ic],
                                           t.grid.depth[iz]])))
    cands.sort(key=lambda c: -c[0])
    chosen: list[np.ndarray] = []
    for _, pos in cands:
        if all(np.linalg.norm(pos - q) >= min_separation_m for q in chosen):
            chosen.append(pos)
        if len(chosen) == n:
            break
    return np.array(chosen).reshape(-1, 3)


@dataclass(frozen=True)
class PointPick:
    """What :func:`isolated_points` found: the points (tile frame: along, cross, depth),
    their peak magnitude, contrast over the local background and isolation from their
    neighbours (dB); how many local maxima were examined and why the others were not
    taken; ``refused``: why there is none (None where there are)."""
    points: np.ndarray
    levels: np.ndarray
    contrast_db: np.ndarray
    isolation_db: np.ndarray
    examined: int
    rejected: dict
    refused: str | None


def _box(n: int, i: int, half: int) -> slice:
    return slice(max(0, i - half), min(n, i + half + 1))


def isolated_points(tiles: list, settings, n: int | None = None) -> PointPick:
    """Up to ``n`` (``settings.points``) isolated responses of the tiles' images
    (``settings``: :class:`~svss_daq.config.AutofocusConfig`; module docstring): of the
    ``candidates`` brightest local maxima at least ``interface_clearance_m`` below the
    interface and off the tiles' faces, those whose peak stands ``min_contrast_db`` over
    the median magnitude of the box ``background_m`` about them (their main lobe,
    ``core_m``, left out) and ``min_isolation_db`` over the brightest voxel of that box
    outside the lobe, brightest first, ``min_separation_m`` apart."""
    from scipy.ndimage import maximum_filter
    n = settings.points if n is None else n
    cands = []
    mags = [np.abs(t.image) for t in tiles]
    for ti, t in enumerate(tiles):
        mag = mags[ti]
        g = t.grid
        voxel = float(abs(g.along[1] - g.along[0])) if g.along.size > 1 else 1.0
        deep = np.asarray(g.depth) >= settings.interface_clearance_m
        peak = (mag == maximum_filter(mag, size=3, mode="constant")) & (mag > 0)
        peak &= deep[None, None, :]
        for ax in range(3):                   # a face's maximum may be a lobe's flank
            idx = [slice(None)] * 3
            idx[ax] = [0, -1]
            peak[tuple(idx)] = False
        flat = np.flatnonzero(peak)
        if flat.size > settings.candidates:
            flat = flat[np.argpartition(mag.reshape(-1)[flat], -settings.candidates)
                        [-settings.candidates:]]
        for f in flat:
            cands.append((float(mag.reshape(-1)[f]), ti, np.unravel_index(int(f), mag.shape),
                          voxel))
    cands.sort(key=lambda c: -c[0])
    cands = cands[:settings.candidates]
    rejected = {"low contrast": 0, "a neighbour as bright": 0, "too near a pick": 0}
    chosen, levels, contrast, isolation = [], [], [], []
    best = (-np.inf, -np.inf)
    for level, ti, (ia, ic, iz), voxel in cands:
        t = tiles[ti]
        mag = mags[ti]
        hb = [max(1, int(round(h / voxel))) for h in settings.background_m]
        hc = [max(1, int(round(h / voxel))) for h in settings.core_m]
        sl = tuple(_box(mag.shape[a], i, hb[a]) for a, i in enumerate((ia, ic, iz)))
        sub = mag[sl]
        core = np.zeros(sub.shape, dtype=bool)
        core[tuple(slice(max(0, i - s_.start - hc[a]), i - s_.start + hc[a] + 1)
                   for a, (i, s_) in enumerate(zip((ia, ic, iz), sl)))] = True
        ring = sub[~core]
        ring = ring[ring > 0]
        if ring.size == 0:
            rejected["low contrast"] += 1
            continue
        c_db = 20 * math.log10(level / max(float(np.median(ring)), 1e-300))
        i_db = 20 * math.log10(level / max(float(ring.max()), 1e-300))
        best = max(best, (c_db, i_db))
        if c_db < settings.min_contrast_db:
            rejected["low contrast"] += 1
            continue
        if i_db < settings.min_isolation_db:
            rejected["a neighbour as bright"] += 1
            continue
        pos = np.array([t.grid.along[ia], t.grid.cross[ic], t.grid.depth[iz]], dtype=float)
        if any(np.linalg.norm(pos - q) < settings.min_separation_m for q in chosen):
            rejected["too near a pick"] += 1
            continue
        chosen.append(pos)
        levels.append(level)
        contrast.append(c_db)
        isolation.append(i_db)
        if len(chosen) == n:
            break
    refused = None
    if not chosen:
        if not cands:
            refused = ("no isolated response: no local maximum of the image "
                       f"{settings.interface_clearance_m:g} m or more below the interface")
        else:
            refused = (f"no isolated response: of {len(cands)} local maxima "
                       f"{settings.interface_clearance_m:g} m or more below the interface, "
                       f"{rejected['low contrast']} stand less than "
                       f"{settings.min_contrast_db:g} dB over their local background and "
                       f"{rejected['a neighbour as bright']} have a neighbour within "
                       f"{settings.min_isolation_db:g} dB (the best: {best[0]:.1f} dB over "
                       f"the background, {best[1]:.1f} dB over its neighbours)")
    return PointPick(np.array(chosen, dtype=float).reshape(-1, 3), np.array(levels),
                     np.array(contrast), np.array(isolation), len(cands), rejected, refused)


def image_sharpness(image: np.ndarray) -> float:
    """The mean of |I|^4 over the voxels some ping reached: the image's sharpness, which
    grows where the same energy gathers into fewer voxels (a focused response) and falls
    where it spreads. Not normalised by the image's energy squared: moving the pings
    changes that energy by a few per cent (the interface's tail, the sidelobes), and
    the normalised measure fell by 3 % on a correction that raised every point's peak
    (benchmarks/RESULTS.md, 2026-11-27, "Autofocus: on a seabed")."""
    p = np.abs(image[image != 0]).astype(np.float64) ** 2
    if p.size == 0:
        return 0.0
    return float(np.mean(p ** 2))


def sharpness_region(processing, points: np.ndarray, settings):
    """The grid (along, cross, depth axes, tile frame) over which the image's sharpness
    is judged: the points' along-track span and ``region_margin_m``, the tile's width,
    from ``interface_clearance_m`` below the interface to the tile's bottom, at the
    tile's voxel."""
    tile = processing.tile
    v = tile.voxel_m
    a0 = float(points[:, 0].min()) - settings.region_margin_m
    a1 = float(points[:, 0].max()) + settings.region_margin_m
    along = a0 + v * np.arange(int(round((a1 - a0) / v)) + 1)
    cross = -tile.width_m / 2 + v * (np.arange(int(round(tile.width_m / v))) + 0.5)
    top = max(tile.top_m, settings.interface_clearance_m)
    depth = top + v * (np.arange(int(round((tile.top_m + tile.depth_m - top) / v))) + 0.5)
    return along, cross, depth


def accept(before: np.ndarray, after: np.ndarray, guard: float) -> tuple[bool, str]:
    """The guard: corrections that leave every point's peak at ``1 - guard`` of its
    level or more and raise the points' summed peak power are kept; the reason."""
    worst = float(np.min(after / np.maximum(before, 1e-300)))
    if worst < 1 - guard:
        return False, f"a point's peak fell to {worst:.3f} of its level"
    if float((after ** 2).sum()) <= float((before ** 2).sum()):
        return False, "the points' peak power did not grow"
    return True, "sharper"


def peak_levels(sampler: _Sampler, pings: list, points: np.ndarray, settings
                ) -> tuple[np.ndarray, np.ndarray]:
    """Each point's response peak: the largest magnitude of the image of ``pings`` within
    ``peak_search_m`` of it on a ``peak_step_m`` grid (the kernel, as the tiles image it);
    (positions (n, 3), levels (n,))."""
    h, st = settings.peak_search_m, settings.peak_step_m
    offs = st * np.arange(-int(round(h / st)), int(round(h / st)) + 1)
    pos = np.zeros((len(points), 3))
    lev = np.zeros(len(points))
    for i, p in enumerate(points):
        axes = [p[a] + offs for a in range(3)]
        mag = np.abs(sampler.grid(pings, *axes))
        k = np.unravel_index(int(np.argmax(mag)), mag.shape)
        pos[i] = [axes[a][k[a]] for a in range(3)]
        lev[i] = float(mag[k])
    return pos, lev


def accept_holdout(before: np.ndarray, after: np.ndarray, guard: float) -> tuple[bool, str]:
    """The held-out points' guard: each keeps ``1 - guard`` of its peak or more and
    their summed peak power does not fall; the reason."""
    if not len(before):
        return True, "sharper"
    worst = float(np.min(after / np.maximum(before, 1e-300)))
    if worst < 1 - guard:
        return False, f"a held-out point's peak fell to {worst:.3f} of its level"
    if float((after ** 2).sum()) < float((before ** 2).sum()):
        return False, "the held-out points' peak power fell"
    return True, "sharper"


def autofocus(accumulator, processing, line: TrackLine, pings: list, points: np.ndarray,
              *, holdout: np.ndarray | None = None, settings=None, knot_s: float = 0.1,
              rough_m: tuple = (0.002, 0.005), prior_m: tuple = (0.01, 0.03),
              guard: float | None = None, judge_image: bool = True, outer: int = 1
              ) -> AutofocusResult:
    """Corrections of ``pings``' cross-track and vertical positions (module docstring)
    that focus ``points`` (tile frame of ``line``: along, cross, depth; e.g. from
    :func:`isolated_points`), with ``accumulator`` (a
    :class:`~svss_proc.imaging.imager.PingAccumulator`) and ``processing`` as they image
    the tiles. Knots every ``knot_s`` seconds of ping time. The guard (module docstring,
    3): ``guard`` (default ``settings.point_guard``) on the points, ``holdout`` points
    (not fitted) and, with ``judge_image``, the image's sharpness below the interface;
    ``settings``: :class:`~svss_daq.config.AutofocusConfig` (default
    :func:`autofocus_settings` of ``processing``)."""
    settings = settings if settings is not None else autofocus_settings(processing)
    guard = settings.point_guard if guard is None else guard
    holdout = (np.zeros((0, 3)) if holdout is None
               else np.asarray(holdout, dtype=np.float64).reshape(-1, 3))
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = len(pings)
    zero = np.zeros(n)
    if not len(points) or n < 3:
        return AutofocusResult(list(pings), zero, zero, np.zeros(len(points)),
                               np.zeros(len(points)), False,
                               "no point to focus on" if not len(points) else
                               "fewer than 3 pings")
    sampler = _Sampler(accumulator, processing, line)
    c, gy, gz = point_contributions(sampler, pings, points)
    seen = (c != 0).sum(axis=1)
    if np.all(seen >= 3):
        # each point moved to its response's peak: a value at a fixed voxel off the
        # peak grows when the response is only moved onto it, not focused
        points, before = peak_levels(sampler, pings, points, settings)
        c, gy, gz = point_contributions(sampler, pings, points)
    else:
        before = np.abs(c.sum(axis=1))
    if np.any(seen < 3):
        return AutofocusResult(list(pings), zero, zero, before, before, False,
                               f"points {np.flatnonzero(seen < 3).tolist()} are reached by "
                               f"fewer than 3 pings")
    t = np.array([p.nav.time_ns for p in pings], dtype=np.float64) * 1e-9
    t = t - t[0]
    span = max(float(t[-1]), 1e-9)
    dy, dz = zero.copy(), zero.copy()
    moved = list(pings)
    for _ in range(outer):          # the phase model linearised again at each solution
        a = None
        basis = None
        spacing = span
        while True:                              # coarse to fine: knots twice as dense
            knots = np.linspace(0.0, span, max(2, int(round(span / spacing)) + 1))
            new = _hat_basis(t, knots)
            if a is None:
                start = np.zeros(2 * knots.size)
            else:                                # the coarse solution on the new knots
                y, z = basis @ a[:basis.shape[1]], basis @ a[basis.shape[1]:]
                fit = np.linalg.lstsq(new, np.column_stack([y, z]), rcond=None)[0]
                start = np.concatenate([fit[:, 0], fit[:, 1]])
            basis = new
            a = _solve(c, gy, gz, basis, rough_m, prior_m, start)
            if spacing <= knot_s * 1.001:
                break
            spacing = max(spacing / 2, knot_s)
        nk = basis.shape[1]
        dy, dz = dy + basis @ a[:nk], dz + basis @ a[nk:]
        moved = [shifted(p, line, float(y), float(z)) for p, y, z in zip(pings, dy, dz)]
        c, gy, gz = point_contributions(sampler, moved, points)
    after = peak_levels(sampler, moved, points, settings)[1]
    kept, why = accept(before, after, guard)
    # the held-out points: reached by 3 pings or more, their peaks before and after
    hb = ha = np.zeros(0)
    if len(holdout):
        h0 = point_contributions(sampler, pings, holdout)[0]
        reached = (h0 != 0).sum(axis=1) >= 3
        hb = peak_levels(sampler, pings, holdout[reached], settings)[1]
        ha = peak_levels(sampler, moved, holdout[reached], settings)[1]
        ok, why_h = accept_holdout(hb, ha, settings.holdout_guard)
        if kept and not ok:
            kept, why = False, why_h
    s0 = s1 = None
    if judge_image:
        region = sharpness_region(processing, np.concatenate([points, holdout]), settings)
        s0 = image_sharpness(sampler.grid(list(pings), *region))
        s1 = image_sharpness(sampler.grid(moved, *region))
        if kept and s1 < s0 * (1 - settings.sharpness_tolerance):
            kept, why = False, (f"the image below the interface got less sharp (mean "
                                f"|I|^4 {s1 / s0:.3f} of its level)")
    extra = dict(holdout_before=hb, holdout_after=ha, sharpness_before=s0,
                 sharpness_after=s1)
    if kept:
        log.info("autofocus: %d points, peaks %+.2f dB (mean), corrections rms %.1f mm "
                 "cross, %.1f mm down", len(points),
                 float(np.mean(20 * np.log10(after / before))),
                 1e3 * float(np.sqrt(np.mean(dy ** 2))), 1e3 * float(np.sqrt(np.mean(dz ** 2))))
        return AutofocusResult(moved, dy, dz, before, after, True, "sharper", **extra)
    log.info("autofocus: corrections refused (%s); the navigation is kept", why)
    return AutofocusResult(list(pings), zero, zero, before, after, False, why, **extra)


def autofocus_image(accumulator, processing, line: TrackLine, pings: list, tiles: list,
                    settings=None, **options) -> tuple[AutofocusResult, PointPick]:
    """The autofocus of ``tiles`` (the image of ``pings``) on its isolated responses
    (:func:`isolated_points`): every third held out of the fit to judge it where there
    are ``holdout_min_points`` or more; refused, with the reason, where there is none.
    ``options``: of :func:`autofocus`."""
    settings = settings if settings is not None else autofocus_settings(processing)
    pick = isolated_points(tiles, settings)
    if pick.refused is not None:
        zero = np.zeros(len(pings))
        log.info("autofocus: refused (%s); the navigation is kept", pick.refused)
        return AutofocusResult(list(pings), zero, zero, np.zeros(0), np.zeros(0), False,
                               pick.refused), pick
    pts = pick.points
    held = np.zeros(len(pts), dtype=bool)
    if len(pts) >= settings.holdout_min_points:
        held[1::3] = True
    res = autofocus(accumulator, processing, line, pings, pts[~held], holdout=pts[held],
                    settings=settings, **options)
    return res, pick
