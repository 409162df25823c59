"""Raw-run files: HDF5 laid out after the ICES SONAR-netCDF4 convention where it applies.

Layout (see docs/formats.md)::

    /                       attrs: Conventions, svss_format, svss_format_version, the
                            run's attributes (title, run_id, sonar, ...)
    /Sonar/Beam_group1      backscatter_r (ping_time x beam x sample, int32 codes),
                            ping_time (int64 ns), ping_sequence, transmit_projector,
                            window_start_ns; attrs sample_rate_hz, ...
    /Platform               time1 (int64 ns) and the navigation snapshot of each ping
    /Platform/NMEA          time (int64 ns), sentence (raw NMEA text)
    /Platform/PD0           time (int64 ns), offset, n_bytes: each PD0 ensemble as received,
                            its bytes at ``stream[offset:offset + n_bytes]`` (absent in
                            files written before it was kept)
    /Platform/ping_clock    receive_time, transmit_time (int64 ns): the sequencer's
                            transmit records as received, the ping clock on the host's
                            (absent in files written before it was kept)
    /Environment            attrs: scene or measured environment
    /Provenance             attrs: software, creation time; hardware configuration text
    /Vendor_specific        hardware configuration text and its id; ``events`` (time,
                            kind, detail of every device fault and recovery the
                            acquisition daemon saw); root attribute
                            ``acquisition_summary`` (JSON counters, written at close)

Version 2 (:data:`FORMAT_VERSION`) opens as netCDF-4 (``xarray.open_dataset(path,
group="Sonar/Beam_group1", engine="h5netcdf")``): every dataset has named dimensions
(HDF5 dimension scales, :func:`_dims`), every variable ``units`` and ``long_name``, and
every time variable CF units (:data:`TIME_UNITS`, decoded to datetime64). Version 1
files (the same datasets without them) still read.

Every dataset is chunked by ping and appended ping by ping. The writer runs in HDF5's
single-writer/multiple-reader mode, so the file on disk is consistent at every flush: a
writer killed mid-run leaves a file readable up to its last flush (pings after it are
lost, nothing before it). Flushes happen every ``flush_every_pings`` pings and at least
every ``flush_interval_s`` seconds; after each successful flush the writer records the
number of pings then on disk in ``/Sonar/Beam_group1/pings_flushed``, which a reader
takes as an upper bound. A write or flush that fails (a full disk) stops the writer with
a :class:`RawFileError`; what was flushed before stays readable.

Files are untrusted: a reader checks the HDF5 superblock's end-of-file address against
the file's size before opening it, bounds HDF5's metadata read retries, validates the
layout (groups, datasets, shapes, dtypes, attributes) up front and turns every failure
into a :class:`RawFileError` naming the file and the path (with the pieces of
:mod:`svss_daq.untrusted_hdf5`, which the tile reader shares).
"""

from __future__ import annotations

import contextlib
import functools
import json
import logging
import os
import time
from pathlib import Path

import h5py
import numpy as np

from . import __version__
from .config import ConfigError, HardwareConfig, Loaded, loaded_from_text
from .ping import NAV_FIELDS, NavSnapshot, Ping
from .signals import deferred_stop
from .untrusted_hdf5 import (H5_ERRORS, abandon, cause, dataset, format_version, group,
                             hdf5_superblock, in_child, open_swmr, shown, text)

log = logging.getLogger(__name__)

FORMAT = "svss-raw"
#: 2: netCDF-4 dimension scales, CF time units, units and long names (docs/formats.md)
FORMAT_VERSION = 2
READABLE_VERSIONS = (1, 2)
#: CF units of every time variable (int64 ns since the Unix epoch, UTC), as SONAR-netCDF4
TIME_UNITS = "nanoseconds since 1970-01-01 00:00:00Z"
#: the SONAR-netCDF4 version whose structure the file follows (deviations: docs/formats.md)
SONAR_NETCDF4_VERSION = "2.0"
#: root attributes the writer sets itself (the rest are the run's: run_id, segment, ...)
WRITER_ATTRS = ("Conventions", "sonar_convention_authority", "sonar_convention_name",
                "sonar_convention_version", "svss_format", "svss_format_version", "title",
                "summary", "date_created", "sonar_model", "hardware_config_id",
                "software_name", "software_version")
#: the name HDF5 dimension scales of netCDF-4 give a dimension that has no variable
_NOT_A_VARIABLE = "This is a netCDF dimension but not a netCDF variable."
BEAM = "Sonar/Beam_group1"
NMEA_LEN = 96
#: the instrument records a run keeps for re-navigation (docs/formats.md)
PD0 = "Platform/PD0"
#: bytes per chunk of the concatenated PD0 stream
PD0_CHUNK = 1 << 12
#: the ping-clock events (the sequencer's transmit records) as received
PING_CLOCK = "Platform/ping_clock"
#: root attribute: the navigation configuration (devices [navigation] table) the
#: acquisition daemon posed the pings with
NAV_CONFIG_ATTR = "navigation_config_toml"
EVENT_KIND_LEN = 32
EVENT_DETAIL_LEN = 200
EVENTS = "Vendor_specific/events"
#: 1-element int64: pings known to be on disk (written after each successful flush)
FLUSHED = f"{BEAM}/pings_flushed"

_PER_PING = {  # name: (dtype, long name, units)
    "ping_time": ("<i8", "transmit time of the ping (UTC)", TIME_UNITS),
    "ping_sequence": ("<i8", "ping sequence number", "1"),
    "transmit_projector": ("<i2", "index of the projector that transmitted", "1"),
    "window_start_ns": ("<i8", "receive-window start after transmit", "ns"),
}
#: units of the navigation snapshot's fields (``/Platform``), by name
_NAV_UNITS = {"north_m": "m", "east_m": "m", "down_m": "m", "vel_north_m_s": "m/s",
              "vel_east_m_s": "m/s", "vel_down_m_s": "m/s", "roll_rad": "rad",
              "pitch_rad": "rad", "heading_rad": "rad", "altitude_m": "m",
              "latitude_deg": "degrees_north", "longitude_deg": "degrees_east",
              "quality": "1"}
#: CF standard names of the navigation snapshot's fields that have one
_NAV_STANDARD_NAMES = {"latitude_deg": "latitude", "longitude_deg": "longitude",
                       "heading_rad": "platform_orientation", "roll_rad": "platform_roll",
                       "pitch_rad": "platform_pitch"}
_NAV_LONG_NAMES = {
    "north_m": "north of the body origin in the survey frame (local NED)",
    "east_m": "east of the body origin in the survey frame (local NED)",
    "down_m": "down of the body origin in the survey frame (local NED)",
    "vel_north_m_s": "velocity north", "vel_east_m_s": "velocity east",
    "vel_down_m_s": "velocity down",
    "roll_rad": "roll, starboard down positive (ZYX Euler)",
    "pitch_rad": "pitch, nose up positive (ZYX Euler)",
    "heading_rad": "heading from true north (ZYX Euler)",
    "altitude_m": "altitude of the body origin above the water-sediment interface",
    "latitude_deg": "WGS-84 latitude of the body origin (NaN: unknown)",
    "longitude_deg": "WGS-84 longitude of the body origin (NaN: unknown)",
    "quality": "navigation quality bit flags (svss_daq/ping.py NAV_*)"}


class RawFileError(ValueError):
    """A raw-run file that cannot be read (or written) as such."""




def _appendable(group: h5py.Group, name: str, dtype, shape_tail=(), chunk=1024, doc="",
                units: str | None = None):
    ds = group.create_dataset(name, shape=(0, *shape_tail), maxshape=(None, *shape_tail),
                              dtype=dtype, chunks=(chunk, *shape_tail))
    if doc:
        ds.attrs["long_name"] = doc
    if units is not None:
        ds.attrs["units"] = units
    if units == TIME_UNITS:
        ds.attrs.update({"standard_name": "time", "calendar": "standard", "axis": "T"})
    return ds


def _dimension(group: h5py.Group, name: str, size: int | None) -> h5py.Dataset:
    """A netCDF-4 dimension without a variable (``size`` None: unlimited): an empty
    dimension scale named as netCDF-4 names them, which netCDF readers show as a
    dimension only."""
    ds = group.create_dataset(name, shape=(size or 0,),
                              maxshape=(None if size is None else size,), dtype="<f4",
                              chunks=(1024,) if size is None else None)
    ds.make_scale(f"{_NOT_A_VARIABLE}{size or 0:10d}")
    return ds


def _dims(ds: h5py.Dataset, *scales: h5py.Dataset) -> None:
    """Name the dimensions of ``ds`` by attaching the dimension scales ``scales``
    (one per axis), as netCDF-4 does."""
    for axis, scale in enumerate(scales):
        ds.dims[axis].attach_scale(scale)


def _coordinate(ds: h5py.Dataset, name: str) -> h5py.Dataset:
    """Make ``ds`` the coordinate variable of its own dimension ``name``."""
    ds.make_scale(name)
    return ds


def _whole(method):
    """A writer's method that a stop signal does not cut: a KeyboardInterrupt landing
    inside HDF5 comes out of h5py as an HDF5 error (the file then failed, the command's
    exit 1 instead of 130); the signal is raised once the write is whole
    (:func:`~svss_daq.signals.deferred_stop`)."""
    @functools.wraps(method)
    def whole(self, *args, **kwargs):
        with deferred_stop():
            return method(self, *args, **kwargs)
    return whole


class RawRunWriter:
    """Append pings (and the raw NMEA sentences and PD0 ensembles the navigation used)
    to a new raw-run file.

    Use as a context manager. ``hardware`` is the loaded hardware configuration (its
    text is stored for provenance and reprocessing). An existing file is refused unless
    ``overwrite``. A write or flush that fails (a full disk) raises :class:`RawFileError`
    naming the file, the ping and the cause, and stops the writer: the pings flushed
    before (``n_flushed``) stay readable and nothing more is written.
    """

    @_whole
    def __init__(self, path: str | Path, hardware: Loaded[HardwareConfig], *,
                 flush_every_pings: int = 10, flush_interval_s: float = 1.0,
                 environment: dict | None = None, run_attrs: dict | None = None,
                 overwrite: bool = False):
        self.path = Path(path)
        self.hardware = hardware
        self.flush_every = int(flush_every_pings)
        self.flush_interval = float(flush_interval_s)
        dig = hardware.value.digitiser
        self.n_channels, self.n_samples = dig.n_channels, dig.window_samples
        self.n_pings = 0
        self.n_flushed = 0
        self.failed: str | None = None
        if self.path.exists() and not overwrite:
            raise RawFileError(f"{self.path}: already exists; not overwriting it (pass "
                               "--force to replace it)")
        try:
            self._f = h5py.File(self.path, "w" if overwrite else "w-", libver="latest")
        except H5_ERRORS as exc:
            raise RawFileError(f"{self.path}: cannot create ({exc})") from None
        try:
            self._create(hardware, environment, run_attrs)
        except H5_ERRORS as exc:
            abandon(self._f)
            self.path.unlink(missing_ok=True)       # nothing in it worth keeping
            raise RawFileError(f"{self.path}: writing the run's header failed "
                               f"({cause(exc)}); no file written") from None
        except BaseException:                   # a signal mid-header: no half-made file
            abandon(self._f)
            self.path.unlink(missing_ok=True)
            raise
        self._last_flush = time.monotonic()

    def _create(self, hardware, environment, run_attrs) -> None:
        dig = hardware.value.digitiser
        f = self._f
        created = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        f.attrs.update({
            "Conventions": "CF-1.8, ACDD-1.3",
            "sonar_convention_authority": "ICES",
            "sonar_convention_name": "SONAR-netCDF4",
            "sonar_convention_version": SONAR_NETCDF4_VERSION,
            "svss_format": FORMAT, "svss_format_version": FORMAT_VERSION,
            "title": f"SVSS raw run ({hardware.value.name})",
            "summary": ("Raw element-level ADC samples of every ping of a Sediment Volume "
                        "Search Sonar run, with the navigation of each ping and the "
                        "instrument records it was computed from"),
            "date_created": created, "sonar_model": hardware.value.name,
            "hardware_config_id": hardware.id,
            "software_name": "svss", "software_version": __version__})
        for k, v in (run_attrs or {}).items():
            f.attrs[k] = v
        sonar = f.create_group("Sonar")
        sonar.attrs.update({"sonar_manufacturer": "ARL/PSU (SVSS)",
                            "sonar_model": hardware.value.name})
        beam = f.create_group(BEAM)
        beam.attrs.update({"sample_rate_hz": dig.sample_rate_hz,
                           "beam_mode": "element", "conversion_equation_type": "counts",
                           "adc_bits": dig.bits})
        self._per_ping = {k: _appendable(beam, k, dt, doc=doc, units=units)
                          for k, (dt, doc, units) in _PER_PING.items()}
        ping_time = _coordinate(self._per_ping["ping_time"], "ping_time")
        channel = _coordinate(beam.create_dataset(
            "beam", data=np.arange(self.n_channels, dtype="<i4")), "beam")
        channel.attrs.update({"long_name": "receive channel (element) number",
                              "units": "1"})
        sample = _coordinate(beam.create_dataset(
            "sample", data=np.arange(self.n_samples, dtype="<i4")), "sample")
        sample.attrs.update({"long_name": ("sample number in the receive window (time "
                                           "after transmit: window_start_ns + sample / "
                                           "sample_rate_hz)"), "units": "1"})
        # one chunk per ping, each with HDF5's Fletcher-32 checksum: a ping damaged on
        # disk is found (and named) on reading, not imaged
        self._samples = beam.create_dataset(
            "backscatter_r", shape=(0, self.n_channels, self.n_samples),
            maxshape=(None, self.n_channels, self.n_samples), dtype="<i4",
            chunks=(1, self.n_channels, self.n_samples), fletcher32=True)
        self._samples.attrs.update({"long_name": "raw ADC codes (24-bit carried in int32)",
                                    "units": "1"})
        _dims(self._samples, ping_time, channel, sample)
        for k, ds in self._per_ping.items():
            if k != "ping_time":
                _dims(ds, ping_time)
        plat = f.create_group("Platform")
        time1 = _coordinate(_appendable(plat, "time1", "<i8", units=TIME_UNITS,
                                        doc="navigation snapshot time (UTC)"), "time1")
        self._nav = {"time1": time1}
        for name in NAV_FIELDS:
            if name == "time_ns":
                continue
            ds = _appendable(plat, name, "<i8" if name == "quality" else "<f8",
                             doc=_NAV_LONG_NAMES[name], units=_NAV_UNITS[name])
            if name in _NAV_STANDARD_NAMES:          # CF: what a GIS tool looks for
                ds.attrs["standard_name"] = _NAV_STANDARD_NAMES[name]
            _dims(ds, time1)
            self._nav[name] = ds
        nmea = plat.create_group("NMEA")
        self._nmea_time = _coordinate(_appendable(nmea, "time", "<i8", units=TIME_UNITS,
                                                  doc="host receive time (UTC)"), "time")
        self._nmea_text = _appendable(nmea, "sentence", f"S{NMEA_LEN}", units="1",
                                      doc="raw NMEA 0183 sentence")
        self._nmea_text.attrs["_Encoding"] = "ascii"      # text in netCDF readers
        _dims(self._nmea_text, self._nmea_time)
        pd0 = plat.create_group("PD0")
        pd0.attrs["long_name"] = ("Teledyne RDI PD0 ensembles as received from the DVL "
                                  "(header to checksum), for re-navigation")
        self._pd0_stream = _appendable(pd0, "stream", "u1", chunk=PD0_CHUNK, units="1",
                                       doc="the ensembles' bytes, concatenated")
        _dims(self._pd0_stream, _dimension(pd0, "stream_byte", None))
        self._pd0_time = _coordinate(_appendable(pd0, "time", "<i8", chunk=256,
                                                 units=TIME_UNITS,
                                                 doc="host receive time (UTC)"), "time")
        self._pd0_offset = _appendable(pd0, "offset", "<i8", chunk=256, units="1",
                                       doc="byte offset of the ensemble in 'stream'")
        self._pd0_size = _appendable(pd0, "n_bytes", "<i4", chunk=256, units="1",
                                     doc="length of the ensemble, bytes")
        _dims(self._pd0_offset, self._pd0_time)
        _dims(self._pd0_size, self._pd0_time)
        clock = plat.create_group("ping_clock")
        clock.attrs["long_name"] = ("ping-clock events as the host received them (the "
                                    "sequencer's transmit records): instrument clocks are "
                                    "judged against the ping clock through them")
        self._clock_rx = _coordinate(_appendable(
            clock, "receive_time", "<i8", chunk=256, units=TIME_UNITS,
            doc="host receive time of the transmit record (UTC)"), "receive_time")
        self._clock_ping = _appendable(clock, "transmit_time", "<i8", chunk=256,
                                       units=TIME_UNITS,
                                       doc="transmit time on the ping clock (UTC)")
        _dims(self._clock_ping, self._clock_rx)
        env = f.create_group("Environment")
        for k, v in (environment or {}).items():
            env.attrs[k] = v
        prov = f.create_group("Provenance")
        prov.attrs.update({"software_name": "svss", "software_version": __version__,
                           "creation_time_utc": created})
        vendor = f.create_group("Vendor_specific")
        # kept open until the flush below: closing a dataset whose (sieve-buffered) data
        # cannot be written fails inside h5py's finaliser, where nobody sees it
        self._text = vendor.create_dataset("hardware_config_toml", data=hardware.text)
        self._text.attrs.update({"long_name": "hardware configuration (TOML) of the run",
                                 "units": "1"})
        vendor.attrs["hardware_config_id"] = hardware.id
        vendor.attrs["hardware_config_source"] = hardware.source
        events = vendor.create_group("events")
        events.attrs["long_name"] = ("device faults and recoveries seen while recording "
                                     "(svss acquire)")
        ev_time = _coordinate(_appendable(events, "time", "<i8", chunk=64, units=TIME_UNITS,
                                          doc="event time (UTC)"), "time")
        self._events = (ev_time,
                        _appendable(events, "kind", f"S{EVENT_KIND_LEN}", chunk=64,
                                    units="1", doc="event kind, e.g. digitiser.reconnect"),
                        _appendable(events, "detail", f"S{EVENT_DETAIL_LEN}", chunk=64,
                                    units="1", doc="what happened"))
        for ds in self._events[1:]:
            _dims(ds, ev_time)
            ds.attrs["_Encoding"] = "utf-8"   # netCDF/xarray read them as text, not bytes
        # created before SWMR mode, which forbids new objects
        self._flushed = beam.create_dataset("pings_flushed", data=np.zeros(1, "<i8"))
        self._flushed.attrs.update({"long_name": ("pings known to be on disk: written after "
                                                  "each successful flush; a reader reads "
                                                  "no more"), "units": "1"})
        _dims(self._flushed, _dimension(beam, "flush_count", 1))
        f.flush()
        f.swmr_mode = True

    def _check_usable(self) -> None:
        if self.failed:
            raise RawFileError(f"{self.path}: the writer stopped after an earlier failure "
                               f"({self.failed}); {self.n_flushed} pings are on disk")

    def _fail(self, what: str, exc: Exception) -> RawFileError:
        """Stop the writer after a failed write: close the file without writing more."""
        cause = " ".join(str(exc).split())
        self.failed = f"{what} failed: {cause}"
        abandon(self._f)
        err = RawFileError(f"{self.path}: {what} failed ({cause}); the writer stopped, "
                           f"{self.n_flushed} pings are safely on disk")
        log.error("%s", err)
        return err

    @_whole
    def append(self, ping: Ping) -> None:
        """Append one ping; flushes according to the policy."""
        self._check_usable()
        if ping.samples.shape != (self.n_channels, self.n_samples):
            raise ValueError(f"{self.path}: ping {ping.sequence} has samples of shape "
                             f"{ping.samples.shape}; this run records "
                             f"{(self.n_channels, self.n_samples)}")
        if ping.config_id and ping.config_id != self.hardware.id:
            raise ValueError(f"{self.path}: ping {ping.sequence} was acquired with hardware "
                             f"config {ping.config_id}, this run records {self.hardware.id}")
        i = self.n_pings
        try:
            # samples first, ping_time last: a reader takes the shortest dataset as the count
            self._samples.resize(i + 1, axis=0)
            self._samples[i] = ping.samples
            nav = ping.nav
            for name, ds in self._nav.items():
                ds.resize(i + 1, axis=0)
                ds[i] = nav.time_ns if name == "time1" else getattr(nav, name)
            values = {"ping_sequence": ping.sequence, "transmit_projector": ping.projector,
                      "window_start_ns": ping.window_start_ns,
                      "ping_time": ping.transmit_time_ns}
            for name, ds in self._per_ping.items():
                ds.resize(i + 1, axis=0)
                ds[i] = values[name]
        except H5_ERRORS as exc:
            raise self._fail(f"writing ping {ping.sequence}", exc) from None
        self.n_pings += 1
        if (self.n_pings - self.n_flushed >= self.flush_every
                or time.monotonic() - self._last_flush >= self.flush_interval):
            self.flush()

    @_whole
    def append_nmea(self, time_ns: int, sentence: str) -> None:
        """Record one raw NMEA sentence (truncated to 96 bytes)."""
        self._check_usable()
        raw = sentence.strip().encode("ascii", "replace")[:NMEA_LEN]
        try:
            i = self._nmea_time.shape[0]
            self._nmea_text.resize(i + 1, axis=0)
            self._nmea_text[i] = raw
            self._nmea_time.resize(i + 1, axis=0)
            self._nmea_time[i] = time_ns
        except H5_ERRORS as exc:
            raise self._fail(f"writing NMEA sentence {i}", exc) from None

    @_whole
    def append_pd0(self, time_ns: int, ensemble: bytes) -> None:
        """Record one PD0 ensemble as received (its bytes, header to checksum) with its
        host receive time; durable at the next flush."""
        self._check_usable()
        data = np.frombuffer(bytes(ensemble), dtype=np.uint8)
        if data.size == 0:
            raise ValueError(f"{self.path}: an empty PD0 ensemble")
        i = self._pd0_time.shape[0]
        try:
            # bytes first, time last: a reader takes the shortest index as the count
            start = self._pd0_stream.shape[0]
            self._pd0_stream.resize(start + data.size, axis=0)
            self._pd0_stream[start:] = data
            for ds, v in ((self._pd0_offset, start), (self._pd0_size, data.size),
                          (self._pd0_time, int(time_ns))):
                ds.resize(i + 1, axis=0)
                ds[i] = v
        except H5_ERRORS as exc:
            raise self._fail(f"writing PD0 ensemble {i}", exc) from None

    @_whole
    def append_clock_reference(self, receive_ns: int, transmit_ns: int) -> None:
        """Record one ping-clock event: a transmit record of ping time ``transmit_ns``
        received at host time ``receive_ns``; durable at the next flush."""
        self._check_usable()
        i = self._clock_rx.shape[0]
        try:
            for ds, v in ((self._clock_ping, int(transmit_ns)), (self._clock_rx,
                                                                  int(receive_ns))):
                ds.resize(i + 1, axis=0)
                ds[i] = v
        except H5_ERRORS as exc:
            raise self._fail(f"writing ping-clock event {i}", exc) from None

    @_whole
    def append_event(self, time_ns: int, kind: str, detail: str) -> None:
        """Record one device event (kind up to 32, detail up to 200 bytes, truncated);
        durable at the next flush."""
        self._check_usable()
        times, kinds, details = self._events
        i = times.shape[0]
        try:
            for ds, v in ((kinds, kind.encode("ascii", "replace")[:EVENT_KIND_LEN]),
                          (details, detail.encode("ascii", "replace")[:EVENT_DETAIL_LEN]),
                          (times, int(time_ns))):
                ds.resize(i + 1, axis=0)
                ds[i] = v
        except H5_ERRORS as exc:
            raise self._fail(f"writing event {i} ({kind})", exc) from None

    def read_ping(self, i: int) -> Ping:
        """Ping ``i`` of this file as written so far (for a catch-up service in the
        writing process)."""
        if not 0 <= i < self.n_pings:
            raise IndexError(f"{self.path}: ping {i} out of range 0..{self.n_pings - 1}")
        self._check_usable()
        try:
            nav = {name: ds[i].item() for name, ds in self._nav.items()}
            meta = {name: int(ds[i]) for name, ds in self._per_ping.items()}
            samples = self._samples[i]
        except H5_ERRORS as exc:
            raise RawFileError(f"{self.path}: reading back ping {i} failed "
                               f"({cause(exc)})") from None
        nav["time_ns"] = int(nav.pop("time1"))
        nav["quality"] = int(nav["quality"])
        return Ping(sequence=meta["ping_sequence"], projector=meta["transmit_projector"],
                    transmit_time_ns=meta["ping_time"],
                    sample_rate_hz=float(self.hardware.value.digitiser.sample_rate_hz),
                    window_start_ns=meta["window_start_ns"], samples=samples,
                    nav=NavSnapshot(**nav), config_id=self.hardware.id)

    @_whole
    def flush(self) -> None:
        """Make everything appended so far durable on disk, then record the count of
        pings on disk (``pings_flushed``)."""
        self._check_usable()
        try:
            self._f.flush()
            self._flushed[0] = self.n_pings
            self._f.flush()
        except H5_ERRORS as exc:
            last = f"pings {self.n_flushed}..{self.n_pings - 1}" \
                if self.n_pings > self.n_flushed else "the run's records"
            raise self._fail(f"flushing {last}", exc) from None
        self.n_flushed = self.n_pings
        self._last_flush = time.monotonic()

    @_whole
    def close(self) -> None:
        """Flush and close the file (after a failure: only release it)."""
        if self.failed or not self._f.id.valid:
            abandon(self._f)
            return
        self.flush()
        try:
            self._f.close()
        except H5_ERRORS as exc:
            raise self._fail("closing the file", exc) from None
        log.info("closed %s: %d pings", self.path, self.n_pings)

    def __enter__(self) -> "RawRunWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def write_summary(path: str | Path, summary: dict) -> None:
    """Store ``summary`` (JSON) as the root attribute ``acquisition_summary`` of a raw
    run whose writer has closed it."""
    import json
    try:
        with h5py.File(path, "a") as f:
            f.attrs["acquisition_summary"] = json.dumps(summary, sort_keys=True)
    except H5_ERRORS as exc:
        raise RawFileError(f"{path}: writing the acquisition summary failed "
                           f"({cause(exc)})") from None


#: the largest summary file beside a raw run a reader reads, bytes
MAX_SUMMARY_BYTES = 1 << 20


def summary_path(path: str | Path) -> Path:
    """Where the acquisition summary of the raw run ``path`` lies when its file could
    not take it (a writer stopped by a full disk): ``<stem>.summary.json`` beside it."""
    path = Path(path)
    return path.with_name(path.stem + ".summary.json")


def write_summary_beside(path: str | Path, summary: dict) -> Path:
    """Store ``summary`` (JSON) in :func:`summary_path` of ``path`` (atomically: a
    temporary file renamed); its path. :class:`RawFileError` naming it on failure."""
    import json
    side = summary_path(path)
    tmp = side.with_name(side.name + ".partial")
    try:
        with open(tmp, "w") as fh:
            fh.write(json.dumps(summary, sort_keys=True))
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, side)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise RawFileError(f"{side}: writing the acquisition summary of {Path(path).name} "
                           f"failed ({exc.strerror or exc})") from None
    return side


def _rot32(x: int, k: int) -> int:
    return ((x << k) | (x >> (32 - k))) & 0xFFFFFFFF


def lookup3(data: bytes, initval: int = 0) -> int:
    """Bob Jenkins' lookup3 ``hashlittle`` of ``data``: the checksum HDF5 stores at the
    end of a version 2 or 3 superblock (``H5_checksum_lookup3``)."""
    m = 0xFFFFFFFF
    n = len(data)
    abc = [(0xDEADBEEF + n + initval) & m] * 3
    padded = data + bytes(-n % 12)
    words = [int.from_bytes(padded[i:i + 4], "little") for i in range(0, len(padded), 4)]

    def step(x, y, z, k):            # x -= z; x ^= rot(z, k); z += y
        abc[x] = ((abc[x] - abc[z]) & m) ^ _rot32(abc[z], k)
        abc[z] = (abc[z] + abc[y]) & m

    def final(x, y, k):              # x ^= y; x -= rot(y, k)
        abc[x] = ((abc[x] ^ abc[y]) - _rot32(abc[y], k)) & m

    k = 0
    while n - 4 * k > 12:
        abc = [(v + w) & m for v, w in zip(abc, words[k:k + 3])]
        for x, y, z, r in ((0, 1, 2, 4), (1, 2, 0, 6), (2, 0, 1, 8), (0, 1, 2, 16),
                           (1, 2, 0, 19), (2, 0, 1, 4)):
            step(x, y, z, r)
        k += 3
    if n - 4 * k == 0:
        return abc[2]
    abc = [(v + w) & m for v, w in zip(abc, words[k:k + 3])]
    for x, y, r in ((2, 1, 14), (0, 2, 11), (1, 0, 25), (2, 1, 16), (0, 2, 4), (1, 0, 14),
                    (2, 1, 24)):
        final(x, y, r)
    return abc[2]


def _clear_open_flags(path: Path) -> None:
    """What ``h5clear -s --increment`` does to a file whose writer died: the superblock's
    file consistency flags cleared (open for writing, SWMR writing) and its end-of-file
    address raised to the file's size (so that nothing HDF5 allocates next lands on
    bytes the dead writer left), the superblock's checksum recomputed. Version 2 and 3
    superblocks only (what :class:`RawRunWriter` writes); :class:`RawFileError`
    otherwise."""
    sb = hdf5_superblock(path, RawFileError)
    if sb["version"] not in (2, 3):
        raise RawFileError(f"{path}: HDF5 superblock version {sb['version']}; only "
                           "versions 2 and 3 can be closed here")
    off = sb["offset"]
    with open(path, "r+b") as fh:
        fh.seek(off)
        head = bytearray(fh.read(48))
        n_off = head[9]
        end = 12 + 4 * n_off               # signature .. root object header address
        if n_off != 8 or len(head) < end + 4:
            raise RawFileError(f"{path}: HDF5 superblock with {n_off}-byte addresses; "
                               "only 8-byte addresses can be closed here")
        stored = int.from_bytes(head[end:end + 4], "little")
        if lookup3(bytes(head[:end])) != stored:
            raise RawFileError(f"{path}: HDF5 superblock checksum does not match; the "
                               "file is left as it is")
        eoa_at = 12 + 2 * n_off
        base = int.from_bytes(head[12:12 + n_off], "little")
        eoa = int.from_bytes(head[eoa_at:eoa_at + n_off], "little")
        head[11] = 0
        head[eoa_at:eoa_at + n_off] = max(eoa, sb["size"] - base).to_bytes(n_off, "little")
        head[end:end + 4] = lookup3(bytes(head[:end])).to_bytes(4, "little")
        fh.seek(off)
        fh.write(head[:end + 4])
        fh.flush()
        os.fsync(fh.fileno())


def close_interrupted(path: str | Path, summary: dict) -> str:
    """Close the segment ``path`` of a writer that died (a daemon killed mid-run) and
    mark it: its open-for-writing flags cleared (:func:`_clear_open_flags`; every
    flushed ping stays as it was) and ``summary`` (saying it was interrupted) stored as
    its ``acquisition_summary``. A file that cannot be closed so is left untouched and
    gets the summary beside it (:func:`write_summary_beside`). Returns ``"closed"`` or
    ``"beside"``; :class:`RawFileError` when neither could be written."""
    path = Path(path)
    try:
        if hdf5_superblock(path, RawFileError)["flags"] & 1:
            _clear_open_flags(path)
        write_summary(path, summary)
        return "closed"
    except (RawFileError, OSError) as exc:
        log.warning("%s: not closed (%s); its summary goes beside it", path, exc)
    write_summary_beside(path, summary)
    return "beside"


def _open_for_reading(path: Path) -> tuple[h5py.File, bool]:
    """Open an SVSS HDF5 file read-only: (file, closed cleanly). A writer that never
    closed leaves its open-for-writing flag set; such a file is opened as a SWMR reader
    (with bounded metadata read attempts). A file shorter than its superblock records
    is refused before HDF5 sees it."""
    if not path.is_file():
        raise RawFileError(f"{path}: no such file")
    sb = hdf5_superblock(path, RawFileError)
    clean = not sb["flags"] & 1
    try:
        return (h5py.File(path, "r") if clean else open_swmr(path)), clean
    except H5_ERRORS as exc:
        raise RawFileError(f"{path}: not a readable HDF5 file ({cause(exc)})") from None


def svss_format(path: str | Path) -> str | None:
    """The ``svss_format`` root attribute of an SVSS HDF5 file (a raw run or a tile),
    None when it has none (or it is not a string); also reads files a killed writer left
    open."""
    path = Path(path)
    return in_child(path, lambda: _format_of(path), RawFileError)


def _format_of(path: Path) -> str | None:
    f, _ = _open_for_reading(path)
    try:
        with f:
            return text(f.attrs.get("svss_format"))
    except H5_ERRORS as exc:
        raise RawFileError(f"{path}: cannot read its root attributes ({cause(exc)})") \
            from None


_NAV = ["time1", *NAV_FIELDS[1:]]


def _on_disk(ds: h5py.Dataset, n: int, size: int) -> int:
    """How many leading entries (along axis 0, up to ``n``) of a chunked dataset have
    their chunks written and wholly within a file of ``size`` bytes."""
    if n == 0 or ds.chunks is None:
        return n
    step = ds.chunks[0]
    zeros = (0,) * (ds.ndim - 1)
    for k in range(0, n, step):
        info = ds.id.get_chunk_info_by_coord((k, *zeros))
        if info.byte_offset is None or info.byte_offset + info.size > size:
            return k
    return n


#: what a reader keeps of a run, read in a child process
#: (:func:`~svss_daq.untrusted_hdf5.in_child`)
_STATE = ("clean", "sample_rate_hz", "hardware", "n_pings", "environment", "attrs",
          "_provenance", "_meta", "_nav", "_nmea_list", "_shape", "_events", "_pd0_index",
          "_clock_list", "_notes", "truncated")


def _read_events(f: h5py.File, path: Path) -> list[tuple[int, str, str]]:
    """The device events of a run (none in files written before they were kept)."""
    if EVENTS not in f:
        return []
    g = group(f, EVENTS, path, RawFileError)
    times = dataset(g, "time", path, 1, "iu", RawFileError)
    kinds = dataset(g, "kind", path, 1, "S", RawFileError)
    details = dataset(g, "detail", path, 1, "S", RawFileError)
    n = min(times.shape[0], kinds.shape[0], details.shape[0])
    return [(int(t), k.decode("ascii", "replace"), d.decode("ascii", "replace"))
            for t, k, d in zip(times[:n], kinds[:n], details[:n])]


def _read_pd0_index(f: h5py.File, path: Path, notes: list[str]
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(receive times, byte offsets, lengths) of the PD0 ensembles recorded with a run
    whose bytes lie within the stream on disk; None in files written before they were
    kept (no ``/Platform/PD0``). What is left out is said in ``notes``."""
    if PD0 not in f:
        return None
    g = group(f, PD0, path, RawFileError)
    stream = dataset(g, "stream", path, 1, "u", RawFileError, what="the PD0 ensembles' bytes (uint8)")
    if stream.dtype.itemsize != 1:
        raise RawFileError(f"{path}: dataset '/{PD0}/stream' has dtype {stream.dtype}; "
                           "expected uint8")
    index = [dataset(g, k, path, 1, "iu", RawFileError) for k in ("time", "offset", "n_bytes")]
    size = path.stat().st_size
    n = min(d.shape[0] for d in index)
    n = min([n] + [_on_disk(d, n, size) for d in index])
    t, o, z = (d[:n].astype(np.int64) for d in index)
    avail = _on_disk(stream, stream.shape[0], size)
    bad = np.flatnonzero((o < 0) | (z <= 0) | (o > avail) | (z > avail - o))
    if bad.size:
        k = int(bad[0])
        notes.append(f"{path}: PD0 ensemble {k} of {n} at byte {int(o[k])} ({int(z[k])} "
                     f"bytes) lies outside the {avail} bytes of '/{PD0}/stream' on disk; "
                     f"reading the first {k}")
        t, o, z = t[:k], o[:k], z[:k]
    return t, o, z


def _read_ping_clock(f: h5py.File, path: Path) -> list[tuple[int, int]]:
    """The ping-clock events recorded with a run (none in files written before they
    were kept)."""
    if PING_CLOCK not in f:
        return []
    g = group(f, PING_CLOCK, path, RawFileError)
    rx = dataset(g, "receive_time", path, 1, "iu", RawFileError)
    tx = dataset(g, "transmit_time", path, 1, "iu", RawFileError)
    size = path.stat().st_size
    n = min(rx.shape[0], tx.shape[0])
    n = min(n, _on_disk(rx, n, size), _on_disk(tx, n, size))
    return list(zip(rx[:n].tolist(), tx[:n].tolist()))


def _read_state(path: Path) -> dict:
    """Open and validate a run, read everything but the samples (touching the first and
    last pings' samples) and close it: the reader's state."""
    run = RawRunReader.__new__(RawRunReader)
    run.path = path
    run._notes = []
    run._open_and_validate()
    try:
        try:
            times, sentences = run._nmea
            n = min(times.shape[0], sentences.shape[0])
            run._nmea_list = [(int(t), s.decode("ascii", "replace"))
                              for t, s in zip(times[:n], sentences[:n])]
            run._shape = tuple(run._samples.shape[1:])
            run._events = _read_events(run._f, path)
            run._pd0_index = _read_pd0_index(run._f, path, run._notes)
            run._clock_list = _read_ping_clock(run._f, path)
            for i in ({0, run.n_pings - 1} if run.n_pings else ()):
                run._samples[i]
        except H5_ERRORS as exc:
            raise RawFileError(f"{path}: cannot read the run ({cause(exc)})") from None
        return {k: getattr(run, k) for k in _STATE}
    finally:
        run._f.close()


class RawRunReader:
    """Read a raw-run file, also one whose writer died (up to its last flush).

    The layout is validated when the file is opened, in a child process
    (:func:`~svss_daq.untrusted_hdf5.in_child`) that reads everything but the samples;
    this process then reads only the samples, ping by ping. Any failure to read the file
    (also later, reading a ping) raises :class:`RawFileError` naming the file."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.__dict__.update(in_child(self.path, lambda: _read_state(self.path), RawFileError))
        self._f, _ = _open_for_reading(self.path)
        try:
            self._samples = self._f[f"{BEAM}/backscatter_r"]
        except H5_ERRORS as exc:
            self._f.close()
            raise RawFileError(f"{self.path}: cannot read the run ({cause(exc)})") from None
        if not self.clean:
            log.warning("%s was not closed by its writer; reading up to its last flush "
                        "(%d pings)", self.path, self.n_pings)
        for note in self._notes:                 # (the child process logs nothing)
            log.warning("%s", note)

    def _open_and_validate(self) -> None:
        self._f, self.clean = _open_for_reading(self.path)
        try:
            self._validate()
        except ConfigError as exc:
            self._f.close()
            raise RawFileError(str(exc)) from None
        except RawFileError:
            self._f.close()
            raise
        except H5_ERRORS as exc:
            self._f.close()
            raise RawFileError(f"{self.path}: cannot read the run ({cause(exc)})") from None

    def _validate(self) -> None:
        f, path = self._f, self.path
        fmt = text(f.attrs.get("svss_format"))
        if fmt != FORMAT:
            raise RawFileError(f"{path}: root attribute 'svss_format' is "
                               f"{shown(f.attrs.get('svss_format'))}; expected {FORMAT!r}")
        format_version(f.attrs.get("svss_format_version"), path, READABLE_VERSIONS,
                       RawFileError)
        self.beam = group(f, BEAM, path, RawFileError)
        rate = self.beam.attrs.get("sample_rate_hz")
        try:
            self.sample_rate_hz = float(np.asarray(rate).reshape(()))
        except (TypeError, ValueError):
            self.sample_rate_hz = float("nan")
        if not (np.isfinite(self.sample_rate_hz) and self.sample_rate_hz > 0):
            raise RawFileError(f"{path}: attribute '/{BEAM}' sample_rate_hz is {shown(rate)}; "
                               "expected a positive number")
        text_ds = dataset(f, "Vendor_specific/hardware_config_toml", path, 0, "SOU",
                          RawFileError, what="the hardware configuration text")
        toml = text(text_ds[()])
        if toml is None:
            raise RawFileError(f"{path}: dataset '/Vendor_specific/hardware_config_toml' "
                               "is not a string")
        self.hardware = loaded_from_text(HardwareConfig, toml,
                                         f"{path}:/Vendor_specific/hardware_config_toml")
        dig = self.hardware.value.digitiser
        samples = dataset(self.beam, "backscatter_r", path, 3, "i",
                          RawFileError, what="int32 samples (ping x channel x sample)")
        if samples.dtype != np.dtype("<i4"):
            raise RawFileError(f"{path}: dataset '/{BEAM}/backscatter_r' has dtype "
                               f"{samples.dtype}; expected int32 ADC codes")
        if samples.shape[1:] != (dig.n_channels, dig.window_samples):
            raise RawFileError(
                f"{path}: dataset '/{BEAM}/backscatter_r' has shape {samples.shape}; the "
                f"stored hardware configuration records {dig.n_channels} channels x "
                f"{dig.window_samples} samples per ping")
        per_ping = {k: dataset(self.beam, k, path, 1, "iu", RawFileError) for k in _PER_PING}
        plat = group(f, "Platform", path, RawFileError)
        nav = {k: dataset(plat, k, path, 1, "iu" if k in ("time1", "quality") else "fiu", RawFileError)
               for k in _NAV}
        lengths = {f"/{BEAM}/backscatter_r": samples.shape[0],
                   **{f"/{BEAM}/{k}": d.shape[0] for k, d in per_ping.items()},
                   **{f"/Platform/{k}": d.shape[0] for k, d in nav.items()}}
        self.n_pings = self._ping_count(lengths)
        counted = "pings_flushed" in self.beam   # absent in files written before it
        size = path.stat().st_size
        on_disk = min(_on_disk(d, self.n_pings, size)
                      for d in (samples, *per_ping.values(), *nav.values()))
        if on_disk < self.n_pings:
            if counted:
                raise RawFileError(
                    f"{path}: truncated or damaged: ping {on_disk} of the {self.n_pings} "
                    f"recorded as flushed is not within its {size} bytes")
            self._notes.append(f"{path}: only the first {on_disk} of {self.n_pings} pings "
                               f"lie within the file's {size} bytes; reading those")
            self.truncated += self.n_pings - on_disk
            self.n_pings = on_disk
        nmea = group(plat, "NMEA", path, RawFileError)
        self._nmea = (dataset(nmea, "time", path, 1, "iu", RawFileError),
                      dataset(nmea, "sentence", path, 1, "S", RawFileError))
        self.environment = dict(group(f, "Environment", path, RawFileError).attrs)
        self._samples = samples
        self._meta = {k: d[: self.n_pings] for k, d in per_ping.items()}
        self._nav = {k: d[: self.n_pings] for k, d in nav.items()}
        self.attrs = dict(f.attrs)
        self._provenance = dict(f["Provenance"].attrs) if "Provenance" in f else {}

    def _closed_as_interrupted(self, path: Path) -> bool:
        """Whether the file's ``acquisition_summary`` (the root attribute) says another
        daemon closed it as interrupted (:func:`close_interrupted`)."""
        with contextlib.suppress(Exception):
            summary = json.loads(text(self._f.attrs.get("acquisition_summary")) or "{}")
            return bool(summary.get("interrupted"))
        return False

    def _ping_count(self, lengths: dict[str, int]) -> int:
        """The number of pings the per-ping datasets (``lengths``: path -> entries) hold
        together. Every one holds every ping of a closed file, and at least the pings
        flushed (``pings_flushed``) of any file: a shorter one is a damaged file,
        :class:`RawFileError` naming it. A file written before ``pings_flushed`` was
        kept and left open by its writer is read up to its shortest dataset, said in a
        warning (:attr:`_notes`)."""
        path = self.path
        self.truncated = 0          # pings left out of a file read to its shortest dataset
        short = min(lengths, key=lengths.get)
        n_min, n_max = lengths[short], max(lengths.values())
        others = sorted({n for k, n in lengths.items() if n != n_min})
        if "pings_flushed" in self.beam:
            flushed = dataset(self.beam, "pings_flushed", path, 1, "iu", RawFileError)
            if flushed.shape != (1,) or flushed[0] < 0:
                raise RawFileError(f"{path}: dataset '/{FLUSHED}' holds "
                                   f"{shown(flushed[()])}; expected one count >= 0")
            n = int(flushed[0])
            if n_min < n:
                raise RawFileError(
                    f"{path}: damaged: dataset '{short}' has {n_min} entries, the run "
                    f"records {n} pings flushed ('/{FLUSHED}'); the other per-ping "
                    f"datasets have {others or [n_min]}")
            if self.clean and n_max != n:
                long = max(lengths, key=lengths.get)
                if not self._closed_as_interrupted(path):
                    raise RawFileError(
                        f"{path}: damaged: dataset '{long}' has {n_max} entries, the run "
                        f"was closed with {n} pings ('/{FLUSHED}')")
                # its writer was killed with a ping half-written (its datasets grown,
                # the count not yet): another daemon closed it at the count
                self._notes.append(
                    f"{path}: closed as interrupted with {n} pings flushed; dataset "
                    f"'{long}' has {n_max} entries: reading {n} pings, "
                    f"{n_max - n} left out")
                self.truncated = n_max - n
            return n
        if n_max != n_min:
            if self.clean:
                raise RawFileError(
                    f"{path}: damaged: dataset '{short}' has {n_min} entries; the other "
                    f"per-ping datasets have {others} (a closed file has one length)")
            self._notes.append(
                f"{path}: its writer did not close it; dataset '{short}' has {n_min} "
                f"entries, the other per-ping datasets up to {n_max}: reading "
                f"{n_min} pings, {n_max - n_min} left out")
            self.truncated = n_max - n_min
        return n_min

    def __len__(self) -> int:
        return self.n_pings

    @property
    def shape(self) -> tuple[int, int]:
        """(channels, samples per ping) of the recorded pings."""
        return self._shape

    def ping_table(self) -> dict[str, np.ndarray]:
        """Per-ping records of every ping: ``ping_time`` (ns), ``ping_sequence``,
        ``transmit_projector``, ``window_start_ns`` (copies)."""
        return {k: v.copy() for k, v in self._meta.items()}

    def nav_table(self) -> dict[str, np.ndarray]:
        """Navigation of every ping: ``time1`` (ns) and the :class:`NavSnapshot` fields
        (copies)."""
        return {k: v.copy() for k, v in self._nav.items()}

    @property
    def provenance(self) -> dict:
        """The writer's provenance attributes (empty when the file has none)."""
        return dict(self._provenance)

    def nav(self, i: int) -> NavSnapshot:
        kw = {k: self._nav[k][i].item() for k in NAV_FIELDS[1:]}
        try:
            return NavSnapshot(time_ns=int(self._nav["time1"][i]), **kw)
        except (TypeError, ValueError) as exc:
            raise RawFileError(f"{self.path}: navigation of ping {i} in '/Platform' is "
                               f"invalid ({cause(exc)})") from None

    @property
    def verifiable(self) -> bool:
        """The pings' samples carry checksums (HDF5 Fletcher-32 per ping); runs recorded
        before they were written read as before, unverified."""
        return bool(self._samples.fletcher32)

    def _damage(self, i: int) -> str:
        return (f"{self.path}: ping {i} (sequence {int(self._meta['ping_sequence'][i])}), "
                f"dataset '/{BEAM}/backscatter_r': its samples fail their Fletcher-32 "
                "checksum (changed on disk since they were recorded)")

    def ping(self, i: int) -> Ping:
        """Ping ``i``. A ping whose samples fail their checksum comes back with
        ``damage`` saying so (file, ping, dataset) and zeros for samples: every gate
        refuses it (:func:`svss_daq.ping_gate.ping_problem`), the rest of the run reads
        on."""
        if not 0 <= i < self.n_pings:
            raise IndexError(f"{self.path}: ping {i} out of range 0..{self.n_pings - 1}")
        damage = None
        try:
            samples = self._samples[i]
        except H5_ERRORS as exc:
            if not (self.verifiable and "filter" in str(exc)):
                raise RawFileError(f"{self.path}: cannot read ping {i} of "
                                   f"'/{BEAM}/backscatter_r' ({cause(exc)})") from None
            damage = self._damage(i)          # logged by whatever refuses the ping
            samples = np.zeros(self._shape, dtype="<i4")
        return Ping(sequence=int(self._meta["ping_sequence"][i]),
                    projector=int(self._meta["transmit_projector"][i]),
                    transmit_time_ns=int(self._meta["ping_time"][i]),
                    sample_rate_hz=self.sample_rate_hz,
                    window_start_ns=int(self._meta["window_start_ns"][i]),
                    samples=samples, nav=self.nav(i), config_id=self.hardware.id,
                    damage=damage)

    def verify(self, progress=None) -> list[str]:
        """Read every ping's samples against their checksums: what is damaged (each
        naming file, ping and dataset; empty: none). ``progress``: called with the pings
        read so far. Raises :class:`RawFileError` for a run recorded without checksums."""
        if not self.verifiable:
            raise RawFileError(f"{self.path}: recorded without checksums (before they were "
                               "written): it cannot be verified")
        out = []
        buf = np.empty(self._shape, dtype="<i4")
        for i in range(self.n_pings):
            try:
                self._samples.read_direct(buf, np.s_[i])
            except H5_ERRORS as exc:
                if "filter" not in str(exc):
                    raise RawFileError(f"{self.path}: cannot read ping {i} of "
                                       f"'/{BEAM}/backscatter_r' ({cause(exc)})") from None
                out.append(self._damage(i))
            if progress is not None:
                progress(i + 1)
        return out

    def __iter__(self):
        for i in range(self.n_pings):
            yield self.ping(i)

    def nmea(self) -> list[tuple[int, str]]:
        """The raw NMEA sentences: (receive time ns, text)."""
        return list(self._nmea_list)

    def events(self) -> list[tuple[int, str, str]]:
        """The device events recorded with the run: (time ns, kind, detail)."""
        return list(self._events)

    @property
    def n_nmea(self) -> int:
        """NMEA sentences recorded with the run."""
        return len(self._nmea_list)

    @property
    def keeps_pd0(self) -> bool:
        """Whether the file has room for the PD0 ensembles the navigation used (False
        in files written before they were kept: their DVL records are lost)."""
        return self._pd0_index is not None

    @property
    def n_pd0(self) -> int:
        """PD0 ensembles recorded with the run (0 in files written before they were
        kept)."""
        return 0 if self._pd0_index is None else int(self._pd0_index[0].size)

    def pd0(self) -> list[tuple[int, bytes]]:
        """The PD0 ensembles as received from the DVL: (host receive time ns, the
        ensemble's bytes from its header to its checksum), in the order received; empty
        in files written before they were kept."""
        if not self.n_pd0:
            return []
        times, offsets, sizes = self._pd0_index
        end = int((offsets + sizes).max())
        try:
            stream = self._f[f"{PD0}/stream"][:end].tobytes()
        except H5_ERRORS as exc:
            raise RawFileError(f"{self.path}: cannot read '/{PD0}/stream' "
                               f"({cause(exc)})") from None
        return [(int(t), stream[o:o + z]) for t, o, z in
                zip(times.tolist(), offsets.tolist(), sizes.tolist())]

    def ping_clock(self) -> list[tuple[int, int]]:
        """The ping-clock events as the host received them: (receive time ns, transmit
        time ns on the ping clock) of each sequencer transmit record, in the order
        received; empty in files written before they were kept."""
        return list(self._clock_list)

    @property
    def run_id(self) -> str:
        """The run this file belongs to: the root attribute ``run_id`` (written by the
        acquisition daemon), else the file's stem."""
        return text(self.attrs.get("run_id")) or self.path.stem

    @property
    def segment(self) -> int:
        """The file's segment number within its run: the root attribute ``segment``,
        else 0. Raises :class:`RawFileError` when it is not an integer."""
        seg = self.attrs.get("segment", 0)
        try:
            return int(np.asarray(seg).reshape(()))
        except (TypeError, ValueError):
            raise RawFileError(f"{self.path}: root attribute 'segment' is {seg!r}; "
                               "expected an integer") from None

    @property
    def navigation_config(self) -> str | None:
        """The navigation configuration (TOML text of the devices configuration's
        ``[navigation]`` table) the acquisition daemon posed the pings with; None when
        the run does not record it."""
        return text(self.attrs.get(NAV_CONFIG_ATTR))

    @property
    def summary(self) -> dict | None:
        """The acquisition daemon's closing counters: the root attribute
        ``acquisition_summary``, else the file beside the run
        (:func:`summary_path`, written when the file could not take it); None when the
        run has none (e.g. a daemon killed before it closed the file)."""
        import json
        summary_text = text(self.attrs.get("acquisition_summary"))
        where = "root attribute 'acquisition_summary'"
        if summary_text is None:
            side = summary_path(self.path)
            if not side.is_file():
                return None
            where = f"{side}"
            try:
                if side.stat().st_size > MAX_SUMMARY_BYTES:
                    raise RawFileError(f"{self.path}: {side} has {side.stat().st_size} "
                                       f"bytes; a summary has at most {MAX_SUMMARY_BYTES}")
                summary_text = side.read_text(encoding="utf-8")
            except (OSError, UnicodeDecodeError) as exc:
                raise RawFileError(f"{self.path}: cannot read its summary {side} "
                                   f"({exc})") from None
        try:
            out = json.loads(summary_text)
        except (ValueError, RecursionError):
            raise RawFileError(f"{self.path}: {where} is not JSON") from None
        if not isinstance(out, dict):
            raise RawFileError(f"{self.path}: {where} is not a JSON object")
        return out

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> "RawRunReader":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def run_of(path: str | Path) -> tuple[str, int]:
    """(run id, segment number) of a raw file (:attr:`RawRunReader.run_id`,
    :attr:`RawRunReader.segment`)."""
    with RawRunReader(path) as r:
        return r.run_id, r.segment
