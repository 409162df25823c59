"""Multipath by image sources between a flat sea surface and a flat seabed.

Tile frame: z is the depth below the water-sediment interface (down positive); the flat
sea surface lies at z = -D (D the water depth) with pressure reflection coefficient R_s
(-1 for a flat air-water surface, the upper bound on multipath: Lowe & Brown 2012).

**Legs to a scatterer.** A leg joins an element (at z_e, -D < z_e < 0) and a point at or
below the seabed. Leaving the scatterer upwards, a leg with m reflections meets the
surface and the seabed alternately (S, B, S, ...); unfolding the path about each
boundary makes it straight, from the scatterer to an image of the element at

    z_m = -m D + z_e         (m even: the element is reached travelling up),
    z_m = -(m + 1) D - z_e   (m odd: reached travelling down, from above),

with ceil(m/2) surface and floor(m/2) seabed reflections. The ray's angle is the same at
every bounce of a flat guide, so each leg gains R_s^n_s R_b(theta)^n_b. An element sees a
leg in its main lobe (m even, boresight down) or its back lobe (m odd). Direct and image
legs of the transmitter and a receiver combine into a bistatic path; the *order* of a
path is the number of reflections it adds, m_tx + m_rx.

**Coherent returns.** The specular return of the seabed and its multiples are
reflection sequences between projector and receiver (e.g. B, SB, BS, BSB, ...); the
image of the projector for a sequence (r_1, ..., r_k) is M_rk(...M_r1(z_tx)) with
M_S(z) = -2D - z and M_B(z) = -z, and the path is the straight line from that image to
the receiver. A sequence of k reflections has order k - 1 (its first bottom bounce is
the direct return).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import product

import numpy as np


@dataclass(frozen=True)
class LegImage:
    """Image of an element for a leg with ``m`` reflections."""
    m: int
    n_surface: int
    n_bottom: int
    direction: float     # +1: the leg leaves the element downwards (main lobe), -1: up


def leg_image(m: int) -> LegImage:
    """Reflection counts and departure direction of a leg with m reflections."""
    if m < 0:
        raise ValueError("m must be >= 0")
    return LegImage(m, (m + 1) // 2, m // 2, 1.0 if m % 2 == 0 else -1.0)


def image_depth(m: int, z_element: np.ndarray | float, water_depth: float) -> np.ndarray:
    """Depth (tile frame, m) of the image of an element at ``z_element`` for a leg with
    ``m`` reflections (module docstring); m = 0 is the element itself."""
    z = np.asarray(z_element, dtype=np.float64)
    if m % 2 == 0:
        return -m * water_depth + z
    return -(m + 1) * water_depth - z


def max_leg_reflections(order: int, has_surface: bool, has_seabed: bool) -> int:
    """Largest m a leg may have: 0 without a surface; 1 without a seabed (no bottom
    bounce to continue the guide); else the order."""
    if not has_surface or order <= 0:
        return 0
    return min(order, 1) if not has_seabed else order


def leg_pairs(order: int, m_max: int) -> list[tuple[int, int]]:
    """All (m_tx, m_rx) with m_tx + m_rx <= order and each <= m_max, direct path first."""
    pairs = [(a, b) for a, b in product(range(m_max + 1), repeat=2) if a + b <= order]
    return sorted(pairs, key=lambda ab: (ab[0] + ab[1], ab))


def _mirror(z: float, boundary: str, water_depth: float) -> float:
    return -2.0 * water_depth - z if boundary == "S" else -z


@dataclass(frozen=True)
class CoherentPath:
    """A reflection sequence from projector to receiver (first reflection first)."""
    sequence: str

    @property
    def n_surface(self) -> int:
        return self.sequence.count("S")

    @property
    def n_bottom(self) -> int:
        return self.sequence.count("B")

    @property
    def order(self) -> int:
        return len(self.sequence) - 1

    @property
    def departure(self) -> float:
        """+1 if the path leaves the projector downwards, -1 upwards."""
        return 1.0 if self.sequence[0] == "B" else -1.0

    @property
    def arrival(self) -> float:
        """Direction from the receiver towards the last reflection: +1 down, -1 up."""
        return 1.0 if self.sequence[-1] == "B" else -1.0

    def image_depth(self, z_tx: float, water_depth: float) -> float:
        """Depth of the projector's image for this sequence (tile frame, m)."""
        z = z_tx
        for b in self.sequence:
            z = _mirror(z, b, water_depth)
        return z


def coherent_paths(order: int, has_surface: bool) -> list[CoherentPath]:
    """Reflection sequences with at least one seabed bounce and at most order + 1
    reflections (alternating S and B); without a surface only 'B'."""
    if not has_surface:
        return [CoherentPath("B")]
    out = []
    for k in range(1, order + 2):
        for first in "BS":
            seq = "".join(first if i % 2 == 0 else ("S" if first == "B" else "B")
                          for i in range(k))
            if "B" in seq:
                out.append(CoherentPath(seq))
    return out
