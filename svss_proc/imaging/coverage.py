"""Coverage of a tile: how many pings, and how many ping-channel pairs, reached each voxel.

Computed geometrically, beside the imaging kernel and from the same inputs (the ping's
placed array, the beam cones used for gating and the receive window), without touching
the image: a voxel is *reached* by a ping when it lies inside the projector's cone and,
for a channel, inside that receiver's cone with the two-way travel time inside the
receive window. Travel times are those of straight rays, the part of the path below the
interface at the sediment speed (``water`` speed throughout for ``delays = "straight"``,
as the kernel does): a bound good to a few samples for the refracting delay models,
which matters only at the far end of the window.

Cost: per voxel in the projector cone, the receiver test is made for the corners of the
receive aperture (its convex hull in the array plane) only: the set of element positions
whose cone holds a voxel is convex, and so is the (straight-ray) travel time to an
element, so when every corner passes, every element does. Only voxels at a cone or
window edge loop over all channels. Without gating (``beam_gating = false``) every
voxel inside the window counts.

Counts saturate at 65535 (uint16): more than 800 full-array (80-channel) pings per
voxel, a platform holding still.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

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


@nb.njit(parallel=True, cache=True)
def _accumulate(pings, channels, ax, cy, dz, ia0, ia1, tx, rx, corners, bore, cos_tx,
                cos_rx, gating, t_lo, t_hi, inv_cw, inv_cs):
    nc, nd, nch = cy.size, dz.size, rx.shape[0]
    h_tx = -tx[2]
    b0, b1, b2 = bore[0], bore[1], bore[2]
    h_min = -rx[0, 2]
    for j in range(nch):
        h_min = min(h_min, -rx[j, 2])
    for ia in nb.prange(ia0, ia1):
        x = ax[ia] - tx[0]
        for ic in range(nc):
            y = cy[ic] - tx[1]
            for iz in range(nd):
                z = dz[iz]
                vz = z + h_tx
                r1 = math.sqrt(x * x + y * y + vz * vz)
                if gating and x * b0 + y * b1 + vz * b2 < r1 * cos_tx:
                    continue
                t1 = _leg_time(x, y, z, h_tx, inv_cw, inv_cs)
                if t1 > t_hi:
                    continue
                # corners first: all of them inside the cone and the window's end, and
                # the nearest possible element (straight below) not before its start,
                # means every element is
                ok = t1 + (z + h_min) * min(inv_cw, inv_cs) >= t_lo
                for k in range(corners.size):
                    if not ok:
                        break
                    e = corners[k]
                    ex = ax[ia] - rx[e, 0]
                    ey = cy[ic] - rx[e, 1]
                    ez = z - rx[e, 2]
                    if gating:
                        r2 = math.sqrt(ex * ex + ey * ey + ez * ez)
                        if ex * b0 + ey * b1 + ez * b2 < r2 * cos_rx:
                            ok = False
                    if t1 + _leg_time(ex, ey, z, -rx[e, 2], inv_cw, inv_cs) > t_hi:
                        ok = False
                n = nch
                if not ok:
                    n = 0
                    for e in range(nch):
                        ex = ax[ia] - rx[e, 0]
                        ey = cy[ic] - rx[e, 1]
                        ez = z - rx[e, 2]
                        if gating:
                            r2 = math.sqrt(ex * ex + ey * ey + ez * ez)
                            if ex * b0 + ey * b1 + ez * b2 < r2 * cos_rx:
                                continue
                        t = t1 + _leg_time(ex, ey, z, -rx[e, 2], inv_cw, inv_cs)
                        if t_lo <= t <= t_hi:
                            n += 1
                if n > 0:
                    if pings[ia, ic, iz] < 65535:
                        pings[ia, ic, iz] += 1
                    c = np.int64(channels[ia, ic, iz]) + n
                    channels[ia, ic, iz] = min(c, 65535)


def new_coverage(shape: tuple[int, int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Empty coverage volumes (pings, ping-channel pairs), uint16."""
    return np.zeros(shape, dtype=np.uint16), np.zeros(shape, dtype=np.uint16)


def add_ping(pings: np.ndarray, channels: np.ndarray, along: np.ndarray,
             cross: np.ndarray, depth: np.ndarray, ia0: int, ia1: int, tx: np.ndarray,
             rx: np.ndarray, corners: np.ndarray, bore: np.ndarray, half_tx_rad: float,
             half_rx_rad: float, gating: bool, window_s: tuple[float, float],
             water_m_s: float, sediment_m_s: float) -> None:
    """Add one ping's coverage to ``pings`` and ``channels`` (uint16 volumes, along x
    cross x depth, changed in place) over along-track voxels ``ia0:ia1``.

    ``tx`` (3,), ``rx`` (n_channels, 3), ``bore`` (3,): the placed array in the tile
    frame (m; depth below the interface); ``corners``: :func:`aperture_corners`;
    ``half_*_rad``: beam half-angles; ``window_s``: the receive window (first and last
    arrival time the samples hold, s after transmit); speeds in m/s (the sediment speed
    equal to the water's for straight-ray delays)."""
    _accumulate(pings, channels, np.ascontiguousarray(along, dtype=np.float64),
                np.ascontiguousarray(cross, dtype=np.float64),
                np.ascontiguousarray(depth, dtype=np.float64), int(ia0), int(ia1),
                np.asarray(tx, dtype=np.float64), np.ascontiguousarray(rx, dtype=np.float64),
                np.asarray(corners, dtype=np.int64), np.asarray(bore, dtype=np.float64),
                math.cos(half_tx_rad), math.cos(half_rx_rad), bool(gating),
                float(window_s[0]), float(window_s[1]), 1.0 / water_m_s, 1.0 / sediment_m_s)


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
    geodetic_ref: tuple[float, float, float, float, float] | None = None

    @classmethod
    def new(cls, shape: tuple[int, int, int], receivers_body: np.ndarray) -> Coverage:
        return cls(*new_coverage(shape), int(receivers_body.shape[0]),
                   aperture_corners(receivers_body))

    @property
    def mean_height_m(self) -> float:
        """Mean projector height above the interface of the pings added, m (NaN: none)."""
        return self.height_sum_m / self.n_pings if self.n_pings else float("nan")

    def add(self, grid, ia0: int, ia1: int, placed, geometry, window_s: tuple[float, float],
            imaging, nav) -> None:
        """Add one ping: ``grid`` the tile's :class:`~svss_proc.imaging.grid.TileGrid`,
        ``ia0:ia1`` the along-track voxels the kernel was given, ``placed`` the
        :class:`~svss_daq.geometry.PlacedArray` in the tile frame, ``geometry`` the
        :class:`~svss_daq.geometry.ArrayGeometry`, ``window_s`` the receive window
        (s after transmit), ``imaging`` the processing configuration's ``[imaging]``,
        ``nav`` the ping's pose."""
        cw = imaging.water_sound_speed_m_s
        cs = cw if imaging.delays == "straight" else imaging.sediment_sound_speed_m_s
        add_ping(self.pings, self.channels, grid.along, grid.cross, grid.depth, ia0, ia1,
                 placed.tx, placed.rx, self.corners, placed.bore,
                 geometry.projector_half_angle, geometry.receiver_half_angle,
                 imaging.beam_gating, window_s, cw, cs)
        self.height_sum_m += float(-placed.tx[2])
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
