"""Tests of the image products: background, normalisation and compression, detections,
tile files, quicklooks and the ``svss inspect`` / ``svss score`` commands.

Helpers shared by these tests live here.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from svss_proc.tiles import Tile

VOXEL = 0.02


def speckle(shape, rng, sigma: float = 1.0) -> np.ndarray:
    """Complex circular Gaussian noise, each part of standard deviation ``sigma``: its
    magnitude is Rayleigh distributed with median ``sigma * sqrt(2 ln 2)``."""
    return (sigma * (rng.standard_normal(shape) + 1j * rng.standard_normal(shape))
            ).astype(np.complex64)


def rayleigh_median(sigma: float) -> float:
    """Median of a Rayleigh magnitude whose complex parts have deviation ``sigma``."""
    return sigma * np.sqrt(2.0 * np.log(2.0))


def plant(image: np.ndarray, axes, centre_m, amplitude: float, width_vox: float = 1.2
          ) -> None:
    """Add a target: a 3-D Gaussian blob of peak ``amplitude`` (uPa) and deviation
    ``width_vox`` voxels centred at ``centre_m`` (along, cross, depth), in phase."""
    g = [np.exp(-0.5 * ((ax - c) / (width_vox * VOXEL)) ** 2) for ax, c in zip(axes, centre_m)]
    image += (amplitude * g[0][:, None, None] * g[1][None, :, None]
              * g[2][None, None, :]).astype(image.dtype)


def make_tile(grid, line, image: np.ndarray, pings=(), updates: int = 0) -> Tile:
    """A finished :class:`Tile` holding ``image`` (whichever way the imager stores it)."""
    names = {f.name for f in dataclasses.fields(Tile)}
    if "image" in names:
        return Tile(grid, line, image.astype(np.complex64), pings=list(pings),
                    updates=updates)
    return Tile(grid, line, np.ascontiguousarray(image.real, dtype=np.float32),
                np.ascontiguousarray(image.imag, dtype=np.float32), pings=list(pings),
                updates=updates)
