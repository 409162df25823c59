"""The sediment-speed scan as a stage of ``svss process`` and ``svss batch``: a recorded
run's pings, posed as they are to be imaged, scanned (:func:`.speed.estimate_speed`),
and the processing configuration the run's tiles are imaged with (the estimate as the
half-space speed, or the configured speed where the echoes do not constrain it)."""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence

from svss_daq.config import Loaded, ProcessingConfig
from svss_daq.ping import NavSnapshot, Ping

from .per_tile import tile_speeds
from .relief import estimate_relief, with_relief
from .slope import estimate_slope, with_slope
from .speed import SpeedEstimate, configured_speed, estimate_speed, speed_wanted

log = logging.getLogger(__name__)

__all__ = ["RunPings", "seabed_stage"]


class RunPings(Sequence):
    """A recorded run's pings (its segment readers, in order) as a sequence read on
    demand, each with its pose of ``poses`` (None: as recorded)."""

    def __init__(self, readers, poses: list[NavSnapshot] | None = None):
        self._where = [(r, i) for r in readers for i in range(len(r))]
        self._poses = poses
        if poses is not None and len(poses) != len(self._where):
            raise ValueError(f"{len(poses)} poses for {len(self._where)} pings")

    def __len__(self) -> int:
        return len(self._where)

    def nav(self, k: int) -> NavSnapshot:
        """Ping ``k``'s pose, without reading its samples."""
        if self._poses is not None:
            return self._poses[k]
        r, i = self._where[k]
        return r.nav(i)

    def __getitem__(self, k: int) -> Ping:
        r, i = self._where[k]
        p = r.ping(i)
        if self._poses is not None:
            p = dataclasses.replace(p, nav=self._poses[k])
        return p


def shipped_settings():
    """config/processing.toml's ``[seabed]`` (for a configuration without the table)."""
    from svss_daq.config import ConfigError, config_path, load
    path = config_path("processing.toml")
    sb = load(ProcessingConfig, path).seabed
    if sb is None:
        raise ConfigError(f"{path}: no [seabed] table (the sediment-speed scan's settings)")
    return sb


def seabed_stage(readers, poses: list[NavSnapshot] | None,
                 processing: Loaded[ProcessingConfig], speed: str | None = None
                 ) -> tuple[Loaded[ProcessingConfig], SpeedEstimate]:
    """(the processing the run is imaged with, what the scan found). ``speed``:
    'estimate' or 'configured' (a command line's ``--sediment-speed``), None: the
    configuration's ``[seabed] speed``. The configuration's text (the tiles'
    provenance) is kept; the speed used is in the estimate (the manifest's and the
    tiles' ``seabed``)."""
    proc = processing.value
    configured = float(proc.imaging.sediment_sound_speed_m_s)
    if not speed_wanted(proc, speed):
        return processing, configured_speed(proc)
    if proc.seabed is None:                 # asked for by the command line: the
        proc = dataclasses.replace(proc, seabed=shipped_settings())   # shipped settings
    pings = RunPings(readers, poses)
    slope = relief = None
    if proc.seabed.slope == "estimate":
        slope = estimate_slope(pings, readers[0].hardware, proc)
        proc = with_slope(proc, slope.slope_deg)
    if proc.seabed.relief == "estimate":
        relief = estimate_relief(pings, readers[0].hardware, proc)
        proc = with_relief(proc, relief.summary())
    est = estimate_speed(pings, readers[0].hardware, proc)
    interface = {**(slope.summary() if slope is not None else {}),
                 **(relief.summary() if relief is not None else {})}
    tiles, disagree = tile_speeds(est.summary(), proc.tile)
    if tiles:
        interface.update(tiles=tiles, tiles_disagree=disagree)
    if interface:
        est = dataclasses.replace(est, slope=interface)
    log.info("%s: %s", readers[0].path, est.description)
    if disagree:
        log.warning("%s: the tiles' own sediment speeds disagree (%s): the run may cross "
                    "from one sediment into another; its tiles are imaged with %.0f m/s",
                    readers[0].path, ", ".join(f"tile {t['tile']}: {t['speed_m_s']:.0f} +/- "
                                               f"{t['sigma_m_s']:.0f}" for t in tiles),
                    est.speed_m_s)
    if est.disagrees:
        log.warning("%s: the configured sediment speed %.0f m/s disagrees with the "
                    "echoes' %.0f +/- %.0f m/s; imaged with the estimate",
                    readers[0].path, configured, est.speed_m_s, est.sigma_m_s)
    if est.status != "estimated" and not interface:
        return processing, est
    return dataclasses.replace(processing, value=est.apply(processing.value)), est
