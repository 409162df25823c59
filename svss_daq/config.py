"""Validated configuration loading.

Every number of the hardware, the processing and the scenes lives in TOML files under
``config/``; this module holds only their *schema*: frozen dataclasses whose fields carry
the expected type, range and meaning. :func:`load` reads a file and builds the
dataclass, rejecting unknown keys, missing keys, wrong types and out-of-range values
with a :class:`ConfigError` that names the file, the dotted key and what was expected.

Schema fields carry no defaults: defaults live in the config files. A field whose type
is ``X | None`` may be omitted: :func:`load` then gives it the ``default`` of its
:func:`spec` (the one place a default of an omitted key is written), or None where the
spec has none (omitted meaning "none", e.g. ``extended_min_m3``).

By job: the schema machinery and the loader in :mod:`svss_daq.config_loader`, the
processing schema in :mod:`svss_daq.config_processing`, the hardware, acquisition
(daq.toml) and devices schemas here; every name of the three is imported from here.
"""

from __future__ import annotations

from dataclasses import dataclass

from .config_loader import (CONFIG_ENV, SHIPPED_FILES, ConfigError, Loaded, config_dir,
                            config_path, digest, from_dict, load, load_with_text,
                            loaded_from_text, loads, omitted_default, read_toml, spec)
from .config_processing import (AutofocusConfig, BackgroundConfig, ClassifyConfig,
                                ConditioningConfig,
                                DepthGainConfig, DetectionConfig, DrcConfig,
                                FeaturesConfig, ImagingConfig, LimitsConfig,
                                MicronavConfig, PingClassifyConfig,
                                PingGateConfig, ProcessingConfig, ProductsConfig,
                                QuicklookConfig, SeabedConfig, SedimentLayerConfig,
                                SpectraConfig, TileConfig)


# --------------------------------------------------------------------------- hardware


@dataclass(frozen=True)
class ReceiveSection:
    name: str = spec("section name")
    rows: int = spec("channels along-track", lo=1, hi=64)
    cols: int = spec("channels cross-track", lo=1, hi=64)
    center_m: tuple[float, float, float] = spec(
        "section centre in the array frame (x fwd, y stbd, z down), m", length=3)


@dataclass(frozen=True)
class ReceiveArray:
    pitch_m: float = spec("centre-to-centre element spacing, m", lo=1e-3, hi=1.0)
    module_rows: int = spec("channels per module along-track", lo=1, hi=64)
    module_cols: int = spec("channels per module cross-track", lo=1, hi=64)
    sections: tuple[ReceiveSection, ...] = spec("array sections", min_length=1)


@dataclass(frozen=True)
class Projectors:
    positions_m: tuple[tuple[float, float, float], ...] = spec(
        "projector positions in the array frame (x fwd, y stbd, z down), m", min_length=1)


@dataclass(frozen=True)
class Beams:
    projector_half_angle_deg: float = spec("projector beam cone half-angle, deg", lo=1, hi=90)
    receiver_half_angle_deg: float = spec("hydrophone beam cone half-angle, deg", lo=1, hi=90)
    boresight: tuple[float, float, float] = spec(
        "common boresight direction in the body frame (unit vector, z down)", length=3)


@dataclass(frozen=True)
class WaveformConfig:
    kind: str = spec("waveform type", choices=("lfm",))
    f_start_hz: float = spec("instantaneous frequency at t = 0, Hz", lo=1.0, hi=1e6)
    f_stop_hz: float = spec("instantaneous frequency at t = duration, Hz", lo=1.0, hi=1e6)
    duration_s: float = spec("pulse length, s", lo=1e-6, hi=0.1)
    center_hz: float = spec("centre (carrier) frequency for basebanding, Hz", lo=1.0, hi=1e6)
    window: str = spec("amplitude taper", choices=("taylor", "rect", "hann"))
    taylor_nbar: int = spec("Taylor window: number of nearly equal sidelobes", lo=1, hi=20)
    taylor_sll_db: float = spec("Taylor window: peak sidelobe level below the main lobe, dB",
                                lo=10, hi=120)
    source_level_db: float = spec("source level, dB re 1 uPa at 1 m (peak of the taper)",
                                  lo=100, hi=260)


@dataclass(frozen=True)
class Digitiser:
    n_channels: int = spec("receive channels", lo=1, hi=1024)
    sample_rate_hz: float = spec("per-channel sample rate, Hz", lo=1e3, hi=1e7)
    window_samples: int = spec("samples per channel per ping", lo=16, hi=1_000_000)
    window_start_s: float = spec("receive-window start after transmit, s", lo=0.0, hi=1.0)
    group_delay_s: float = spec("digitiser filter group delay, s", lo=0.0, hi=0.01)
    bits: int = spec("ADC resolution, bits (carried in int32)", lo=8, hi=32)
    full_scale_v: float = spec("ADC full-scale amplitude, V", lo=1e-3, hi=100)
    sensitivity_db_re_v_per_upa: float = spec("hydrophone sensitivity, dB re 1 V/uPa",
                                               lo=-260, hi=-100)
    gain_db: float = spec("analogue gain before the ADC, dB", lo=-40, hi=120)


@dataclass(frozen=True)
class Sequencer:
    ping_interval_s: float = spec("ping repetition interval, s", lo=1e-3, hi=10.0)
    projector_order: tuple[int, ...] = spec("projector indices cycled ping by ping",
                                            min_length=1)


@dataclass(frozen=True)
class LeverArms:
    array_m: tuple[float, float, float] = spec(
        "array reference point in the body frame (x fwd, y stbd, z down), m", length=3)
    gps_antenna_m: tuple[float, float, float] = spec("GPS antenna in the body frame, m", length=3)
    dvl_m: tuple[float, float, float] = spec("DVL transducer head in the body frame, m", length=3)


@dataclass(frozen=True)
class HardwareConfig:
    name: str = spec("hardware description")
    receive_array: ReceiveArray = spec("receive array layout")
    projectors: Projectors = spec("projector layout")
    beams: Beams = spec("beam cones")
    waveform: WaveformConfig = spec("transmit waveform")
    digitiser: Digitiser = spec("digitiser")
    sequencer: Sequencer = spec("transmit sequencer")
    lever_arms: LeverArms = spec("lever arms")


# ---------------------------------------------------------------------------- daq


@dataclass(frozen=True)
class PublisherConfig:
    endpoint: str = spec("ZeroMQ endpoint the ping publisher binds")
    send_hwm: int = spec("ZeroMQ send high-water mark, messages queued per subscriber; "
                         "beyond it pings to that subscriber are dropped and counted",
                         lo=1, hi=10**6)
    end_timeout_s: float | None = spec("seconds the end-of-run marker is retried while a "
                                       "subscriber's queue stays full (omitted: 10.0)",
                                       lo=0.0, hi=3600)


@dataclass(frozen=True)
class SubscriberConfig:
    receive_hwm: int = spec("ZeroMQ receive high-water mark of a ping subscriber, messages",
                            lo=1, hi=10**6)
    gap_wait_s: float | None = spec("tile worker without a catch-up service: seconds a "
                                    "sequence gap is waited for before it is skipped "
                                    "(omitted: 2.0)", lo=0.0, hi=3600, default=2.0)
    reorder_pings: int | None = spec("tile worker: pings held at most in its reorder "
                                     "buffer (480 kB each; omitted: 200)", lo=1, hi=100000,
                                     default=200)
    max_sequence_jump: int | None = spec(
        "tile worker: a ping more than this many sequences past the run's expected one "
        "(plus the pings sent since that last moved) is refused and counted unless the "
        "catch-up service's recording holds it (omitted: 1000)", lo=1, hi=10**9,
        default=1000)
    max_listed_gaps: int | None = spec(
        "tile worker: ranges of skipped pings (never imaged) listed in a run's journal "
        "and manifest at most; beyond, their pings are counted (omitted: 100)", lo=1,
        hi=10**6, default=100)


#: what a tile worker behind the sonar does (daq.toml ``[worker] when_behind``)
WHEN_BEHIND = ("quicklook_first", "full_products")


@dataclass(frozen=True)
class WorkerConfig:
    """A tile worker behind the sonar (docs/worker.md, *Behind the sonar*). Every key may
    be omitted: its default is given here."""
    behind_s: float | None = spec(
        "a tile worker whose pings reach its imager this many seconds after their "
        "transmit time (less the smallest such delay of the run) is behind: it logs the "
        "alarm worker.behind and degrades by when_behind", lo=0.0, hi=86400, default=20.0)
    caught_up_s: float | None = spec(
        "... and has caught up again once a ping reaches its imager within this many "
        "seconds (the alarm is cleared, deferred products are finished), s", lo=0.0,
        hi=86400, default=5.0)
    when_behind: str | None = spec(
        "what a worker behind does: quicklook_first (every ping is still imaged; a "
        "completed tile gets its quick-look PNG at once and its full products and tile "
        "file once caught up, or at the run's end) or full_products (no degrading: the "
        "alarm only)", choices=WHEN_BEHIND, default="quicklook_first")
    max_deferred_tiles: int | None = spec(
        "tiles whose full products wait at most (their image planes stay in memory, 60 MB "
        "per default tile in float32); beyond, the oldest is finished at once", lo=1,
        hi=1000, default=4)
    products: str | None = spec(
        "where a live worker makes a completed tile's full products (background, "
        "detections, tile file, PNG): process (a second process, beside the imaging: "
        "docs/keeping_up.md) or inline (the worker waits for them)",
        choices=("process", "inline"), default="process")
    products_threads: int | None = spec(
        "numba threads of the products process (1: the imaging keeps both cores of a "
        "2-core machine when it needs them)", lo=1, hi=1024, default=1)
    products_nice: int | None = spec(
        "the products process's niceness above the worker's: the imaging, which must "
        "keep up with the pings, goes first and the products take the cores' idle time "
        "(0: equal shares)", lo=0, hi=19, default=10)
    products_in_flight: int | None = spec(
        "tiles handed to the products process and not yet written at most (their image "
        "planes stay in memory, 60 MB per default tile); beyond, the worker waits",
        lo=1, hi=100, default=2)


@dataclass(frozen=True)
class ServiceConfig:
    endpoint: str = spec("ZeroMQ endpoint of the catch-up ping service (ROUTER) that "
                         "serves recorded pings to the tile worker (docs/catchup.md)")
    request_timeout_s: float = spec("a catch-up client's wait for each reply, s",
                                    lo=0.01, hi=3600)
    max_pings_per_reply: int = spec("pings in one catch-up reply at most (480 kB each)",
                                    lo=1, hi=10000)
    max_clients: int = spec("clients a reply is sent to at once; a fetch beyond them is "
                            "answered busy (the client asks again), and as many stalled "
                            "clients are remembered (their requests refused)", lo=1,
                            hi=1000)
    client_queue: int = spec("messages ZeroMQ queues for each client, each way (a ping is "
                             "one message, 480 kB): the most a client that does not read "
                             "costs the service", lo=1, hi=10000)
    stall_s: float = spec("a reply that could send nothing to its client for this long "
                          "is abandoned and that client refused from then on, s",
                          lo=0.01, hi=3600)
    max_workers: int = spec("tile workers whose progress (svss.progress: the run, the "
                            "first ping each still lacks) the service keeps; a worker "
                            "beyond them is refused, counted and logged", lo=1, hi=1000)
    worker_silence_s: float = spec("a worker whose progress has not come for this long is "
                                   "silent: kept, with the alarm worker.silent raised (a "
                                   "silent worker that lacks pings keeps the daemon up "
                                   "after the run, at most catch_up.max_linger_s), s",
                                   lo=0.1, hi=3600)
    progress_interval_s: float = spec("a tile worker tells the service its progress this "
                                      "often (well within worker_silence_s), s", lo=0.01,
                                      hi=600)


@dataclass(frozen=True)
class RecorderConfig:
    flush_every_pings: int = spec("flush the raw file at least every N pings", lo=1, hi=100000)
    flush_interval_s: float = spec("flush the raw file at least every T seconds", lo=0.0, hi=3600)


@dataclass(frozen=True)
class DaqConfig:
    publisher: PublisherConfig = spec("ping publisher")
    subscriber: SubscriberConfig = spec("ping subscriber (the tile worker)")
    recorder: RecorderConfig = spec("raw-run recorder")
    service: ServiceConfig | None = spec("catch-up ping service for the tile worker "
                                         "(omitted: none)")
    worker: WorkerConfig | None = spec("what a tile worker behind the sonar does "
                                       "(omitted: the defaults of every key)")
    security: CurveConfig | None = spec("ZeroMQ CURVE keys of the endpoints "
                                                  "(omitted: disabled; docs/security.md)")


def worker_section(daq: DaqConfig) -> WorkerConfig:
    """daq.toml's ``[worker]``: its table, or every default when it has none."""
    return daq.worker if daq.worker is not None else from_dict(WorkerConfig, {},
                                                               "[worker] defaults")




@dataclass(frozen=True)
class CurveConfig:
    """The ``[security]`` table of daq.toml."""
    enabled: bool = spec("secure the ZeroMQ endpoints with CURVE (false: plain TCP, "
                         "for loopback and a trusted boat LAN only)")
    server_secret_key: str = spec("server side: the server's secret key file (zcert, "
                                  "'svss keys --name server' writes server.key_secret)")
    authorized_clients: str = spec("server side: folder of the public key files (*.key) "
                                   "of the clients allowed to connect")
    server_public_key: str = spec("client side: the server's public key file "
                                  "(server.key)")
    client_secret_key: str = spec("client side: this client's secret key file "
                                  "(NAME.key_secret)")


# -------------------------------------------------------------------------- devices


@dataclass(frozen=True)
class SequencerLinkConfig:
    port: str = spec("serial port of the transmit sequencer (device path or symlink)")
    baudrate: int = spec("serial baud rate, bit/s", lo=1200, hi=4_000_000)
    reply_timeout_s: float = spec("wait for a command's reply, s", lo=0.01, hi=60)
    retries: int = spec("re-sends of a command after a reply timeout", lo=0, hi=20)
    open_timeout_s: float = spec("wait for the port to open, s", lo=0.01, hi=600)
    queue_records: int = spec("transmit records the driver queues for a reader at most "
                              "(none when it hands them to a callback, as the daemon's); "
                              "beyond, one is dropped, counted and logged", lo=1,
                              hi=10**6)


@dataclass(frozen=True)
class DigitiserLinkConfig:
    host: str = spec("digitiser host name or address")
    port: int = spec("digitiser TCP port", lo=1, hi=65535)
    connect_timeout_s: float = spec("TCP connect timeout, s", lo=0.01, hi=600)
    reply_timeout_s: float = spec("wait for a control reply, s", lo=0.01, hi=60)
    reconnect_initial_s: float = spec("first reconnection delay, s (doubles)", lo=0.001, hi=60)
    reconnect_max_s: float = spec("largest reconnection delay, s", lo=0.001, hi=600)
    ping_timeout_s: float = spec("a ping with no new frame for this long is reported "
                                 "incomplete, s", lo=0.01, hi=60)
    max_payload_bytes: int = spec("largest frame payload accepted, bytes",
                                  lo=1024, hi=1 << 30)
    queue_pings: int = spec("pings (and gaps) the driver holds for the daemon at most; "
                            "beyond, one is dropped, counted and logged (480 kB each)",
                            lo=1, hi=100000)


@dataclass(frozen=True)
class DvlLinkConfig:
    port: str = spec("serial port of the DVL (PD0 ensembles; device path or symlink)")
    baudrate: int = spec("serial baud rate, bit/s", lo=1200, hi=4_000_000)


@dataclass(frozen=True)
class GpsLinkConfig:
    port: str = spec("serial port of the GPS receiver (NMEA 0183; device path or symlink)")
    baudrate: int = spec("serial baud rate, bit/s", lo=1200, hi=4_000_000)


@dataclass(frozen=True)
class NavigationConfig:
    origin_latitude_deg: float | None = spec(
        "survey origin geodetic latitude, deg (omitted: the first GPS fix's)", lo=-90, hi=90)
    origin_longitude_deg: float | None = spec(
        "survey origin longitude, deg (omitted: the first GPS fix's)", lo=-180, hi=360)
    origin_height_m: float | None = spec(
        "survey origin ellipsoidal height, m (omitted: the first fix that has one)", lo=-1e4, hi=1e5)
    dvl_beam_angle_deg: float = spec("DVL Janus beam angle from the vertical, deg, used "
                                     "only where the PD0 fixed leader sends none "
                                     "(RDI: 20 or 30)", lo=1, hi=60)
    dvl_min_beams: int = spec("valid bottom-track beams needed for velocity and "
                              "altitude", lo=3, hi=4)
    magnetic_declination_deg: float = spec(
        "magnetic declination (east positive) added to the DVL compass heading where the "
        "instrument applies none itself (PD0 heading bias EB 0), deg", lo=-180, hi=180)
    gps_fix_max_age_s: float = spec("a pose further than this from a GPS fix is flagged "
                                    "dead-reckoned, s", lo=0.01, hi=600)
    dvl_max_gap_s: float = spec("DVL samples further apart than this break dead "
                                "reckoning, s", lo=0.01, hi=600)
    heading_max_age_s: float = spec("a heading source older than this is not used (HDT, "
                                    "then the DVL compass, then the RMC course), s",
                                    lo=0.01, hi=600)
    course_min_speed_m_s: float = spec("RMC course is used as heading only above this "
                                       "speed, m/s", lo=0, hi=50)
    gps_max_sigma_m: float = spec("fixes whose GST horizontal sigma (DRMS) exceeds this "
                                  "are rejected, m (no GST: no limit)", lo=0.001, hi=1e4)
    clock_max_offset_s: float = spec("an instrument clock further than this from the ping "
                                     "clock (median over clock_records records of receive "
                                     "minus instrument time) is re-timed onto it, s",
                                     lo=0.1, hi=1e9)
    clock_records: int = spec("records whose median judges an instrument's clock", lo=1,
                              hi=1000)
    clock_window_s: float = spec("an instrument's clock is judged on its records of this "
                                 "long (instrument time; at least clock_records), every "
                                 "one of which must be off, s", lo=0.0, hi=3600)
    held_clear_s: float = spec("the acquisition says pings are no longer posed on held "
                               "navigation once none was for this long (ping time), s",
                               lo=0.0, hi=3600)
    # the fusion's noise model (docs/navigation.md, "Fusion"): the instruments' specifications
    dvl_velocity_sigma_m_s: float = spec("DVL bottom-track velocity noise per component and "
                                         "ensemble, m/s (1 sigma)", lo=1e-5, hi=1.0)
    dvl_velocity_bias_sigma_m_s: float = spec("DVL long-term velocity accuracy (bias) per "
                                              "horizontal component, m/s (1 sigma)",
                                              lo=0.0, hi=1.0)
    dvl_bias_correlation_s: float = spec("correlation time of the DVL velocity bias "
                                         "(first-order Gauss-Markov), s", lo=1.0, hi=1e6)
    dvl_range_sigma_m: float = spec("DVL bottom-track range noise per beam, m (1 sigma)",
                                    lo=1e-4, hi=10.0)
    gps_sigma_m: float = spec("GPS horizontal noise per axis where no GST is sent, m "
                              "(1 sigma)", lo=1e-3, hi=1e3)
    gps_height_sigma_m: float = spec("GPS height noise, m (1 sigma)", lo=1e-3, hi=1e3)
    bottom_depth_rate_sigma_m_s: float = spec("how fast the bottom's depth under the DVL may "
                                              "change beyond its slope, m/s (random-walk "
                                              "intensity)", lo=1e-6, hi=10.0)
    bottom_slope_sigma_per_m: float = spec("how fast the bed's gradient under the DVL may "
                                           "change along the track, per metre travelled "
                                           "(random-walk intensity, 1/sqrt(m))",
                                           lo=0.0, hi=10.0)
    bottom_max_slope_deg: float = spec("the steepest bed one DVL sample's beam footprints "
                                       "may show; a sample showing a steeper one has its "
                                       "ranges left out (a beam off the bed), deg",
                                       lo=1.0, hi=80.0)
    dvl_gap_velocity_sigma_m_s: float = spec("velocity uncertainty while the DVL has no "
                                             "bottom lock (last velocity held), m/s",
                                             lo=1e-3, hi=100.0)
    # the attitude's noise (the poses interpolate it linearly between samples): what it
    # does to the ping-to-ping increments of the array (svss_proc.micronav.renav)
    heading_sigma_deg: float = spec("true-heading (HDT) noise per sample, deg (1 sigma)",
                                    lo=0.0, hi=30.0)
    heading_interval_s: float = spec("interval between true-heading samples, s (the poses' "
                                     "heading is interpolated between them)",
                                     lo=1e-3, hi=60.0)
    dvl_tilt_sigma_deg: float = spec("DVL roll and pitch noise per ensemble, deg (1 sigma)",
                                     lo=0.0, hi=30.0)
    dvl_interval_s: float = spec("interval between DVL ensembles, s (the poses' roll and "
                                 "pitch are interpolated between them)", lo=1e-3, hi=60.0)
    live_follow_s: float = spec("live poses keep each solution's ping-to-ping geometry and "
                                "follow its slow corrections over this time, s",
                                lo=0.01, hi=600.0)
    fixed_lag_s: float = spec("live smoother's lag: a ping is posed with the records up to "
                              "this long after it, s (0: with the records that are there)", lo=0.0, hi=60.0)


@dataclass(frozen=True)
class DevicesConfig:
    sequencer: SequencerLinkConfig = spec("transmit sequencer serial link")
    digitiser: DigitiserLinkConfig = spec("digitiser TCP link")
    dvl: DvlLinkConfig | None = spec("DVL serial link (omitted: no DVL link)")
    gps: GpsLinkConfig | None = spec("GPS serial link (omitted: no GPS link)")
    navigation: NavigationConfig = spec("navigation: survey origin, DVL geometry, fusion")


__all__ = ["CONFIG_ENV", "ConfigError", "spec", "omitted_default", "ReceiveSection",
           "ReceiveArray", "Projectors", "Beams", "WaveformConfig", "Digitiser",
           "Sequencer", "LeverArms", "HardwareConfig", "TileConfig",
           "ConditioningConfig", "SedimentLayerConfig", "ImagingConfig",
           "BackgroundConfig", "DepthGainConfig", "DrcConfig", "DetectionConfig",
           "QuicklookConfig", "FeaturesConfig", "ClassifyConfig", "PingClassifyConfig",
           "SpectraConfig",
           "ProductsConfig",
           "PingGateConfig",
           "LimitsConfig",
           "MicronavConfig", "AutofocusConfig", "SeabedConfig", "ProcessingConfig",
           "PublisherConfig", "SubscriberConfig", "WHEN_BEHIND", "WorkerConfig",
           "ServiceConfig", "RecorderConfig", "DaqConfig", "worker_section",
           "SHIPPED_FILES", "from_dict", "read_toml", "load", "loads", "config_dir",
           "config_path", "digest", "Loaded", "load_with_text", "loaded_from_text",
           "CurveConfig", "SequencerLinkConfig", "DigitiserLinkConfig", "DvlLinkConfig",
           "GpsLinkConfig", "NavigationConfig", "DevicesConfig"]
