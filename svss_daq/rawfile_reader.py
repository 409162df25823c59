"""The raw-run file's reader: :class:`RawRunReader` validates a file of the layout
described in :mod:`svss_daq.rawfile` in a child process (the file is untrusted) and
reads its pings, navigation, instrument records, events and summary, also from a file
whose writer died (up to its last flush); :func:`svss_format` says what an SVSS HDF5
file is, :func:`run_of` which run and segment a raw file is.
"""

from __future__ import annotations

import contextlib
import json
import logging
from pathlib import Path

import h5py
import numpy as np

from .config import ConfigError, HardwareConfig, loaded_from_text
from .ping import NAV_FIELDS, NavSnapshot, Ping
from .rawfile_layout import (BEAM, EVENTS, FLUSHED, FORMAT, MAX_SUMMARY_BYTES,
                             NAV_CONFIG_ATTR, PD0, PER_PING, PING_CLOCK,
                             READABLE_VERSIONS, RawFileError, summary_path)
from .untrusted_hdf5 import (H5_ERRORS, cause, dataset, format_version, group,
                             hdf5_superblock, in_child, open_swmr, run_id_attr, shown,
                             text)

log = logging.getLogger("svss_daq.rawfile")     # one logger for the raw file's modules


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
        per_ping = {k: dataset(self.beam, k, path, 1, "iu", RawFileError) for k in PER_PING}
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
        daemon closed it as interrupted
        (:func:`~svss_daq.rawfile_repair.close_interrupted`)."""
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
        return run_id_attr(self.attrs) or self.path.stem

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
