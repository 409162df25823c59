"""Array geometry: receiver and projector positions in the body frame.

Body frame: x forward, y starboard, z down, origin at the vessel reference point.
The array frame has the same axes with its origin at the array reference point; the
lever arm ``lever_arms.array_m`` places it in the body frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .config import HardwareConfig, ReceiveArray
from .frames import TrackLine, body_to_ned
from .ping import NavSnapshot


def section_positions(array: ReceiveArray) -> list[np.ndarray]:
    """Element positions of each receive section in the array frame, m.

    Channels are numbered module by module, aft section first; within a section modules
    run port to starboard, and within a module channels run row by row (aft to
    forward), port to starboard. Each array is (rows * cols, 3).
    """
    p = array.pitch_m
    out = []
    for sec in array.sections:
        if sec.cols % array.module_cols or sec.rows % array.module_rows:
            raise ValueError(f"receive section '{sec.name}': {sec.rows} x {sec.cols} is not a "
                             f"whole number of {array.module_rows} x {array.module_cols} modules")
        xs = sec.center_m[0] + (np.arange(sec.rows) - (sec.rows - 1) / 2) * p
        ys = sec.center_m[1] + (np.arange(sec.cols) - (sec.cols - 1) / 2) * p
        pos = []
        for m_row in range(0, sec.rows, array.module_rows):
            for m_col in range(0, sec.cols, array.module_cols):
                for r in range(m_row, m_row + array.module_rows):
                    for c in range(m_col, m_col + array.module_cols):
                        pos.append((xs[r], ys[c], sec.center_m[2]))
        out.append(np.array(pos, dtype=np.float64))
    return out


@dataclass(frozen=True)
class ArrayGeometry:
    """Element positions in the body frame, m, and beam cones."""
    receivers: np.ndarray          # (n_channels, 3)
    projectors: np.ndarray         # (n_projectors, 3)
    boresight: np.ndarray          # (3,) unit vector, body frame
    projector_half_angle: float    # rad
    receiver_half_angle: float     # rad

    @property
    def n_channels(self) -> int:
        return self.receivers.shape[0]


def array_geometry(hw: HardwareConfig) -> ArrayGeometry:
    """Build the body-frame array geometry from the hardware configuration."""
    lever = np.asarray(hw.lever_arms.array_m, dtype=np.float64)
    rx = np.concatenate(section_positions(hw.receive_array)) + lever
    if rx.shape[0] != hw.digitiser.n_channels:
        raise ValueError(f"hardware: the receive array has {rx.shape[0]} elements but the "
                         f"digitiser has {hw.digitiser.n_channels} channels")
    tx = np.asarray(hw.projectors.positions_m, dtype=np.float64) + lever
    for i in hw.sequencer.projector_order:
        if not 0 <= i < tx.shape[0]:
            raise ValueError(f"hardware: sequencer.projector_order names projector {i}, "
                             f"expected 0..{tx.shape[0] - 1}")
    b = np.asarray(hw.beams.boresight, dtype=np.float64)
    norm = np.linalg.norm(b)
    if norm == 0:
        raise ValueError("hardware: beams.boresight must be a non-zero vector")
    return ArrayGeometry(rx, tx, b / norm, np.deg2rad(hw.beams.projector_half_angle_deg),
                         np.deg2rad(hw.beams.receiver_half_angle_deg))


@dataclass(frozen=True)
class PlacedArray:
    """One ping's elements in the tile frame (along, cross, depth below the interface)
    or, without a track line, the survey frame (north, east, down), m: projector (3,),
    receivers (n_channels, 3), boresight (3,) unit vector."""
    tx: np.ndarray
    rx: np.ndarray
    bore: np.ndarray
    projector: int


def place_array(geometry: ArrayGeometry, nav: NavSnapshot, projector: int,
                line: TrackLine | None = None) -> PlacedArray:
    """The array at pose ``nav`` with projector ``projector`` transmitting, in the tile
    frame of ``line`` (or the survey frame when ``line`` is None)."""
    if not 0 <= projector < geometry.projectors.shape[0]:
        raise ValueError(f"projector {projector} does not exist: the array has "
                         f"{geometry.projectors.shape[0]} (0..{geometry.projectors.shape[0] - 1})")
    rot = body_to_ned(nav.roll_rad, nav.pitch_rad, nav.heading_rad)
    origin = nav.ned
    if line is not None:
        rot = line.rotation_from_ned() @ rot
        origin = line.ned_to_tile(origin)
    return PlacedArray(origin + rot @ geometry.projectors[projector],
                       origin + geometry.receivers @ rot.T, rot @ geometry.boresight,
                       int(projector))


def cone_reach(height_m: float, bore_z: float, half_angle_rad: float) -> float:
    """Largest horizontal distance from the projector at which a point ``height_m``
    below it can lie inside the projector cone (half angle ``half_angle_rad`` about a
    boresight whose downward component is ``bore_z``), m; the cone's edge is taken no
    flatter than 89 degrees from the vertical. The one definition of the cone's reach
    (the schedule, the coverage count, the GPU launch and the trade's workloads)."""
    tilt = math.acos(max(-1.0, min(1.0, float(bore_z))))
    cone = min(half_angle_rad + tilt, math.radians(89.0))
    return cone_radius(height_m, math.tan(cone))


def cone_radius(height_m, tan_half_angle):
    """Radius of a vertical cone ``height_m`` below its apex (0 above it), m, given the
    tangent of its half-angle: :func:`cone_reach`'s, for callers that hold the tangent
    (the sidelobe footprint, the aperture fraction); arrays broadcast."""
    return np.maximum(height_m, 0.0) * tan_half_angle if isinstance(height_m, np.ndarray) \
        else max(0.0, float(height_m)) * float(tan_half_angle)
