"""The products of one tile as the chain (:mod:`.chain`) makes them and the tile file
(:mod:`svss_proc.tiles`) stores them: a plain record, so that neither of the two needs the
other to name it."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Products:
    """A tile's products. Volumes are along x cross x depth; ``background`` in uPa
    (None when not kept), ``level`` the normalised level in dB re background (no display
    gain), ``drc`` display values 0..1 (None when not kept), ``mips`` the maximum
    intensity projections (:data:`svss_proc.tiles.MIPS`) of level + gain (dB),
    ``detections`` a :data:`svss_proc.products.detect.DTYPE` table, ``timings`` seconds per
    stage; ``tail_profiles`` each contact's tail profile (docs/contact_features.md)."""
    method: str
    kernel_m: tuple[float, float, float]
    kernel_voxels: tuple[int, int, int]
    boundary: str
    ignore_zeros: bool
    max_error_db: float
    floor_upa: float
    background: np.ndarray | None
    level: np.ndarray
    gain_db: np.ndarray
    drc: np.ndarray | None
    mips: dict[str, np.ndarray]
    detections: np.ndarray
    drc_attrs: dict = field(default_factory=dict)
    detection_attrs: dict = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    #: each contact's tail profile (n x m, dB re background, from its peak down at
    #: ``tail_profile_step_m``; :mod:`.contact_features`), None when not measured
    tail_profiles: np.ndarray | None = None
    tail_profile_step_m: float = float("nan")
