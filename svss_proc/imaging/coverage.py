"""Coverage of a tile: how many pings, and how many ping-channel pairs, reached each voxel.

Computed geometrically, beside the imaging kernel and from the same inputs (the ping's
placed array, the beam cones used for gating and the receive window), without touching
the image: a voxel is *reached* by a ping when it lies inside the projector's cone and,
for a channel, inside that receiver's cone with the two-way travel time inside the
receive window. Travel times are those of straight rays, the part of the path below the
interface at the sediment speed (``water`` speed throughout for ``delays = "straight"``,
as the kernel does): a bound good to a few samples for the refracting delay models,
which matters only at the far end of the window.

Cost: the receiver test is made for the corners of the receive aperture (its convex
hull in the array plane) only: the set of element positions whose cone holds a voxel is
convex, and so is the (straight-ray) travel time to an element, so when every corner
passes, every element does; only voxels at a cone or window edge loop over all
channels. And per voxel column the voxels every channel reaches are one depth interval
(convex cones cut by a vertical line; a travel time growing with depth): only the
voxels above and below it are tested, those inside are counted. Without gating (``beam_gating = false``) every
voxel inside the window counts.

Counts saturate at 65535 (uint16): more than 800 full-array (80-channel) pings per
voxel, a platform holding still.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numba as nb
import numpy as np

from svss_daq.geometry import cone_radius, cone_reach

from .kernel_args import VoxelAxes, surface_of

#: largest count a coverage volume holds
SATURATE = 65535


def aperture_corners(receivers_body: np.ndarray) -> np.ndarray:
    """Indices of the receivers at the corners of the receive aperture (its convex hull
    in the body x-y plane, every element if the array is not planar to 1 mm or has
    fewer than three distinct positions)."""
    rx = np.asarray(receivers_body, dtype=np.float64)
    if rx.shape[0] < 3 or np.ptp(rx[:, 2]) > 1e-3:
        return np.arange(rx.shape[0])
    pts = rx[:, :2]
    order = np.lexsort((pts[:, 1], pts[:, 0]))

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    hull: list[int] = []
    for seq in (order, order[::-1]):            # Andrew's monotone chain
        part: list[int] = []
        for i in seq:
            while len(part) >= 2 and cross(pts[part[-2]], pts[part[-1]], pts[i]) <= 1e-12:
                part.pop()
            part.append(int(i))
        hull += part[:-1]
    if len(hull) < 3:
        return np.arange(rx.shape[0])
    return np.unique(np.asarray(hull, dtype=np.int64))


@nb.njit(inline="always", cache=True)
def _leg_time(dx, dy, z, h, inv_cw, inv_cs):
    """Straight-ray one-way time from an element ``h`` above the interface to a voxel at
    depth ``z`` below it, horizontal offset (dx, dy): the path's part below the
    interface at the sediment speed."""
    vz = z + h
    r = math.sqrt(dx * dx + dy * dy + vz * vz)
    if z <= 0.0 or vz <= 0.0:
        return r * inv_cw
    f = z / vz
    return r * ((1.0 - f) * inv_cw + f * inv_cs)


@nb.njit(inline="always", cache=True)
def _rx_time(e, xa, yc, z, s, rx, b0, b1, b2, cos_rx, gating, inv_cw, inv_cs):
    """The one-way time from the voxel (``xa, yc``, ``z`` below its column's interface,
    ``s`` below the level of the element heights) to receive element ``e``; infinite
    where ``gating`` and the voxel lies outside the element's cone."""
    ex = xa - rx[e, 0]
    ey = yc - rx[e, 1]
    ez = z + s - rx[e, 2]
    if gating:
        r2 = math.sqrt(ex * ex + ey * ey + ez * ez)
        if ex * b0 + ey * b1 + ez * b2 < r2 * cos_rx:
            return math.inf
    return _leg_time(ex, ey, z, s - rx[e, 2], inv_cw, inv_cs)


@nb.njit(inline="always", cache=True)
def _count(x, y, z, s, xa, yc, h_tx, h_min, rx, corners, b0, b1, b2, cos_tx, cos_rx,
           gating, t_lo, t_hi, inv_cw, inv_cs):
    """Channels one ping reaches at one voxel (``x, y``: its offset from the projector,
    ``xa, yc``: its position, ``z``: its depth below its column's interface, ``s`` below
    the level the element heights are from; ``h_tx``, ``h_min``: heights above the
    column's interface), and whether every channel does."""
    nch = rx.shape[0]
    vz = z + h_tx
    r1 = math.sqrt(x * x + y * y + vz * vz)
    if gating and x * b0 + y * b1 + vz * b2 < r1 * cos_tx:
        return 0, False
    t1 = _leg_time(x, y, z, h_tx, inv_cw, inv_cs)
    if t1 > t_hi:
        return 0, False
    # corners first: all of them inside the cone and the window's end, and the nearest
    # possible element (straight below) not before its start, means every element is
    # (the least slowness; no min() here or in _add: the GPU compiles this source too,
    # gpu_coverage, and min's CUDA overload needs a device to compile for)
    least = inv_cw if inv_cw < inv_cs else inv_cs
    ok = t1 + (z + h_min) * least >= t_lo
    for k in range(corners.size):
        if not ok:
            break
        e = corners[k]
        if t1 + _rx_time(e, xa, yc, z, s, rx, b0, b1, b2, cos_rx, gating, inv_cw,
                         inv_cs) > t_hi:
            ok = False
    if ok:
        return nch, True
    n = 0
    for e in range(nch):
        t = t1 + _rx_time(e, xa, yc, z, s, rx, b0, b1, b2, cos_rx, gating, inv_cw, inv_cs)
        if t_lo <= t <= t_hi:
            n += 1
    return n, False


@nb.njit(inline="always", cache=True)
def _add(pings, channels, ia, ic, iz, n):
    if n > 0:
        if pings[ia, ic, iz] < SATURATE:
            pings[ia, ic, iz] += 1
        total = np.int64(channels[ia, ic, iz]) + n
        channels[ia, ic, iz] = total if total < SATURATE else SATURATE


@nb.njit(inline="always", cache=True)
def _column(pings, channels, ia, ic, ax, cy, dz, surf, tx, rx, corners, b0, b1, b2, h_tx,
            h_min, cos_tx, cos_rx, gating, t_lo, t_hi, inv_cw, inv_cs, rho_max):
    """One voxel column's coverage (``_accumulate``); the CPU's loop and the GPU's
    thread (:mod:`~svss_proc.imaging.gpu_coverage`) run it alike."""
    nd, nch = dz.size, rx.shape[0]
    xa = ax[ia]
    x = xa - tx[0]
    yc = cy[ic]
    y = yc - tx[1]
    if x * x + y * y > rho_max * rho_max:       # outside the cone at every depth
        return
    s = surf[ia, ic]
    first = -1
    for iz in range(nd):
        n, full = _count(x, y, dz[iz], s, xa, yc, h_tx + s, h_min + s, rx, corners,
                         b0, b1, b2, cos_tx, cos_rx, gating, t_lo, t_hi, inv_cw,
                         inv_cs)
        _add(pings, channels, ia, ic, iz, n)
        if full:
            first = iz
            break
    if first < 0:
        return
    last = nd - 1
    while last > first:
        n, full = _count(x, y, dz[last], s, xa, yc, h_tx + s, h_min + s, rx,
                         corners, b0, b1, b2, cos_tx, cos_rx, gating, t_lo, t_hi,
                         inv_cw, inv_cs)
        _add(pings, channels, ia, ic, last, n)
        if full:
            break
        last -= 1
    for iz in range(first + 1, last):
        _add(pings, channels, ia, ic, iz, nch)


def lowest_receiver(rx: np.ndarray) -> float:
    """The lowest receive element's height above the interface's level, m."""
    return float(np.min(-np.asarray(rx, dtype=np.float64)[:, 2]))


@nb.njit(parallel=True, cache=True)
def _accumulate(pings, channels, ax, cy, dz, surf, ia0, ia1, tx, rx, corners, bore, cos_tx,
                cos_rx, gating, t_lo, t_hi, inv_cw, inv_cs, rho_max, h_min):
    """Per voxel column, the voxels every channel reaches form one depth interval (the
    intersection of the beam cones, convex, with a vertical line, and a window on a
    travel time that grows with depth): it is found by testing from the top down and
    from the bottom up until a voxel passes; the voxels between are counted without
    testing."""
    nc = cy.size
    h_tx = -tx[2]
    b0, b1, b2 = bore[0], bore[1], bore[2]
    for ia in nb.prange(ia0, ia1):
        for ic in range(nc):
            _column(pings, channels, ia, ic, ax, cy, dz, surf, tx, rx, corners, b0, b1, b2,
                    h_tx, h_min, cos_tx, cos_rx, gating, t_lo, t_hi, inv_cw, inv_cs,
                    rho_max)


def new_coverage(shape: tuple[int, int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Empty coverage volumes (pings, ping-channel pairs), uint16."""
    return np.zeros(shape, dtype=np.uint16), np.zeros(shape, dtype=np.uint16)


def add_ping(pings: np.ndarray, channels: np.ndarray, along: np.ndarray,
             cross: np.ndarray, depth: np.ndarray, ia0: int, ia1: int, tx: np.ndarray,
             rx: np.ndarray, corners: np.ndarray, bore: np.ndarray, half_tx_rad: float,
             half_rx_rad: float, gating: bool, window_s: tuple[float, float],
             water_m_s: float, sediment_m_s: float,
             surface: np.ndarray | None = None) -> None:
    """Add one ping's coverage to ``pings`` and ``channels`` (uint16 volumes, along x
    cross x depth, changed in place) over along-track voxels ``ia0:ia1``.

    ``tx`` (3,), ``rx`` (n_channels, 3), ``bore`` (3,): the placed array in the tile
    frame (m; depth below the interface); ``corners``: :func:`aperture_corners`;
    ``half_*_rad``: beam half-angles; ``window_s``: the receive window (first and last
    arrival time the samples hold, s after transmit); speeds in m/s (the sediment speed
    equal to the water's for straight-ray delays); ``surface``: the interface's depth
    at each column below the level the array's heights are from (None: flat;
    :func:`~svss_proc.imaging.kernel_args.surface_of`)."""
    count_cpu(pings, channels, coverage_args(along, cross, depth, tx, rx, corners, bore,
                                             half_tx_rad, half_rx_rad, gating, window_s,
                                             water_m_s, sediment_m_s, surface), ia0, ia1)


def count_cpu(pings: np.ndarray, channels: np.ndarray, a: "CoverageArgs", ia0: int,
              ia1: int) -> None:
    """Count one ping's coverage ``a`` (:func:`coverage_args`) into the host volumes
    over along-track voxels ``ia0:ia1``."""
    _accumulate(pings, channels, a.ax, a.cy, a.dz, a.surf, int(ia0), int(ia1), a.tx, a.rx,
                a.corners, a.bore, a.cos_tx, a.cos_rx, a.gating, a.t_lo, a.t_hi, a.inv_cw,
                a.inv_cs, a.rho_max, a.h_min)


class CoverageArgs(NamedTuple):
    """One ping's coverage inputs as the counting code takes them (float64 arrays)."""
    ax: np.ndarray
    cy: np.ndarray
    dz: np.ndarray
    surf: np.ndarray
    tx: np.ndarray
    rx: np.ndarray
    corners: np.ndarray
    bore: np.ndarray
    cos_tx: float
    cos_rx: float
    gating: bool
    t_lo: float
    t_hi: float
    inv_cw: float
    inv_cs: float
    rho_max: float
    h_min: float


def coverage_args(along, cross, depth, tx, rx, corners, bore, half_tx_rad, half_rx_rad,
                  gating, window_s, water_m_s, sediment_m_s, surface) -> CoverageArgs:
    """:func:`add_ping`'s arguments as the counting code takes them (CPU and GPU)."""
    surf = surface_of(VoxelAxes(along, cross, depth, surface))
    # the widest the projector cone gets within the tile: a column further away is
    # outside it at every depth (its tilt added to the half-angle, as the imager does)
    lowest = max(float(np.max(depth)) + float(surf.max(initial=0.0)), 0.0)
    rho_max = (cone_reach(lowest - float(tx[2]), float(bore[2]), half_tx_rad) + 1e-9
               if gating else math.inf)
    rx = np.ascontiguousarray(rx, dtype=np.float64)
    return CoverageArgs(np.ascontiguousarray(along, dtype=np.float64),
                        np.ascontiguousarray(cross, dtype=np.float64),
                        np.ascontiguousarray(depth, dtype=np.float64), surf,
                        np.asarray(tx, dtype=np.float64), rx,
                        np.asarray(corners, dtype=np.int64),
                        np.asarray(bore, dtype=np.float64), math.cos(half_tx_rad),
                        math.cos(half_rx_rad), bool(gating), float(window_s[0]),
                        float(window_s[1]), 1.0 / water_m_s, 1.0 / sediment_m_s, rho_max,
                        lowest_receiver(rx))


@dataclass
class Coverage:
    """A tile's coverage while it is formed: ``pings`` and ``channels`` (uint16 volumes,
    along x cross x depth; channels counts ping-channel pairs), the array's channel
    count, the sum of the projector heights above the interface over the pings added
    (m; :attr:`mean_height_m`) and ``geodetic_ref``: (latitude deg, longitude deg,
    north m, east m, down m) of the first ping added whose pose has a geodetic position
    (None: none had)."""
    pings: np.ndarray
    channels: np.ndarray
    n_channels: int
    corners: np.ndarray
    height_sum_m: float = 0.0
    n_pings: int = 0
    #: along-track span (tile frame, m) of the projector positions of the pings added
    #: (:func:`aperture_fraction`; inf, -inf: none)
    tx_along_min_m: float = math.inf
    tx_along_max_m: float = -math.inf
    geodetic_ref: tuple[float, float, float, float, float] | None = None

    def __getstate__(self) -> dict:
        """Pickled (handed to the products process) without instance-level wrappers of
        its methods (a stage clock's timing of :meth:`add`)."""
        return {k: v for k, v in self.__dict__.items()
                if not (callable(v) and hasattr(type(self), k))}

    @classmethod
    def new(cls, shape: tuple[int, int, int], receivers_body: np.ndarray,
            zeros=None) -> Coverage:
        """Empty coverage; ``zeros(shape, dtype)`` makes its volumes (None: host arrays;
        on the GPU, device arrays)."""
        volumes = (new_coverage(shape) if zeros is None
                   else (zeros(shape, np.uint16), zeros(shape, np.uint16)))
        return cls(*volumes, int(receivers_body.shape[0]),
                   aperture_corners(receivers_body))

    def to_host(self) -> Coverage:
        """Bring device-resident volumes (GPU coverage) back to host memory."""
        if hasattr(self.pings, "copy_to_host"):
            self.pings, self.channels = (self.pings.copy_to_host(),
                                         self.channels.copy_to_host())
        return self

    @property
    def mean_height_m(self) -> float:
        """Mean projector height above the interface of the pings added, m (NaN: none)."""
        return self.height_sum_m / self.n_pings if self.n_pings else float("nan")

    def add(self, grid, ia0: int, ia1: int, placed, geometry, window_s: tuple[float, float],
            imaging, nav, counter=None) -> None:
        """Add one ping: ``grid`` the tile's :class:`~svss_proc.imaging.grid.TileGrid`,
        ``ia0:ia1`` the along-track voxels the kernel was given, ``placed`` the
        :class:`~svss_daq.geometry.PlacedArray` in the tile frame, ``geometry`` the
        :class:`~svss_daq.geometry.ArrayGeometry`, ``window_s`` the receive window
        (s after transmit), ``imaging`` the processing configuration's ``[imaging]``,
        ``nav`` the ping's pose; ``counter(pings, channels, args, ia0, ia1)`` counts
        (None: :func:`count_cpu`; on the GPU,
        :class:`~svss_proc.imaging.gpu_coverage.DeviceCounter`)."""
        cw = imaging.water_sound_speed_m_s
        cs = cw if imaging.delays == "straight" else imaging.sediment_sound_speed_m_s
        args = coverage_args(grid.along, grid.cross, grid.depth, placed.tx, placed.rx,
                             self.corners, placed.bore, geometry.projector_half_angle,
                             geometry.receiver_half_angle, imaging.beam_gating, window_s,
                             cw, cs, getattr(grid, "surface", None))
        (counter or count_cpu)(self.pings, self.channels, args, ia0, ia1)
        self.height_sum_m += float(-placed.tx[2])
        self.tx_along_min_m = min(self.tx_along_min_m, float(placed.tx[0]))
        self.tx_along_max_m = max(self.tx_along_max_m, float(placed.tx[0]))
        self.n_pings += 1
        lat, lon = getattr(nav, "latitude_deg", math.nan), getattr(nav, "longitude_deg",
                                                                    math.nan)
        if self.geodetic_ref is None and math.isfinite(lat) and math.isfinite(lon):
            self.geodetic_ref = (float(lat), float(lon), float(nav.north_m),
                                 float(nav.east_m), float(nav.down_m))


def full_fraction(pings: np.ndarray) -> np.ndarray:
    """Each voxel's coverage as a fraction of the full coverage at its depth (the most
    pings any voxel of that depth layer got; 0 where the layer got none)."""
    ref = pings.reshape(-1, pings.shape[-1]).max(axis=0).astype(np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(ref > 0, pings / np.where(ref > 0, ref, 1.0), 0.0).astype(np.float32)


def aperture_fraction(along: np.ndarray, depth: np.ndarray, tx_along_span_m: tuple[float, float],
                      height_m: float, tan_half_angle: float) -> np.ndarray:
    """The fraction of each voxel's synthetic aperture that the platform traversed
    (along x depth, float32; broadcast over cross-track).

    A voxel at along-track ``a`` and depth ``z`` (below the interface; projectors
    ``height_m`` above it) lies inside the projector cone of every ping whose projector
    is within ``R(z) = (height_m + z) tan(half-angle)`` of it horizontally: its full
    synthetic aperture is the along-track interval ``[a - R, a + R]`` of projector
    positions. The tile's pings put the projector over ``tx_along_span_m`` (the first
    and last along-track projector position, tile frame, m); the fraction is the length
    of that interval's overlap with the aperture over ``2 R``. It does not count pings,
    so it is independent of the ping rate and of the platform's speed; it is below 1
    where the run starts or ends within a voxel's aperture (a partly imaged edge: the
    tile's own most-covered voxels can then be partly imaged too, so the coverage rule's
    count against the tile's own maximum does not see it)."""
    lo, hi = tx_along_span_m
    a = np.asarray(along, dtype=np.float64)[:, None]
    reach = np.maximum(cone_radius(float(height_m) + np.asarray(depth, dtype=np.float64),
                                   float(tan_half_angle)), 1e-9)[None, :]
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi < lo:
        return np.zeros((a.shape[0], reach.shape[1]), dtype=np.float32)
    overlap = np.clip(np.minimum(a + reach, hi) - np.maximum(a - reach, lo), 0.0, None)
    return np.minimum(overlap / (2.0 * reach), 1.0).astype(np.float32)
