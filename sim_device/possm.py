"""Point-based scatterers (PoSSM, Brown, Johnson & Olson 2017): where they are and what
they are, seeded per spatial cell.

The seabed is divided into cells of the scene's tile frame (along, cross and, for the
volume, depth; edge ``cell_m``). A cell holds n = round(density x cell size) scatterers
at uniform random positions, each with a circular complex Gaussian weight xi
(E|xi|^2 = 1) and the cell size share dA = area/n or dV = volume/n, so the mean intensity
does not depend on the density. Every random number is a counter-based hash of
(scene seed, kind, cell indices, scatterer index, component): a cell is the same whichever
pings look at it and in whatever order, and no state is carried between pings.

Only cells that the transmitting projector's cone (its image's cones, with multipath)
can reach are generated; :func:`cone_reach` gives the horizontal reach at each depth
through the layered seabed, which follows Snell's law.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

KIND_INTERFACE = 1
KIND_VOLUME = 2

_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_GOLD = np.uint64(0x9E3779B97F4A7C15)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_S11 = np.uint64(11)
_BIAS = 1 << 40            # cell indices are offset to stay non-negative
_INV53 = 1.0 / 9007199254740992.0


@nb.njit(cache=True, inline="always")
def _mix(z):
    """splitmix64 finaliser (a bijection of uint64 with good avalanche)."""
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@nb.njit(cache=True)
def cell_key(seed, kind, i, j, l):
    """Hash key of cell (i, j, l) of a kind (uint64)."""
    h = _mix(np.uint64(seed) + _GOLD * np.uint64(kind))
    h = _mix(h ^ (np.uint64(i + _BIAS) * _GOLD))
    h = _mix(h ^ (np.uint64(j + _BIAS) * _M1))
    return _mix(h ^ (np.uint64(l + _BIAS) * _M2))


@nb.njit(cache=True, inline="always")
def _uniform(key, k, comp):
    """Uniform number in [0, 1) for scatterer k, component comp of a cell."""
    h = _mix(key + _GOLD * np.uint64(8 * k + comp + 1))
    return float(h >> _S11) * _INV53


@nb.njit(parallel=True, cache=True)
def generate_cells(cells, kind, n_per, cell, cell_z, seed, x, y, z, xi):
    """Fill scatterers of ``cells`` ((n, 3) int64: along, cross, depth indices): positions
    (m, tile frame) and complex Gaussian weights; cell c owns entries
    [c n_per, (c + 1) n_per). Interface cells put z = 0."""
    for c in nb.prange(cells.shape[0]):
        i, j, l = cells[c, 0], cells[c, 1], cells[c, 2]
        key = cell_key(seed, kind, i, j, l)
        for k in range(n_per):
            o = c * n_per + k
            x[o] = (i + _uniform(key, k, 0)) * cell
            y[o] = (j + _uniform(key, k, 1)) * cell
            z[o] = (l + _uniform(key, k, 2)) * cell_z if kind == KIND_VOLUME else 0.0
            u1 = 1.0 - _uniform(key, k, 3)               # (0, 1]
            u2 = _uniform(key, k, 4)
            g = math.sqrt(-math.log(u1))                  # |xi|, E|xi|^2 = 1
            xi[o] = complex(g * math.cos(2.0 * math.pi * u2), g * math.sin(2.0 * math.pi * u2))


def scatterers_per_cell(density: float, size: float) -> int:
    """Scatterers in a cell of ``size`` (m^2 or m^3) at ``density``; at least one."""
    return max(1, int(round(density * size)))


def cone_reach(depth: np.ndarray, height: float, angle: float, c: np.ndarray,
               z_top: np.ndarray, limit: float) -> np.ndarray:
    """Horizontal reach (m) at ``depth`` (m below the interface; <= 0 in water) of rays
    leaving a point ``height`` m above the interface at up to ``angle`` (rad) from the
    vertical, refracted through the media (speeds ``c``, tops ``z_top``); capped at
    ``limit`` (m) where a ray at ``angle`` cannot enter a layer (beyond critical)."""
    depth = np.atleast_1d(np.asarray(depth, dtype=np.float64))
    s0 = math.sin(min(angle, 0.5 * math.pi - 1e-9))
    out = np.full(depth.shape, height * math.tan(min(angle, 0.5 * math.pi - 1e-9)))
    for i in range(1, c.size):
        top = z_top[i]
        bot = z_top[i + 1] if i + 1 < c.size else np.inf
        ext = np.clip(depth, top, bot) - top
        si = s0 * c[i] / c[0]
        if si >= 1.0:
            out = np.where(ext > 0, limit, out)
        else:
            out = out + ext * si / math.sqrt(1.0 - si * si)
    if c.size == 1:
        out = out + np.maximum(depth, 0.0) * math.tan(min(angle, 0.5 * math.pi - 1e-9))
    return np.minimum(out, limit)


def cells_in_disc(cx: float, cy: float, radius: float, cell: float) -> np.ndarray:
    """(n, 2) indices of the square cells of edge ``cell`` that meet the disc of
    ``radius`` about (cx, cy) (tile frame, m)."""
    if not radius >= 0:
        return np.zeros((0, 2), dtype=np.int64)
    i = np.arange(math.floor((cx - radius) / cell), math.floor((cx + radius) / cell) + 1)
    j = np.arange(math.floor((cy - radius) / cell), math.floor((cy + radius) / cell) + 1)
    ii, jj = np.meshgrid(i, j, indexing="ij")
    dx = np.maximum(np.maximum(ii * cell - cx, cx - (ii + 1) * cell), 0.0)
    dy = np.maximum(np.maximum(jj * cell - cy, cy - (jj + 1) * cell), 0.0)
    keep = dx * dx + dy * dy <= radius * radius
    return np.stack([ii[keep], jj[keep]], axis=1).astype(np.int64)


def interface_cells(cx: float, cy: float, radius: float, cell: float) -> np.ndarray:
    """(n, 3) interface cells (depth index 0) that meet the disc."""
    ij = cells_in_disc(cx, cy, radius, cell)
    return np.concatenate([ij, np.zeros((ij.shape[0], 1), dtype=np.int64)], axis=1)


def volume_cells(cx: float, cy: float, reach, z_max: float, cell: float) -> np.ndarray:
    """(n, 3) volume cells down to ``z_max`` whose depth slab the cone reaches:
    ``reach(z)`` gives the radius at depth z (taken at the bottom of each slab)."""
    if z_max <= 0:
        return np.zeros((0, 3), dtype=np.int64)
    n_slabs = int(math.ceil(z_max / cell - 1e-9))
    out = []
    for l in range(n_slabs):
        r = float(reach(min((l + 1) * cell, z_max)))
        ij = cells_in_disc(cx, cy, r, cell)
        out.append(np.concatenate([ij, np.full((ij.shape[0], 1), l, dtype=np.int64)], axis=1))
    return np.concatenate(out) if out else np.zeros((0, 3), dtype=np.int64)
