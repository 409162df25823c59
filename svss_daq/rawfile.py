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

The jobs are apart: the layout's names in :mod:`svss_daq.rawfile_layout`, the writer in
:mod:`svss_daq.rawfile_writer`, the reader in :mod:`svss_daq.rawfile_reader`, the
repair of a file whose writer died in :mod:`svss_daq.rawfile_repair`; this module is
their one public face.
"""

from __future__ import annotations

from .rawfile_layout import (BEAM, EVENT_DETAIL_LEN, EVENT_KIND_LEN, EVENTS, FLUSHED,
                             FORMAT, FORMAT_VERSION, MAX_SUMMARY_BYTES, NAV_CONFIG_ATTR,
                             NMEA_LEN, PD0, PD0_CHUNK, PER_PING, PING_CLOCK,
                             READABLE_VERSIONS, SONAR_NETCDF4_VERSION, TIME_UNITS,
                             WRITER_ATTRS, RawFileError, summary_path)
from .rawfile_reader import RawRunReader, run_of, svss_format
from .rawfile_repair import close_interrupted, lookup3
from .rawfile_writer import RawRunWriter, write_summary, write_summary_beside
from .untrusted_hdf5 import hdf5_superblock

__all__ = ["BEAM", "EVENT_DETAIL_LEN", "EVENT_KIND_LEN", "EVENTS", "FLUSHED", "FORMAT",
           "FORMAT_VERSION", "MAX_SUMMARY_BYTES", "NAV_CONFIG_ATTR", "NMEA_LEN", "PD0",
           "PD0_CHUNK", "PER_PING", "PING_CLOCK", "READABLE_VERSIONS",
           "SONAR_NETCDF4_VERSION", "TIME_UNITS", "WRITER_ATTRS", "RawFileError",
           "RawRunReader", "RawRunWriter", "close_interrupted", "hdf5_superblock",
           "lookup3", "run_of", "summary_path", "svss_format", "write_summary",
           "write_summary_beside"]
