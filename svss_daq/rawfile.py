"""Raw-run files: HDF5 laid out after the ICES SONAR-netCDF4 convention where it applies.

Layout (see docs/formats.md)::

    /                       attrs: Conventions, svss_format, svss_format_version
    /Sonar/Beam_group1      backscatter_r (ping_time x channel x sample, int32 codes),
                            ping_time (int64 ns), ping_sequence, transmit_projector,
                            window_start_ns; attrs sample_rate_hz, ...
    /Platform               time1 (int64 ns) and the navigation snapshot of each ping
    /Platform/NMEA          time (int64 ns), sentence (raw NMEA text)
    /Environment            attrs: scene or measured environment
    /Provenance             attrs: software, creation time; hardware configuration text
    /Vendor_specific        hardware configuration text and its id

Every dataset is chunked by ping and appended ping by ping. The writer runs in HDF5's
single-writer/multiple-reader mode, so the file on disk is consistent at every flush: a
writer killed mid-run leaves a file readable up to its last flush (pings after it are
lost, nothing before it). Flushes happen every ``flush_every_pings`` pings and at least
every ``flush_interval_s`` seconds.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import h5py
import numpy as np

from . import __version__
from .config import HardwareConfig, Loaded, loaded_from_text
from .ping import NAV_FIELDS, NavSnapshot, Ping

log = logging.getLogger(__name__)

FORMAT = "svss-raw"
FORMAT_VERSION = 1
BEAM = "Sonar/Beam_group1"
NMEA_LEN = 96

_PER_PING = {  # name: (dtype, description)
    "ping_time": ("<i8", "transmit time, ns since the Unix epoch (UTC)"),
    "ping_sequence": ("<i8", "ping sequence number"),
    "transmit_projector": ("<i2", "index of the projector that transmitted"),
    "window_start_ns": ("<i8", "receive-window start after transmit, ns"),
}


class RawFileError(ValueError):
    """A raw-run file that cannot be read as such."""


def _appendable(group: h5py.Group, name: str, dtype, shape_tail=(), chunk=1024, doc=""):
    ds = group.create_dataset(name, shape=(0, *shape_tail), maxshape=(None, *shape_tail),
                              dtype=dtype, chunks=(chunk, *shape_tail))
    if doc:
        ds.attrs["long_name"] = doc
    return ds


class RawRunWriter:
    """Append pings (and raw NMEA sentences) to a new raw-run file.

    Use as a context manager. ``hardware`` is the loaded hardware configuration (its
    text is stored for provenance and reprocessing).
    """

    def __init__(self, path: str | Path, hardware: Loaded[HardwareConfig], *,
                 flush_every_pings: int = 10, flush_interval_s: float = 1.0,
                 environment: dict | None = None, run_attrs: dict | None = None):
        self.path = Path(path)
        self.hardware = hardware
        self.flush_every = int(flush_every_pings)
        self.flush_interval = float(flush_interval_s)
        dig = hardware.value.digitiser
        self.n_channels, self.n_samples = dig.n_channels, dig.window_samples
        self._f = h5py.File(self.path, "w", libver="latest")
        f = self._f
        f.attrs.update({"Conventions": "SONAR-netCDF4-like", "svss_format": FORMAT,
                        "svss_format_version": FORMAT_VERSION})
        for k, v in (run_attrs or {}).items():
            f.attrs[k] = v
        sonar = f.create_group("Sonar")
        sonar.attrs.update({"sonar_manufacturer": "ARL/PSU (SVSS)",
                            "sonar_model": hardware.value.name})
        beam = f.create_group(BEAM)
        beam.attrs.update({"sample_rate_hz": dig.sample_rate_hz,
                           "beam_mode": "element", "conversion_equation_type": "counts",
                           "adc_bits": dig.bits})
        self._samples = beam.create_dataset(
            "backscatter_r", shape=(0, self.n_channels, self.n_samples),
            maxshape=(None, self.n_channels, self.n_samples), dtype="<i4",
            chunks=(1, self.n_channels, self.n_samples))
        self._samples.attrs["long_name"] = "raw ADC codes (24-bit carried in int32)"
        self._samples.attrs["dimensions"] = "ping_time channel sample"
        self._per_ping = {k: _appendable(beam, k, dt, doc=doc)
                          for k, (dt, doc) in _PER_PING.items()}
        plat = f.create_group("Platform")
        self._nav = {"time1": _appendable(plat, "time1", "<i8",
                                          doc="navigation snapshot time, ns (UTC)")}
        for name in NAV_FIELDS:
            if name == "time_ns":
                continue
            self._nav[name] = _appendable(plat, name, "<i8" if name == "quality" else "<f8")
        nmea = plat.create_group("NMEA")
        self._nmea_time = _appendable(nmea, "time", "<i8", doc="receive time, ns (UTC)")
        self._nmea_text = _appendable(nmea, "sentence", f"S{NMEA_LEN}",
                                      doc="raw NMEA 0183 sentence")
        env = f.create_group("Environment")
        for k, v in (environment or {}).items():
            env.attrs[k] = v
        prov = f.create_group("Provenance")
        prov.attrs.update({"software_name": "svss", "software_version": __version__,
                           "creation_time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ",
                                                              time.gmtime())})
        vendor = f.create_group("Vendor_specific")
        vendor.create_dataset("hardware_config_toml", data=hardware.text)
        vendor.attrs["hardware_config_id"] = hardware.id
        vendor.attrs["hardware_config_source"] = hardware.source
        f.swmr_mode = True
        self.n_pings = 0
        self.n_flushed = 0
        self._last_flush = time.monotonic()

    def append(self, ping: Ping) -> None:
        """Append one ping; flushes according to the policy."""
        if ping.samples.shape != (self.n_channels, self.n_samples):
            raise ValueError(f"{self.path}: ping {ping.sequence} has samples of shape "
                             f"{ping.samples.shape}; this run records "
                             f"{(self.n_channels, self.n_samples)}")
        if ping.config_id and ping.config_id != self.hardware.id:
            raise ValueError(f"{self.path}: ping {ping.sequence} was acquired with hardware "
                             f"config {ping.config_id}, this run records {self.hardware.id}")
        i = self.n_pings
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
        self.n_pings += 1
        if (self.n_pings - self.n_flushed >= self.flush_every
                or time.monotonic() - self._last_flush >= self.flush_interval):
            self.flush()

    def append_nmea(self, time_ns: int, sentence: str) -> None:
        """Record one raw NMEA sentence (truncated to 96 bytes)."""
        raw = sentence.strip().encode("ascii", "replace")[:NMEA_LEN]
        i = self._nmea_time.shape[0]
        self._nmea_text.resize(i + 1, axis=0)
        self._nmea_text[i] = raw
        self._nmea_time.resize(i + 1, axis=0)
        self._nmea_time[i] = time_ns

    def flush(self) -> None:
        """Make everything appended so far durable on disk."""
        self._f.flush()
        self.n_flushed = self.n_pings
        self._last_flush = time.monotonic()

    def close(self) -> None:
        if self._f.id.valid:
            self.flush()
            self._f.close()
            log.info("closed %s: %d pings", self.path, self.n_pings)

    def __enter__(self) -> "RawRunWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _open_for_reading(path: Path) -> tuple[h5py.File, bool]:
    """Open an SVSS HDF5 file read-only: (file, closed cleanly). A writer that never
    closed leaves the SWMR flag set; such a file is opened as a SWMR reader."""
    if not path.is_file():
        raise RawFileError(f"{path}: no such file")
    try:
        return h5py.File(path, "r"), True
    except OSError:
        try:
            return h5py.File(path, "r", libver="latest", swmr=True), False
        except OSError as exc:
            raise RawFileError(f"{path}: not a readable HDF5 file ({exc})") from None


def svss_format(path: str | Path) -> str | None:
    """The ``svss_format`` root attribute of an SVSS HDF5 file (a raw run or a tile),
    None when it has none; also reads files a killed writer left open."""
    f, _ = _open_for_reading(Path(path))
    with f:
        fmt = f.attrs.get("svss_format")
    return fmt.decode() if isinstance(fmt, bytes) else fmt


class RawRunReader:
    """Read a raw-run file, also one whose writer died (up to its last flush)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self._f, self.clean = _open_for_reading(self.path)
        if not self.clean:
            log.warning("%s was not closed by its writer; reading up to its last flush",
                        self.path)
        f = self._f
        if f.attrs.get("svss_format") != FORMAT:
            raise RawFileError(f"{self.path}: root attribute 'svss_format' is "
                               f"{f.attrs.get('svss_format')!r}; expected {FORMAT!r}")
        version = int(f.attrs.get("svss_format_version", -1))
        if version != FORMAT_VERSION:
            raise RawFileError(f"{self.path}: svss_format_version {version}; this software "
                               f"reads version {FORMAT_VERSION}")
        if BEAM not in f:
            raise RawFileError(f"{self.path}: group '/{BEAM}' missing")
        self.beam = f[BEAM]
        self.sample_rate_hz = float(self.beam.attrs["sample_rate_hz"])
        text = f["Vendor_specific/hardware_config_toml"][()]
        text = text.decode() if isinstance(text, bytes) else str(text)
        self.hardware = loaded_from_text(HardwareConfig, text,
                                         f"{self.path}:/Vendor_specific/hardware_config_toml")
        lengths = [self.beam["backscatter_r"].shape[0]]
        lengths += [self.beam[k].shape[0] for k in _PER_PING]
        lengths += [f["Platform"][k].shape[0] for k in ["time1", *NAV_FIELDS[1:]]]
        self.n_pings = min(lengths)
        if max(lengths) != self.n_pings:
            log.warning("%s: per-ping datasets have lengths %s; reading the first %d pings",
                        self.path, sorted(set(lengths)), self.n_pings)
        self._meta = {k: self.beam[k][: self.n_pings] for k in _PER_PING}
        plat = f["Platform"]
        self._nav = {k: plat[k][: self.n_pings] for k in ["time1", *NAV_FIELDS[1:]]}
        self.environment = dict(f["Environment"].attrs)
        self.attrs = dict(f.attrs)

    def __len__(self) -> int:
        return self.n_pings

    @property
    def shape(self) -> tuple[int, int]:
        """(channels, samples per ping) of the recorded pings."""
        return tuple(self.beam["backscatter_r"].shape[1:])

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
        return dict(self._f["Provenance"].attrs) if "Provenance" in self._f else {}

    def nav(self, i: int) -> NavSnapshot:
        kw = {k: self._nav[k][i].item() for k in NAV_FIELDS[1:]}
        return NavSnapshot(time_ns=int(self._nav["time1"][i]), **kw)

    def ping(self, i: int) -> Ping:
        if not 0 <= i < self.n_pings:
            raise IndexError(f"{self.path}: ping {i} out of range 0..{self.n_pings - 1}")
        return Ping(sequence=int(self._meta["ping_sequence"][i]),
                    projector=int(self._meta["transmit_projector"][i]),
                    transmit_time_ns=int(self._meta["ping_time"][i]),
                    sample_rate_hz=self.sample_rate_hz,
                    window_start_ns=int(self._meta["window_start_ns"][i]),
                    samples=self.beam["backscatter_r"][i], nav=self.nav(i),
                    config_id=self.hardware.id)

    def __iter__(self):
        for i in range(self.n_pings):
            yield self.ping(i)

    def nmea(self) -> list[tuple[int, str]]:
        g = self._f["Platform/NMEA"]
        n = min(g["time"].shape[0], g["sentence"].shape[0])
        return [(int(t), s.decode("ascii", "replace"))
                for t, s in zip(g["time"][:n], g["sentence"][:n])]

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> "RawRunReader":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
