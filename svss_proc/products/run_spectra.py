"""Each contact's resonance line from a run's recorded pings (docs/contact_features.md,
"Resonance lines from the pings"): the pings read again after the run is imaged, each
placed as the imaging placed it (:func:`~svss_proc.imaging.schedule.ping_frame` in the
tiles' frame, the poses the tiles were imaged with), conditioned only where its
projector cone holds a contact, and focused on the contacts it sees
(:mod:`.contact_spectra`)."""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Iterable

import numpy as np

from svss_daq.config import HardwareConfig, Loaded, ProcessingConfig, SpectraConfig
from svss_daq.frames import TrackLine
from svss_daq.geometry import array_geometry, place_array
from svss_daq.ping import Ping
from svss_daq.progress import Progress
from svss_daq.waveform import make_waveform

from ..conditioning import Conditioner
from ..imaging.delays import SpeedProfile
from ..imaging.imager import receive_apodisation
from ..imaging.schedule import ping_frame
from ..imaging.surface import InterfaceShape
from .contact_spectra import EchoCollector, Focus, contact_lines

log = logging.getLogger(__name__)


def run_spectra(pings: Iterable[Ping], hardware: Loaded[HardwareConfig],
                processing: ProcessingConfig, cfg: SpectraConfig, contacts: list[dict],
                line: TrackLine, total: int | None = None) -> list[dict]:
    """The :data:`~.contact_spectra.SPECTRA_FIELDS` of each of ``contacts`` (dicts with
    ``along_m``, ``cross_m`` in the run frame ``line`` and ``depth_below_seabed_m``),
    from ``pings`` imaged with ``processing`` (its speeds, conditioning, apodisation)."""
    hw = hardware.value
    geo = array_geometry(hw)
    im = processing.imaging
    conditioner = Conditioner(hw.digitiser, make_waveform(hw.waveform),
                              processing.conditioning.decimation, 1)
    profile = SpeedProfile.of(im)
    focus = Focus(im.water_sound_speed_m_s, im.sediment_sound_speed_m_s,
                  hw.waveform.center_hz, math.cos(geo.projector_half_angle),
                  math.cos(geo.receiver_half_angle),
                  receive_apodisation(geo.receivers, im.apodisation), cfg.start_s,
                  cfg.length_s, np.asarray(profile.tops, dtype=np.float64),
                  np.asarray(profile.speeds, dtype=np.float64))
    shape = InterfaceShape.of(im)           # the bed's slope and relief the tiles used
    points = [[c["along_m"], c["cross_m"], c["depth_below_seabed_m"]] for c in contacts]
    col = EchoCollector(points, focus, cfg.reference_m,
                        None if shape.level else shape.depth)
    t0, n, used = time.perf_counter(), 0, 0
    dt = None
    progress = Progress("resonance lines", total, log)
    for ping in pings:
        n += 1
        progress.update()
        placed = place_array(geo, ping.nav, ping.projector, ping_frame(line, ping.nav,
                                                                       processing))
        which = col.wants(placed.tx, placed.bore)
        if not which.size:
            continue
        c = conditioner.ping(ping)
        dt = c.dt_s
        used += 1
        col.add(c.data, c.t0_s, c.dt_s, placed.tx, placed.rx, placed.bore, which)
    band = (hw.waveform.f_start_hz, hw.waveform.f_stop_hz)
    # dt is None only where no ping saw any contact: then every contact has no series
    out = [contact_lines(e, dt or 1.0, hw.waveform.center_hz, band, cfg.min_pings,
                         cfg.max_lines, cfg.rel_threshold, r, cfg.min_over_background_db)
           for e, r in zip(col.echoes, col.references)]
    log.info("resonance lines of %d contact(s) from %d of %d ping(s) (%d with a line) in "
             "%.1f s", len(contacts), used, n,
             sum(math.isfinite(o["resonance_hz"]) for o in out), time.perf_counter() - t0)
    return out
