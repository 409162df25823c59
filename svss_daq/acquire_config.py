"""``svss acquire --config FILE``: the schema of the acquisition daemon's configuration.

The file names the hardware, devices and daq configurations it runs with (paths relative
to its own folder) and holds the daemon's own settings: where runs are recorded and how
their files rotate, the status stream, the disk-space floor and the pairing of the
digitiser's pings with the sequencer's transmit records. See docs/acquisition.md.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from .config import (
    ConfigError,
    DaqConfig,
    DevicesConfig,
    HardwareConfig,
    Loaded,
    from_dict,
    load,
    load_with_text,
    read_toml,
    spec,
)


@dataclass(frozen=True)
class RunSection:
    hardware: str = spec("hardware TOML (relative to this file's folder)")
    devices: str = spec("devices TOML: links to the sequencer, digitiser, DVL and GPS")
    daq: str = spec("daq TOML: publisher, catch-up service, recorder flushes")
    out_dir: str = spec("folder of the raw-run files (relative to this file's folder)")
    name: str = spec("run name; the run id is NAME-YYYYMMDDTHHMMSSZ (UTC start)")


@dataclass(frozen=True)
class RotationSection:
    max_file_mib: float = spec("start a new segment file beyond this size, MiB", lo=1,
                               hi=1e7)
    max_file_s: float = spec("start a new segment file after this long, s", lo=1, hi=1e6)


@dataclass(frozen=True)
class StatusSection:
    endpoint: str = spec("ZeroMQ endpoint the status stream (PUB, JSON) binds")
    interval_s: float = spec("seconds between status messages", lo=0.05, hi=3600)
    rate_window_s: float = spec("ping rate averaged over this window, s", lo=0.5, hi=3600)


@dataclass(frozen=True)
class DiskSection:
    min_free_mib: float = spec("stop recording (cleanly) when free space falls below "
                               "this, MiB", lo=0, hi=1e9)
    reserve_mib: float | None = spec(
        "disk space held from the run's start to its close, released for the closing "
        "summaries (room for them on a full disk), MiB (omitted: 1; 0: none)", lo=0,
        hi=1024)


@dataclass(frozen=True)
class PairingSection:
    transmit_wait_s: float = spec("wait this long for the sequencer's transmit record of "
                                  "a ping before assembling it from the digitiser's alone, s",
                                  lo=0.0, hi=60)
    start_timeout_s: float = spec("wait this long for the devices to connect at start, s",
                                  lo=0.1, hi=600)
    drain_s: float = spec("at stop, wait this long for pings still in flight, s", lo=0,
                          hi=60)


@dataclass(frozen=True)
class CatchUpSection:
    linger_s: float = spec("after the run ends, keep the catch-up service up while "
                           "workers still fetch from it, until none has asked for this "
                           "long, s (0: close with the run); a worker that tells the "
                           "service its progress keeps it up while it lacks pings",
                           lo=0, hi=3600)
    max_linger_s: float = spec("... but no longer than this after the run's end, s",
                               lo=0, hi=86400)


@dataclass(frozen=True)
class NavigationSection:
    history_s: float = spec("navigation samples kept for the solution, s", lo=5, hi=3600)
    wait_s: float = spec("wait this long for DVL and GPS data at or after a ping's "
                         "transmit time before posing it (a GPS outage or lost DVL "
                         "ends the wait), s", lo=0.0, hi=60)


@dataclass(frozen=True)
class LimitsSection:
    pending_pings: int = spec("pings waiting for their transmit record or navigation at "
                              "most (480 kB each); beyond, the oldest is posed and "
                              "recorded at once (counted, event daemon.pending_full)",
                              lo=1, hi=100000)
    transmit_records: int = spec("sequencer transmit records waiting for their ping at "
                                 "most; beyond, the oldest is dropped (counted)", lo=1,
                                 hi=10**6)
    duplicate_window: int = spec("latest ping numbers remembered to refuse a ping "
                                 "delivered twice", lo=1, hi=10**7)
    records_waiting: int = spec("NMEA sentences, PD0 ensembles and ping-clock records "
                                "each waiting to be written at most; beyond, the oldest "
                                "is dropped (counted, event daemon.records_dropped)",
                                lo=1, hi=10**7)


@dataclass(frozen=True)
class AlarmsSection:
    """Thresholds of the named alarms (:mod:`svss_daq.alarms`, docs/operator.md). Every
    key may be omitted: its default is the ``default`` here, the one place it is
    written."""
    no_ping_intervals: float | None = spec(
        "alarm pings.stopped: no ping for this many ping intervals (hardware "
        "sequencer.ping_interval_s) while recording", lo=1, hi=10000, default=5.0)
    min_rate_fraction: float | None = spec(
        "alarm pings.rate_low: the ping rate over status.rate_window_s below this "
        "fraction of the schedule's", lo=0.0, hi=1.0, default=0.8)
    recent_s: float | None = spec(
        "alarms pings.lost, stream.dropped and worker.memory_bound: raised while what "
        "they count happened within this long, s", lo=0.5, hi=86400, default=10.0)
    disk_min_free_mib: float | None = spec(
        "alarm disk.low: free space below this, MiB (recording stops at "
        "disk.min_free_mib)", lo=0, hi=1e9, default=4096.0)
    disk_min_time_left_s: float | None = spec(
        "alarm disk.low (critical): less than this left at the current rate before "
        "recording stops, s", lo=0, hi=1e7, default=1800.0)
    dead_reckoning_max_s: float | None = spec(
        "alarm navigation.dead_reckoning: dead reckoning without a GPS fix for longer "
        "than this, s", lo=0, hi=86400, default=60.0)
    device_silent_s: float | None = spec(
        "alarm <device>.silent: nothing received from a connected device for this long "
        "while recording, s", lo=0.1, hi=3600, default=3.0)
    worker_max_backlog_s: float | None = spec(
        "alarm worker.behind: a tile worker this far behind the recording (its backlog "
        "in pings times the ping interval), s", lo=0.1, hi=86400, default=20.0)
    clear_after_s: float | None = spec(
        "an alarm clears once its condition has been absent this long (hysteresis), s",
        lo=0, hi=3600, default=3.0)
    first_ping_s: float | None = spec(
        "pings are due this long after the sequencer is started, at the latest (a "
        "sequencer may hold its first ping for a start time, the simulator for its "
        "lead): until the first ping, pings.stopped, pings.rate_low and sequencer.silent "
        "count from then, s", lo=0, hi=3600, default=30.0)


@dataclass(frozen=True)
class ViewSection:
    """Where ``svss view`` serves the operator's web page (docs/operator.md). Every key
    may be omitted: its default is the ``default`` here, the one place it is written.
    The bind rules of the ZeroMQ endpoints apply (:func:`~svss_daq.endpoints.check_endpoint`):
    loopback unless configured otherwise, another address logged as a warning."""
    address: str | None = spec(
        "address the page's HTTP server binds: an IPv4 address, a bracketed IPv6 address "
        "or a host name; 127.0.0.1 keeps it on this machine, 0.0.0.0 every interface",
        default="127.0.0.1")
    port: int | None = spec("TCP port of the page", lo=1, hi=65535, default=8558)


def view_section(cfg: "AcquireConfig") -> ViewSection:
    """The ``[view]`` settings of ``cfg``: its table, or every default when it has none."""
    return cfg.view if cfg.view is not None else from_dict(ViewSection, {},
                                                           "[view] defaults")


def alarms_section(cfg: "AcquireConfig") -> AlarmsSection:
    """The ``[alarms]`` thresholds of ``cfg``: its table, or every default when it has
    none."""
    return cfg.alarms if cfg.alarms is not None else from_dict(AlarmsSection, {},
                                                               "[alarms] defaults")


#: [limits] when the acquisition TOML has none (config/acquire.toml holds the same)
DEFAULT_LIMITS = LimitsSection(pending_pings=200, transmit_records=1000,
                               duplicate_window=100000, records_waiting=10000)


def limits_section(acq: "AcquireConfig") -> LimitsSection:
    """The ``[limits]`` of ``acq``: its table, or :data:`DEFAULT_LIMITS` when it has
    none (what the daemon and its parts bound their queues by)."""
    return acq.limits or DEFAULT_LIMITS


@dataclass(frozen=True)
class AcquireConfig:
    run: RunSection = spec("what is run and where it is recorded")
    rotation: RotationSection = spec("raw-run file rotation")
    status: StatusSection = spec("status stream")
    disk: DiskSection = spec("disk-space floor")
    pairing: PairingSection = spec("digitiser/sequencer pairing and start/stop")
    navigation: NavigationSection = spec("navigation solution of the daemon")
    catch_up: CatchUpSection = spec("the catch-up service after the run")
    limits: LimitsSection | None = spec("bounds of the daemon's queues (omitted: "
                                        "DEFAULT_LIMITS)")
    alarms: AlarmsSection | None = spec("thresholds of the named alarms (omitted: every "
                                        "default of AlarmsSection)")
    view: ViewSection | None = spec("where svss view serves the operator's page (omitted: "
                                    "every default of ViewSection)")


@dataclass(frozen=True)
class AcquireSetup:
    """Everything ``svss acquire`` runs with, loaded and checked."""
    path: Path
    acquire: AcquireConfig
    hardware: Loaded[HardwareConfig]
    devices: DevicesConfig
    daq: DaqConfig
    out_dir: Path


def load_acquire(path: str | os.PathLike, *, devices: str | os.PathLike | None = None,
                 out_dir: str | os.PathLike | None = None,
                 hardware: str | os.PathLike | None = None) -> AcquireSetup:
    """Read ``path`` and the configurations it names; ``devices`` / ``out_dir`` /
    ``hardware`` replace the file's (e.g. the devices TOML printed by ``svss
    sim-device``). Errors name the file and the key."""
    path = Path(path)
    cfg = from_dict(AcquireConfig, read_toml(path), str(path))
    base = path.resolve().parent

    def named(value: str | os.PathLike, key: str) -> Path:
        p = Path(value)
        p = p if p.is_absolute() else base / p
        if not p.exists():
            raise ConfigError(f"{path}: key '{key}' names {p}, which does not exist")
        return p

    hw = load_with_text(HardwareConfig,
                        hardware or named(cfg.run.hardware, "run.hardware"))
    dev_path = Path(devices) if devices else named(cfg.run.devices, "run.devices")
    dev = load(DevicesConfig, dev_path)
    daq = load(DaqConfig, named(cfg.run.daq, "run.daq"))
    out = Path(out_dir) if out_dir else (
        Path(cfg.run.out_dir) if Path(cfg.run.out_dir).is_absolute()
        else base / cfg.run.out_dir)
    if not cfg.run.name or not all(c.isalnum() or c in "-_." for c in cfg.run.name):
        raise ConfigError(f"{path}: key 'run.name' is {cfg.run.name!r}; expected letters, "
                          "digits, '-', '_' or '.'")
    return AcquireSetup(path, cfg, hw, dev, daq, out)
