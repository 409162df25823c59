"""A tile as the imager forms it: its grid and frame, the image's real and imaginary
planes, and what went into it (pings, track, coverage, poses, the sediment speed).
Pure data: :mod:`svss_proc.tiles` writes and reads tile files; the imaging core knows no
files."""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from svss_daq.frames import TrackLine

from .grid import TileGrid

if TYPE_CHECKING:
    from .coverage import Coverage


@dataclass
class Tile:
    """A tile being formed or finished: the image (real and imaginary planes in the
    kernel's precision while forming) and what went into it."""
    grid: TileGrid
    line: TrackLine
    re: np.ndarray
    im: np.ndarray
    pings: list[int] = field(default_factory=list)
    updates: int = 0
    #: which pings and channels reached each voxel (None: not computed)
    coverage: "Coverage | None" = None
    #: what the pings were posed with (provenance attribute ``poses``), e.g. "recorded
    #: live poses" or "re-navigated from N NMEA sentences and M PD0 ensembles"
    poses: str = ""
    #: the imaging method that made it, 'exact' or 'factorised' (provenance attribute
    #: ``imaging_method``; :mod:`svss_proc.imaging.factorised`)
    method: str = "exact"
    #: the run the tile belongs to (root attribute ``run_id``; "" unknown)
    run_id: str = ""
    #: the sediment speed it was imaged with and where it came from (provenance group
    #: ``seabed``'s attributes; :class:`svss_proc.seabed.speed.SpeedEstimate` summary)
    seabed: dict | None = None
    #: per ping of :attr:`pings`: (transmit time ns UTC, body origin north m, east m,
    #: the navigation's NAV_* flags ``nav.quality``); the flags may be left out (a
    #: 3-tuple: not known, no ``ping_nav_flags`` written)
    track: list[tuple] = field(default_factory=list)
    #: the next tile's first along-track planes, complete when this tile was: (magnitude,
    #: ping-channel pairs or None), for products without seams (None: not known)
    after: "tuple[np.ndarray, np.ndarray | None] | None" = None

    @functools.cached_property
    def image(self) -> np.ndarray:
        """The complex image (along x cross x depth), complex64, uPa; built once, when
        the tile is finished."""
        out = np.empty(self.re.shape, dtype=np.complex64)
        out.real = self.re
        out.imag = self.im
        return out

    def __getstate__(self) -> dict:
        """Pickled (handed to the products process) without the cached complex image:
        it is the planes again, built anew where it is needed."""
        state = self.__dict__.copy()
        state.pop("image", None)
        return state

    def to_host(self) -> "Tile":
        """Bring device-resident planes (GPU imaging) back to host memory."""
        if hasattr(self.re, "copy_to_host"):
            self.re, self.im = self.re.copy_to_host(), self.im.copy_to_host()
        if self.coverage is not None:
            self.coverage.to_host()
        return self
