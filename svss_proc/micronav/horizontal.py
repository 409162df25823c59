"""Ping-to-ping displacement (surge, sway and heave) from the two pings' common phase
centres, focused on the seabed in several directions (docs/phase_centres.md,
"Horizontal increments").

Why focusing: with the configured projector order at 1 m/s no phase centre of one ping
lies within lambda/4 of one of the next ping's (:mod:`.phase_centres`), and the echoes of
single near pairs cannot show a horizontal displacement: near nadir their coherence
hardly falls with the pairs' distance (measured 0.96-0.99 at 2.5-5 cm on the simulated
sand: the near-normal return dominates), and the nadir phase sees heave only. A
horizontal displacement shows as a phase only where the echo comes from off nadir, and
only once the ring of the interface heard at one time is resolved in azimuth. So:

1. **Common sub-aperture.** The channels of ping a and of ping b whose phase centres
   (b's placed by the navigation) lie within ``tolerance_m`` of each other, all offset
   by the same vector delta (:func:`translated_pairs`): b's sub-aperture is a's
   translated, so both hear nearly the same seabed speckle (the principle of redundant
   phase centres, with the pairs' mismatch carried by the whole sub-aperture instead
   of required to vanish).
2. **Focus.** Each sub-aperture is focused, with the exact bistatic paths of its own
   elements, on points P of the seabed plane (no excess approximation is needed):

       v(P) = sum_i bb_i(tau_i(P)) exp(+j 2 pi f_c tau_i(P)),
       tau_i(P) = (|P - t| + |P - r_i|) / c

   (:mod:`svss_daq.conventions`), b's elements at the navigation's pose. The points lie
   in nine patches: about nadir and about the points ``patch_angle`` off nadir in eight
   directions (:func:`seabed_patches`).
3. **Phase.** If b's array was in truth displaced by Delta from where the navigation put
   it, its paths to P are shorter by 2 u.Delta (u the unit vector from the array to P),
   and its focused value turns by 2 k u.Delta (k = 2 pi f_c / c). Per patch m:

       C_m = sum_P v_a(P) conj(v_b(P)),    arg C_m = -2 k u_m . Delta,

   u_m the patch's power-weighted mean direction; unambiguous while |2 k u_m.Delta| < pi
   (about 13 mm vertically, 5 cm horizontally at 15 degrees).
4. **Fit.** Weighted least squares of the patches' phases for Delta (3,), weights from
   each patch's coherence gamma_m over its N_m looks (Cramer-Rao: var(phi) =
   (1 - gamma^2) / (2 N gamma^2)), the covariance scaled by the reduced chi-square where
   above 1 and by ``SCATTER_FACTOR`` squared (measured). The displacement is the
   navigation's plus Delta. Two passes (b re-placed where the first found it) and two
   translations interpolated to zero offset (:func:`estimate_displacement`).

Where it refuses (``DisplacementEstimate.refused`` says why): the phase centres do not
overlap (fewer than ``min_pairs`` pairs sharing a translation within ``tolerance_m``;
for example consecutive pings across the projector sequence's wrap, 5 -> 0, whose phase
centres are 57 cm apart across against the array's 50 cm), there is no coherent seabed
return at nadir (``min_nadir_coherence``), the nadir return is not a seabed's layer (a
point's echo or noise: :func:`seabed_layer`), or too few patches cohere above
``min_coherence`` (the echoes decorrelated).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from svss_daq.geometry import ArrayGeometry

from .patch_focus import SubAperture, focus, ping_taps
from .phase_centres import PhaseCentrePairs, near_pairs, phase_centres
from .rpc import shifted_samples

__all__ = ["DisplacementEstimate", "Patch", "TapCache", "displacement_pass",
           "estimate_displacement", "focus_points", "layer_offsets", "phase_gradient",
           "seabed_layer", "seabed_patches", "translated_pairs"]

#: the measured scatter of the estimates over their Cramer-Rao sigma (simulated sand, seed
#: scene, configured order at 1 m/s, 50 ping pairs at pings 40-70 and 70-100 of
#: development runs described in docs/phase_centres.md ("The σ's calibration"): rms(error / sigma) 1.4-1.9
#: horizontally, 1.0-1.5 vertically): the looks of a patch are not independent (the two
#: sub-apertures share the speckle) and the offset bias is not in the bound. The
#: covariance is multiplied by its square.
SCATTER_FACTOR = 1.7

PATCH_NAMES = ("nadir", "ahead", "astern", "starboard", "port", "ahead-starboard",
               "ahead-port", "astern-starboard", "astern-port")
#: the patches' horizontal directions (forward, starboard), unit or zero
PATCH_DIRECTIONS = ((0.0, 0.0), (1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0),
                    (0.5 ** 0.5, 0.5 ** 0.5), (0.5 ** 0.5, -0.5 ** 0.5),
                    (-0.5 ** 0.5, 0.5 ** 0.5), (-0.5 ** 0.5, -0.5 ** 0.5))


#: the seabed layer test (:func:`seabed_layer`): ping a's nadir patch focused at depth
#: offsets from the navigation's seabed within +-LAYER_WINDOW_M, every LAYER_STEP_M (the
#: 15 kHz chirp resolves 5 cm in range); its strongest return must lie within
#: LAYER_TOLERANCE_M of the seabed (the navigation's altitude error) and stand
#: LAYER_CONTRAST_DB over the mean of the water column LAYER_TOLERANCE_M and more above
#: it. Measured on the simulated sand (seed scene, interface and volume): the return peaks
#: at the seabed and the water 10-20 cm above is 20-60 dB below it. The demo scene (points
#: in water, no seabed): noise within +-5 dB over the window, or a point below nadir
#: whose return keeps growing with depth (each passed the nadir coherence test and gave
#: increments 10-27 mm wrong with a stated 3-6 mm).
LAYER_WINDOW_M = 0.20
LAYER_STEP_M = 0.05
LAYER_TOLERANCE_M = 0.10
LAYER_CONTRAST_DB = 10.0


def layer_offsets(window_m: float = LAYER_WINDOW_M, step_m: float = LAYER_STEP_M
                  ) -> np.ndarray:
    """The depth offsets from the seabed (m, down positive) :func:`seabed_layer` looks at."""
    n = int(round(window_m / step_m))
    return step_m * np.arange(-n, n + 1, dtype=np.float64)


def seabed_layer(offsets_m: np.ndarray, power: np.ndarray,
                 tolerance_m: float = LAYER_TOLERANCE_M,
                 contrast_db: float = LAYER_CONTRAST_DB) -> str | None:
    """None where the nadir patch's mean focused power ``power`` at depth ``offsets_m``
    (from the navigation's seabed, down positive) is a seabed's: its strongest return
    within ``tolerance_m`` of the seabed, ``contrast_db`` over the mean power of the
    water ``tolerance_m`` and more above it. Otherwise why not (a refusal's reason)."""
    d = np.asarray(offsets_m, dtype=np.float64)
    p = np.asarray(power, dtype=np.float64)
    top = int(np.argmax(p))
    head = "no seabed layer under the array: "
    if not abs(d[top]) <= tolerance_m + 1e-9:
        return (head + f"the nadir return is strongest {d[top]:+.2f} m from the "
                f"navigation's seabed (within {tolerance_m:g} m needed: a point's echo "
                "or the sediment, not the interface)")
    water = p[d <= d[top] - tolerance_m + 1e-9]
    level = 10.0 * math.log10(max(float(p[top]), 1e-300) / max(float(water.mean()), 1e-300))
    if not level >= contrast_db:
        return (head + f"the nadir return stands {level:.1f} dB over the water "
                f"{tolerance_m:g} m and more above it ({contrast_db:g} dB needed)")
    return None


def focus_points(bb: np.ndarray, t0_s: float, dt_s: float, center_hz: float,
                 sound_speed_m_s: float, tx: np.ndarray, rx: np.ndarray,
                 points: np.ndarray, weights=None) -> np.ndarray:
    """The sub-aperture's focused value at each point (m,): sum over channels of the
    baseband ``bb`` (n_ch, n) linearly interpolated at tau = (|P - tx| + |P - rx|) / c
    and turned by exp(+j 2 pi f_c tau). ``tx`` (3,), ``rx`` (n_ch, 3), ``points`` (m, 3),
    one frame, m; samples at t0 + k dt. ``weights``: per channel (n_ch,), None for ones,
    or "channels" for the channels' terms unsummed (n_ch, m)."""
    p = np.asarray(points, dtype=np.float64)
    tau = (np.linalg.norm(p - tx, axis=1)[None, :]
           + np.linalg.norm(p[None, :, :] - rx[:, None, :], axis=2)) / sound_speed_m_s
    s = shifted_samples(bb, t0_s, dt_s, tau) * np.exp(2j * math.pi * center_hz * tau)
    if isinstance(weights, str):
        if weights != "channels":
            raise ValueError(f"weights {weights!r}: expected per-channel numbers, None or "
                             "'channels'")
        return s
    w = np.ones(bb.shape[0]) if weights is None else np.asarray(weights, dtype=np.float64)
    return w @ s


def phase_gradient(contrib: np.ndarray, centres: np.ndarray, reach_m: float) -> np.ndarray:
    """The slope g (2,) rad/m of the phase of the channels' focused contributions across
    the aperture (``contrib`` (n_ch, m): each channel's term of the focused values at m
    points; ``centres`` (n_ch, 2) its phase centre): arg sum_P s_i conj(s_i') = g .
    (c_i - c_i') fitted over the neighbours closer than ``reach_m``, weighted by their
    coherent power. Focused on P, the channels' terms are in phase for an echo from P;
    an echo from u off the focus turns them by 2 k (u - u_P) . c: g measures where the
    focused power comes from."""
    r = contrib @ np.conj(contrib.T)
    dc = centres[:, None, :] - centres[None, :, :]
    i, j = np.nonzero(np.triu(np.hypot(dc[..., 0], dc[..., 1]) <= reach_m, 1))
    w = np.abs(r[i, j])
    a = dc[i, j]
    aw = a * w[:, None]
    return np.linalg.lstsq(a.T @ aw, aw.T @ np.angle(r[i, j]), rcond=None)[0]


def translated_pairs(geometry: ArrayGeometry, projector_a: int, projector_b: int,
                     displacement_m, rotation_ba, tolerance_m: float,
                     rank: int = 0) -> PhaseCentrePairs:
    """Channels of a and b whose phase centres (b's turned by ``rotation_ba`` and moved by
    ``displacement_m``, a's body frame) are within ``tolerance_m`` horizontally and all
    offset by the same vector: of the candidate offsets (rounded to 1 mm) the one most
    pairs share, the nearer on a tie (``rank`` 0; 1 the next, ...). So b's sub-aperture
    is a's translated, not a mixture of neighbours on either side (the grids are offset
    by about half a spacing across at a one-projector step: nearest-first pairing takes
    both sides). No pairs where there is no such translation."""
    d = np.asarray(displacement_m, dtype=np.float64).reshape(3)
    pa = phase_centres(geometry, projector_a)
    pb = phase_centres(geometry, projector_b) @ np.asarray(rotation_ba).T + d
    ia, ib = near_pairs(pa, pb, tolerance_m)
    rx = geometry.receivers
    if ia.size == 0:
        z = np.zeros((0, 3))
        return PhaseCentrePairs(ia, ib, z, z, z)
    diff = pb[ib] - pa[ia]
    key = np.round(diff[:, :2] * 1e3).astype(np.int64)
    # one integer per offset, ordered as the offsets (x, then y): a 1-D unique is
    # several times faster than np.unique(axis=0) and gives the same ranking
    span = int(np.abs(key).max()) + 1
    code = (key[:, 0] + span) * (2 * span + 1) + (key[:, 1] + span)
    ucode, inv, count = np.unique(code, return_inverse=True, return_counts=True)
    uniq = np.column_stack([ucode // (2 * span + 1) - span, ucode % (2 * span + 1) - span])
    ranked = sorted(range(len(uniq)), key=lambda k: (-count[k], float(np.hypot(*uniq[k]))))
    if rank >= len(ranked):
        z = np.zeros((0, 3))
        e = np.zeros(0, dtype=np.int64)
        return PhaseCentrePairs(e, e, z, z, z)
    keep = np.flatnonzero(inv.ravel() == ranked[rank])
    ia, ib = ia[keep], ib[keep]
    return PhaseCentrePairs(ia, ib, diff[keep], rx[ia] - geometry.projectors[projector_a],
                            rx[ib] - geometry.projectors[projector_b])


@dataclass(frozen=True)
class Patch:
    """Points of the seabed (m, 3) about one look direction, and its name."""
    name: str
    points: np.ndarray


def seabed_patches(centre: np.ndarray, depth_m: float, patch_angle_rad: float,
                   half_width_m: float, spacing_m: float) -> list[Patch]:
    """Nine square patches of points on the seabed plane z = ``depth_m`` (the poses'
    local frame, z down): about the nadir of ``centre`` (3,) and about the points
    ``patch_angle_rad`` off nadir in the eight directions of ``PATCH_DIRECTIONS`` in
    that frame's x and y (north and east for NED poses: the names say ahead, starboard
    ... for a heading of 0; the estimate does not depend on it, the eight directions are
    evenly spread), each (2 half_width / spacing + 1)^2 points."""
    h = depth_m - float(centre[2])
    if not h > 0:
        raise ValueError(f"the seabed ({depth_m:.3f} m) is not below the array "
                         f"({float(centre[2]):.3f} m)")
    pts = _patch_points(centre, depth_m, h * math.tan(patch_angle_rad), half_width_m,
                        spacing_m)
    return [Patch(name, p) for name, p in zip(PATCH_NAMES, pts)]


def _patch_points(centre, depth_m: float, r: float, half_width_m: float,
                  spacing_m: float) -> np.ndarray:
    """The points of :func:`seabed_patches`, (9, m, 3), the patches ``r`` m off nadir."""
    g = np.arange(-half_width_m, half_width_m + 1e-9, spacing_m)
    gx, gy = np.meshgrid(g, g, indexing="ij")
    u = np.array(PATCH_DIRECTIONS)
    pts = np.empty((len(u), gx.size, 3))
    pts[..., 0] = (centre[0] + r * u[:, 0])[:, None] + gx.ravel()[None, :]
    pts[..., 1] = (centre[1] + r * u[:, 1])[:, None] + gy.ravel()[None, :]
    pts[..., 2] = float(depth_m)
    return pts


@dataclass(frozen=True)
class DisplacementEstimate:
    """Ping b's array displacement from ping a's, in the frame of the poses given (m):
    ``displacement_m`` (3,) the navigation's plus ``correction_m`` (3,), the latter's
    covariance ``cov_m2`` (3, 3); per patch ``coherence`` and ``phase_rad``; ``n_pairs``
    the common phase centres; ``chi2`` the fit's reduced chi-square (before scaling).
    ``refused``: None, or why there is no estimate (then the numbers are NaN)."""
    displacement_m: np.ndarray
    correction_m: np.ndarray
    cov_m2: np.ndarray
    coherence: np.ndarray
    phase_rad: np.ndarray
    n_pairs: int
    chi2: float
    refused: str | None = None
    #: b's paired phase centres minus a's, horizontally, as b was placed (2,), m
    offset_m: np.ndarray | None = None

    @property
    def sigma_m(self) -> np.ndarray:
        """Standard deviations of the three components, m."""
        return np.sqrt(np.diag(self.cov_m2))


def _refused(reason: str, n_pairs: int = 0, n_patch: int = len(PATCH_NAMES)
             ) -> DisplacementEstimate:
    nan3 = np.full(3, np.nan)
    return DisplacementEstimate(nan3, nan3, np.full((3, 3), np.nan),
                                np.full(n_patch, np.nan), np.full(n_patch, np.nan),
                                n_pairs, math.nan, reason)


def estimate_displacement(bb_a: np.ndarray, bb_b: np.ndarray, t0_s: float, dt_s: float,
                          geometry: ArrayGeometry, projector_a: int, projector_b: int,
                          rot_a: np.ndarray, origin_a: np.ndarray, rot_b: np.ndarray,
                          origin_b: np.ndarray, seabed_depth_m: float,
                          sound_speed_m_s: float, center_hz: float, *,
                          passes: int = 2, translations: int = 2,
                          **options) -> DisplacementEstimate:
    """Ping b's displacement from ping a (module docstring). The poses: ``rot_*`` (3, 3)
    body to a local frame with z down (x, y horizontal: the frame of the result),
    ``origin_*`` (3,) the body origin there; b's as the navigation has it. The seabed is
    the plane z = ``seabed_depth_m`` of that frame. ``bb_a``, ``bb_b``: the conditioned
    complex baseband (channels, n) on one sample axis (t0 + k dt, arrival time).

    ``passes``: after the first estimate b is placed where it found it and the pairing
    and focusing are done again (a navigation error of a few centimetres leaves the
    sub-apertures that far apart, and they decorrelate); the correction returned is the
    sum, its covariance the last pass's.

    ``translations``: the estimate is biased in proportion to the offset delta between
    the two sub-apertures (the power a focused patch gathers from beside its points
    turns by 2 k (u_s - u_P) . delta: measured about -0.07 mm of sway per mm of offset
    across on the simulated sand). With 2, the estimates of the two most populated
    translations (one grid offset on either side across, at a one-projector step) are
    interpolated to zero offset: x = lam x_0 + (1 - lam) x_1 with lam minimising
    |lam delta_0 + (1 - lam) delta_1| in [0, 1], covariance lam C_0 + (1 - lam) C_1 (a
    bound whatever the two estimates' correlation: they share the echoes). 1: the most
    populated translation alone. ``options``: of :func:`displacement_pass` (one
    :class:`TapCache` is shared by every pass and translation unless given)."""
    if options.get("taps") is None:
        options["taps"] = TapCache()
    ests = []
    for rank in range(max(1, int(translations))):
        est = _passes(bb_a, bb_b, t0_s, dt_s, geometry, projector_a, projector_b, rot_a,
                      origin_a, rot_b, origin_b, seabed_depth_m, sound_speed_m_s,
                      center_hz, passes, dict(options, rank=rank))
        if est.refused:
            if rank == 0:
                return est
            break
        ests.append(est)
    if len(ests) == 1:
        return ests[0]
    e0, e1 = ests[0], ests[1]
    dd = e0.offset_m - e1.offset_m
    lam = 1.0 if not dd @ dd > 0 else float(np.clip(-(e1.offset_m @ dd) / (dd @ dd), 0, 1))
    mix = lambda x0, x1: lam * x0 + (1.0 - lam) * x1          # noqa: E731
    return dataclasses.replace(
        e0, displacement_m=mix(e0.displacement_m, e1.displacement_m),
        correction_m=mix(e0.correction_m, e1.correction_m), cov_m2=mix(e0.cov_m2, e1.cov_m2),
        n_pairs=e0.n_pairs + e1.n_pairs, offset_m=mix(e0.offset_m, e1.offset_m))


def _passes(bb_a, bb_b, t0_s, dt_s, geometry, projector_a, projector_b, rot_a, origin_a,
            rot_b, origin_b, seabed_depth_m, sound_speed_m_s, center_hz, passes,
            options) -> DisplacementEstimate:
    """:func:`displacement_pass` ``passes`` times, b moved by the corrections so far."""
    ob = np.asarray(origin_b, dtype=np.float64)
    total = np.zeros(3)
    est = None
    for _ in range(max(1, int(passes))):
        est = displacement_pass(bb_a, bb_b, t0_s, dt_s, geometry, projector_a, projector_b,
                                rot_a, origin_a, rot_b, ob + total, seabed_depth_m,
                                sound_speed_m_s, center_hz, **options)
        if est.refused:
            return est
        total = total + est.correction_m
    d_nav = ob - np.asarray(origin_a, dtype=np.float64)
    return dataclasses.replace(est, displacement_m=d_nav + total, correction_m=total)


def displacement_pass(bb_a: np.ndarray, bb_b: np.ndarray, t0_s: float, dt_s: float,
                      geometry: ArrayGeometry, projector_a: int, projector_b: int,
                      rot_a: np.ndarray, origin_a: np.ndarray, rot_b: np.ndarray,
                      origin_b: np.ndarray, seabed_depth_m: float,
                      sound_speed_m_s: float, center_hz: float, *,
                      patch_angle_rad: float = math.radians(15.0),
                      half_width_m: float = 0.12, spacing_m: float = 0.03,
                      tolerance_m: float = 0.034, min_pairs: int = 16,
                      min_coherence: float = 0.3, min_patches: int = 6, rank: int = 0,
                      min_nadir_coherence: float = 0.7,
                      gradient: str = "none", kernel: str = "numba",
                      taps: "TapCache | None" = None) -> DisplacementEstimate:
    """One pass of :func:`estimate_displacement`, b placed at ``origin_b``.
    ``tolerance_m``: how far apart two phase centres may be to pair (34 mm, three
    quarters of the 45.5 mm grid: every phase centre of a grid offset by half a spacing
    both ways has a partner). Patches whose coherence is below ``min_coherence`` are left
    out; fewer than ``min_patches`` left, or none off nadir along or across, refuses. So
    does a nadir patch whose coherence is below ``min_nadir_coherence``: the seabed's
    first return is the strongest and most coherent echo there is (0.80-0.99 on the
    simulated sand); without it the other patches' phases are noise and point echoes
    (the demo scene, with no seabed: nadir 0.14-0.22, and the patches' 0.3-0.8 gave
    estimates 15-30 mm wrong before this test). A coherent nadir patch must also be a
    seabed's layer (:func:`seabed_layer` on ping a's nadir patch focused at depths about
    the seabed): a point echo below nadir coheres at 0.9-0.98 too.
    ``gradient``: "offset" corrects each patch's phase for the sub-apertures' offset by
    where its focused power comes from (:func:`phase_gradient`), "full" also moves the
    patch's look direction there, "none" neither (the choice measured: benchmarks/RESULTS.md,
    2026-11-27, "Micronavigation: the estimator with platform motion").
    ``kernel``: "numba" focuses with :mod:`.patch_focus` (the same sums without a sine
    per channel and point; the nadir patch first, refusing before the others are
    focused); "numpy" with :func:`focus_points` (the reference; the gradient options
    always use it). ``taps``: a :class:`TapCache` keeping the pings' taps and a's
    focused patches between calls (None: a new one)."""
    ra, rb = np.asarray(rot_a, dtype=np.float64), np.asarray(rot_b, dtype=np.float64)
    oa, ob = np.asarray(origin_a, dtype=np.float64), np.asarray(origin_b, dtype=np.float64)
    # b's placed body origin in a's body frame, for the pairing
    d_body = ra.T @ (ob - oa)
    pairs = translated_pairs(geometry, projector_a, projector_b, d_body, ra.T @ rb,
                             tolerance_m, rank)
    if len(pairs) < min_pairs:
        pa = phase_centres(geometry, projector_a)[:, :2]
        pb = (phase_centres(geometry, projector_b) @ (ra.T @ rb).T + d_body)[:, :2]
        gap = float(np.hypot(*(pb[None] - pa[:, None]).transpose(2, 0, 1)).min())
        return _refused(f"the phase centres do not overlap: projector {projector_a} then "
                        f"{projector_b}, displaced ({d_body[0]:.3f}, {d_body[1]:.3f}) m, "
                        f"share {len(pairs)} phase centres within {tolerance_m * 1e3:.0f} "
                        f"mm ({min_pairs} needed; the nearest two are {gap * 1e3:.0f} mm "
                        "apart)", len(pairs))
    tx_a = oa + ra @ geometry.projectors[projector_a]
    rx_a = oa + geometry.receivers[pairs.channel_a] @ ra.T
    tx_b = ob + rb @ geometry.projectors[projector_b]
    rx_b = ob + geometry.receivers[pairs.channel_b] @ rb.T
    centre = 0.5 * (tx_a + rx_a.mean(axis=0))
    pc_a, pc_b = 0.5 * (tx_a + rx_a)[:, :2], 0.5 * (tx_b + rx_b)[:, :2]
    mismatch = (pc_b - pc_a).mean(axis=0)
    reach = 1.5 * tolerance_m
    c, k = float(sound_speed_m_s), 2.0 * math.pi * center_hz / float(sound_speed_m_s)
    patches = seabed_patches(centre, seabed_depth_m, patch_angle_rad, half_width_m,
                             spacing_m)
    if kernel not in ("numba", "numpy"):
        raise ValueError(f"kernel {kernel!r}: expected 'numba' or 'numpy'")
    if kernel == "numba" and gradient == "none":
        stats = _patch_stats(bb_a, bb_b, t0_s, dt_s, center_hz, c, k, pairs, tx_a, rx_a,
                             tx_b, rx_b, centre, patches, spacing_m, min_nadir_coherence,
                             taps if taps is not None else TapCache())
        if isinstance(stats, DisplacementEstimate):
            return stats
        return _fit(patches, *stats, k, min_coherence, min_patches, pairs, ob, oa,
                    mismatch)
    phases, gammas, rows, sig = [], [], [], []
    for patch in patches:
        sa = focus_points(bb_a[pairs.channel_a], t0_s, dt_s, center_hz, c, tx_a, rx_a,
                          patch.points, "channels")
        sb = focus_points(bb_b[pairs.channel_b], t0_s, dt_s, center_hz, c, tx_b, rx_b,
                          patch.points, "channels")
        va, vb = sa.sum(axis=0), sb.sum(axis=0)
        cross = np.sum(va * np.conj(vb))
        # the power-weighted mean direction from the phase centres to the patch
        w = np.abs(va) * np.abs(vb)
        u = patch.points - centre
        u = u / np.linalg.norm(u, axis=1)[:, None]
        row = -2.0 * k * (w @ u) / max(float(w.sum()), 1e-300)
        if gradient in ("offset", "full"):
            # the focused power comes from where the channels' terms say (phase_gradient
            # g = 2 k (u_s - u_P) across the aperture), not from the points: b's terms
            # turn by g . delta against a's for the sub-apertures' offset delta (taken
            # out), and by 2 k u_s . Delta for the displacement (the row)
            g = 0.5 * (phase_gradient(sa, pc_a, reach) + phase_gradient(sb, pc_b, reach))
            cross = cross * np.exp(1j * float(g @ mismatch))
            if gradient == "full":
                row[:2] -= g
        pa, pb = np.sum(np.abs(va) ** 2), np.sum(np.abs(vb) ** 2)
        gamma = float(abs(cross) / math.sqrt(max(pa * pb, 1e-300)))
        n_look = _looks(patch.points, centre, rx_a, tx_a, c, center_hz, spacing_m)
        phases.append(float(np.angle(cross)))
        gammas.append(gamma)
        rows.append(row)
        gc = min(max(gamma, 1e-6), 1.0 - 1e-9)
        sig.append(math.sqrt((1.0 - gc * gc) / (2.0 * n_look * gc * gc)))
    phases, gammas = np.array(phases), np.array(gammas)
    if gammas[0] < min_nadir_coherence:
        return _no_seabed(gammas[0], min_nadir_coherence, len(pairs), len(patches))
    offs = layer_offsets()
    profile = _layer_points(patches[0].points, offs)
    va = focus_points(bb_a[pairs.channel_a], t0_s, dt_s, center_hz, c, tx_a, rx_a,
                      profile.reshape(-1, 3))
    why = seabed_layer(offs, np.mean(np.abs(va.reshape(len(offs), -1)) ** 2, axis=1))
    if why:
        return _refused(why, len(pairs), len(patches))
    return _fit(patches, phases, gammas, np.array(rows), np.array(sig), k, min_coherence,
                min_patches, pairs, ob, oa, mismatch)


def _layer_points(nadir: np.ndarray, offsets_m: np.ndarray) -> np.ndarray:
    """The nadir patch's points (m, 3) moved down by each offset: (n_offsets, m, 3)."""
    out = np.repeat(np.asarray(nadir, dtype=np.float64)[None], len(offsets_m), axis=0)
    out[..., 2] += np.asarray(offsets_m)[:, None]
    return out


def _no_seabed(gamma: float, min_nadir_coherence: float, n_pairs: int, n_patch: int
               ) -> DisplacementEstimate:
    return _refused(f"no coherent seabed return under the array: the nadir patch's "
                    f"coherence is {gamma:.2f}, below {min_nadir_coherence:g} (no "
                    "seabed in the window, or the echoes decorrelated)", n_pairs, n_patch)


def _fit(patches, phases, gammas, rows, sig, k, min_coherence, min_patches, pairs, ob, oa,
         mismatch) -> DisplacementEstimate:
    """The weighted least-squares fit of the patches' phases (step 4 of the module
    docstring), or the refusal when too few patches cohere."""
    use = gammas >= min_coherence
    a = rows[use]
    names = [p.name for p, ok in zip(patches, use) if ok]
    if use.sum() < min_patches or not (np.any(np.abs(a[:, 0]) > k * 0.1)
                                       and np.any(np.abs(a[:, 1]) > k * 0.1)):
        weak = ", ".join(f"{p.name} {g:.2f}" for p, g in zip(patches, gammas) if g < min_coherence)
        return _refused(f"the echoes decorrelated: {use.sum()} of {len(patches)} patches "
                        f"cohere above {min_coherence:g} (kept: {', '.join(names)}; "
                        f"weak: {weak})", len(pairs), len(patches))
    w = 1.0 / sig[use] ** 2
    aw = a * w[:, None]
    cov = np.linalg.inv(a.T @ aw)
    delta = cov @ (aw.T @ phases[use])
    res = phases[use] - a @ delta
    dof = int(use.sum()) - 3
    chi2 = float(np.sum(w * res ** 2)) / dof
    cov = cov * max(1.0, chi2) * SCATTER_FACTOR ** 2
    return DisplacementEstimate(ob - oa + delta, delta, cov, gammas, phases, len(pairs), chi2,
                                None, mismatch)


def _looks(points: np.ndarray, centre: np.ndarray, rx: np.ndarray, tx: np.ndarray,
           c: float, center_hz: float, spacing_m: float) -> float:
    """Independent looks in a patch, at least one: its area over (lambda R / (2 L))^2,
    the sub-aperture's angular resolution cell at the patch's range R (L the diagonal
    extent of its phase centres). The range resolution (c / (2 B) over sin(theta)) is
    not taken into account; the scatter this count misses is in SCATTER_FACTOR."""
    ext = np.ptp(0.5 * (rx + tx), axis=0)[:2]
    length = max(float(np.hypot(*ext)), 1e-3)
    r = float(np.linalg.norm(points.mean(axis=0) - centre))
    lam = c / center_hz
    cross_cell = lam * r / (2.0 * length)
    area = (np.ptp(points[:, 0]) + spacing_m) * (np.ptp(points[:, 1]) + spacing_m)
    return max(1.0, area / (cross_cell ** 2))


class TapCache:
    """What the focusing of one ping pair leaves for the next calls
    (:mod:`.patch_focus`): the taps of the last ``size`` pings' baseband (each ping is b
    of one pair and a of the next; both translations and both passes use them), and
    ping a's focused patches (the second pass moves only b: a's sub-aperture and patches
    are the same when the pairing is). Keyed by the baseband arrays' identity (each kept
    referenced, so that an identity is never reused while cached) and the exact
    geometry."""

    def __init__(self, size: int = 3):
        self.size = size
        self._taps: list = []            # (bb, (t0, dt, fc), taps), newest last
        self._focused: dict = {}

    def taps(self, bb: np.ndarray, t0_s: float, dt_s: float, center_hz: float):
        axis = (float(t0_s), float(dt_s), float(center_hz))
        for held, ax, taps in self._taps:
            if held is bb and ax == axis:
                return taps
        taps = ping_taps(bb, t0_s, dt_s, center_hz)
        self._taps.append((bb, axis, taps))
        if len(self._taps) > self.size:
            old = self._taps.pop(0)[0]
            self._focused = {k: v for k, v in self._focused.items() if v[0] is not old}
        return taps

    def focused(self, bb: np.ndarray, key: tuple, make) -> np.ndarray:
        """``make()``'s values, kept under (bb, ``key``)."""
        hit = self._focused.get((id(bb),) + key)
        if hit is not None and hit[0] is bb:
            return hit[1]
        values = make()
        self._focused[(id(bb),) + key] = (bb, values)
        return values


def _patch_stats(bb_a, bb_b, t0_s, dt_s, center_hz, c, k, pairs, tx_a, rx_a, tx_b, rx_b,
                 centre, patches, spacing_m, min_nadir_coherence, cache: TapCache):
    """The patches' phases, coherences, rows and phase sigmas as the reference loop of
    :func:`displacement_pass` computes them, focused by :mod:`.patch_focus` in a frame
    centred on ``centre``, all patches at once; the nadir patch first (a refusal when
    it does not cohere or is not a seabed's layer, before the others are focused)."""
    ta = cache.taps(bb_a, t0_s, dt_s, center_hz)
    tb = cache.taps(bb_b, t0_s, dt_s, center_hz)
    sub_a = SubAperture(pairs.channel_a, tx_a - centre, rx_a - centre)
    sub_b = SubAperture(pairs.channel_b, tx_b - centre, rx_b - centre)
    pts = np.stack([p.points for p in patches]) - centre       # (n_patch, m, 3) local
    n_patch, m = pts.shape[:2]
    geo_a = (sub_a.tx.tobytes(), sub_a.rx.tobytes(), sub_a.channels.tobytes())

    def part(sel, name):
        flat = pts[sel].reshape(-1, 3)
        va = cache.focused(bb_a, geo_a + (name, flat.tobytes()),
                           lambda: focus(ta, sub_a, flat, c))
        vb = focus(tb, sub_b, flat, c)
        return va.reshape(-1, m), vb.reshape(-1, m)

    va0, vb0 = part(slice(0, 1), "nadir")
    pa0, pb0 = np.sum(np.abs(va0) ** 2), np.sum(np.abs(vb0) ** 2)
    g0 = float(abs(np.sum(va0 * np.conj(vb0))) / math.sqrt(max(pa0 * pb0, 1e-300)))
    if g0 < min_nadir_coherence:
        return _no_seabed(g0, min_nadir_coherence, len(pairs), n_patch)
    offs = layer_offsets()
    flat = _layer_points(pts[0], offs).reshape(-1, 3)
    vl = cache.focused(bb_a, geo_a + ("layer", flat.tobytes()),
                       lambda: focus(ta, sub_a, flat, c))
    why = seabed_layer(offs, np.mean(np.abs(vl.reshape(len(offs), m)) ** 2, axis=1))
    if why:
        return _refused(why, len(pairs), n_patch)
    va1, vb1 = part(slice(1, None), "rest")
    va, vb = np.concatenate([va0, va1]), np.concatenate([vb0, vb1])
    cross = np.sum(va * np.conj(vb), axis=1)
    w = np.abs(va) * np.abs(vb)
    u = pts / np.linalg.norm(pts, axis=2)[..., None]
    rows = -2.0 * k * np.einsum("pm,pmi->pi", w, u) / np.maximum(w.sum(axis=1), 1e-300)[:, None]
    pa, pb = np.sum(np.abs(va) ** 2, axis=1), np.sum(np.abs(vb) ** 2, axis=1)
    gammas = np.abs(cross) / np.sqrt(np.maximum(pa * pb, 1e-300))
    n_look = _looks_all(pts, rx_a, tx_a, c, center_hz, spacing_m)
    gc = np.clip(gammas, 1e-6, 1.0 - 1e-9)
    sig = np.sqrt((1.0 - gc * gc) / (2.0 * n_look * gc * gc))
    return np.angle(cross), gammas, rows, sig


def _looks_all(points_local: np.ndarray, rx: np.ndarray, tx: np.ndarray, c: float,
               center_hz: float, spacing_m: float) -> np.ndarray:
    """:func:`_looks` of every patch at once (``points_local`` (n_patch, m, 3) relative
    to the sub-aperture's centre)."""
    ext = np.ptp(0.5 * (rx + tx), axis=0)[:2]
    length = max(float(np.hypot(*ext)), 1e-3)
    r = np.linalg.norm(points_local.mean(axis=1), axis=1)
    cross_cell = (c / center_hz) * r / (2.0 * length)
    area = ((np.ptp(points_local[..., 0], axis=1) + spacing_m)
            * (np.ptp(points_local[..., 1], axis=1) + spacing_m))
    return np.maximum(1.0, area / cross_cell ** 2)
