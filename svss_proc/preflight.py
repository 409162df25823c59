"""Checks made before imaging starts, for settings that cannot work on this machine: a
GPU asked for where there is none, tiles whose image planes do not fit in memory.
Each failure is a :class:`~svss_daq.config.ConfigError` naming the file and the keys."""

from __future__ import annotations

import logging
import os

import numpy as np

from svss_daq.config import ConfigError, ProcessingConfig

from .imaging.grid import n_voxels

log = logging.getLogger(__name__)

GIB = 1 << 30
#: bytes per voxel that finishing a tile takes on top of its image planes (the complex
#: image, its magnitude, the background and the compressed volume, float32 each, and
#: the background filter's work arrays)
PRODUCT_BYTES_PER_VOXEL = 24


def tile_voxels(proc: ProcessingConfig) -> int:
    """Voxels in one tile."""
    t = proc.tile
    return (n_voxels(t.length_m, t.voxel_m) * n_voxels(t.width_m, t.voxel_m)
            * n_voxels(t.depth_m, t.voxel_m))


def plane_bytes(proc: ProcessingConfig) -> int:
    """Bytes of one open tile's two image planes in the kernel precision."""
    return 2 * np.dtype(proc.imaging.precision).itemsize * tile_voxels(proc)


def product_bytes(proc: ProcessingConfig) -> int:
    """Bytes that finishing one tile takes on top of its planes."""
    return PRODUCT_BYTES_PER_VOXEL * tile_voxels(proc)


def max_open_tiles(proc: ProcessingConfig) -> int:
    """How many tiles fit in ``limits.memory_gib`` with one tile's products."""
    return int((proc.limits.memory_gib * GIB - product_bytes(proc)) // plane_bytes(proc))


def available_memory_bytes() -> int | None:
    """Memory the system can give now (MemAvailable), bytes; None where unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_memory(proc: ProcessingConfig, source: str) -> int:
    """Refuse tiles of which two (a ping straddles two tiles) with one tile's products
    exceed ``limits.memory_gib`` or the memory available now; return how many tiles may
    be open at once."""
    need = 2 * plane_bytes(proc) + product_bytes(proc)
    t = proc.tile
    what = (f"two tiles of {tile_voxels(proc):,} voxels ({t.length_m:g} x {t.width_m:g} x "
            f"{t.depth_m:g} m at tile.voxel_m = {t.voxel_m:g}, {proc.imaging.precision}) "
            f"and one tile's products need {need / GIB:.2f} GiB")
    if need > proc.limits.memory_gib * GIB:
        raise ConfigError(f"{source}: {what}, more than limits.memory_gib = "
                          f"{proc.limits.memory_gib:g}; use a larger tile.voxel_m or a "
                          "smaller tile")
    avail = available_memory_bytes()
    if avail is not None and need > avail:
        raise ConfigError(f"{source}: {what}, more than the {avail / GIB:.2f} GiB this "
                          "machine has available")
    return max_open_tiles(proc)


def check_device(proc: ProcessingConfig, source: str) -> None:
    """Refuse ``imaging.device = "cuda"`` where numba-cuda or a CUDA GPU is missing."""
    if proc.imaging.device != "cuda":
        return
    try:
        from numba import cuda
    except ImportError as exc:                               # pragma: no cover
        raise ConfigError(f"{source}: imaging.device = 'cuda' needs numba's CUDA support "
                          f"({exc})") from None
    try:
        ok = cuda.is_available()
    except Exception as exc:                                 # driver errors
        log.debug("cuda.is_available failed: %s", exc)
        ok = False
    if not ok:
        raise ConfigError(f"{source}: imaging.device = 'cuda' but no usable CUDA GPU is "
                          "present (install numba-cuda with pip install -e '.[gpu]' and a "
                          "driver, or set imaging.device = 'cpu')")


def preflight(proc: ProcessingConfig, source: str = "processing configuration") -> int:
    """Every check that must pass before imaging starts; returns how many tiles may be
    open at once (:func:`max_open_tiles`)."""
    check_device(proc, source)
    n = check_memory(proc, source)
    log.debug("preflight: up to %d open tiles within limits.memory_gib", n)
    return n
