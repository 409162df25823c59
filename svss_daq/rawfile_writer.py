"""The raw-run file's writer: :class:`RawRunWriter` makes a new file of the layout
described in :mod:`svss_daq.rawfile` and appends pings (and the instrument records and
events of the run) to it in HDF5's single-writer/multiple-reader mode, flushed by
policy; :func:`write_summary` and :func:`write_summary_beside` store the acquisition
summary of a closed run in it or beside it.
"""

from __future__ import annotations

import functools
import json
import logging
import os
import time
from pathlib import Path

import h5py
import numpy as np

from . import __version__
from .config import HardwareConfig, Loaded
from .ping import NAV_FIELDS, NavSnapshot, Ping
from .rawfile_layout import (BEAM, EVENT_DETAIL_LEN, EVENT_KIND_LEN, FORMAT,
                             FORMAT_VERSION, NMEA_LEN, PD0_CHUNK, PER_PING,
                             SONAR_NETCDF4_VERSION, TIME_UNITS, RawFileError,
                             summary_path)
from .signals import deferred_stop
from .untrusted_hdf5 import H5_ERRORS, abandon, cause

log = logging.getLogger("svss_daq.rawfile")     # one logger for the raw file's modules

#: the name HDF5 dimension scales of netCDF-4 give a dimension that has no variable
_NOT_A_VARIABLE = "This is a netCDF dimension but not a netCDF variable."
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
                          for k, (dt, doc, units) in PER_PING.items()}
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
    try:
        with h5py.File(path, "a") as f:
            f.attrs["acquisition_summary"] = json.dumps(summary, sort_keys=True)
    except H5_ERRORS as exc:
        raise RawFileError(f"{path}: writing the acquisition summary failed "
                           f"({cause(exc)})") from None


def write_summary_beside(path: str | Path, summary: dict) -> Path:
    """Store ``summary`` (JSON) in :func:`summary_path` of ``path`` (atomically: a
    temporary file renamed); its path. :class:`RawFileError` naming it on failure."""
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
