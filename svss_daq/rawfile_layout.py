"""The names of the raw-run file's layout, shared by its writer and its reader.

The layout itself is described in :mod:`svss_daq.rawfile` (and docs/formats.md): the
writer (:mod:`svss_daq.rawfile_writer`) makes it, the reader
(:mod:`svss_daq.rawfile_reader`) validates and reads it, the repair of a file whose
writer died (:mod:`svss_daq.rawfile_repair`) closes it.
"""

from __future__ import annotations

from pathlib import Path

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

#: the per-ping datasets of ``/Sonar/Beam_group1``: name: (dtype, long name, units)
PER_PING = {
    "ping_time": ("<i8", "transmit time of the ping (UTC)", TIME_UNITS),
    "ping_sequence": ("<i8", "ping sequence number", "1"),
    "transmit_projector": ("<i2", "index of the projector that transmitted", "1"),
    "window_start_ns": ("<i8", "receive-window start after transmit", "ns"),
}


class RawFileError(ValueError):
    """A raw-run file that cannot be read (or written) as such."""


#: the largest summary file beside a raw run a reader reads, bytes
MAX_SUMMARY_BYTES = 1 << 20


def summary_path(path: str | Path) -> Path:
    """Where the acquisition summary of the raw run ``path`` lies when its file could
    not take it (a writer stopped by a full disk): ``<stem>.summary.json`` beside it."""
    path = Path(path)
    return path.with_name(path.stem + ".summary.json")
