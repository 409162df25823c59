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
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
import tomllib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")

CONFIG_ENV = "SVSS_CONFIG_DIR"


class ConfigError(ValueError):
    """A configuration file is missing, unreadable or invalid."""


def spec(doc: str, lo: float | None = None, hi: float | None = None,
         choices: tuple | None = None, length: int | None = None,
         min_length: int | None = None, default: Any = None) -> Any:
    """Declare a schema field: ``doc`` with units, inclusive range, allowed values,
    exact or minimum sequence length, and for an optional (``X | None``) field the value
    :func:`load` gives it when the file omits it."""
    return field(metadata={"doc": doc, "lo": lo, "hi": hi, "choices": choices,
                           "length": length, "min_length": min_length,
                           "default": default})


def omitted_default(cls: type, name: str) -> Any:
    """The value :func:`load` gives field ``name`` of schema ``cls`` when a file omits
    it (its :func:`spec` ``default``; None where it has none)."""
    return {f.name: f for f in dataclasses.fields(cls)}[name].metadata.get("default")


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


# ------------------------------------------------------------------------- processing


@dataclass(frozen=True)
class TileConfig:
    length_m: float = spec("tile length along-track, m", lo=0.1, hi=1000)
    width_m: float = spec("tile width cross-track, centred on the track line, m", lo=0.04, hi=100)
    depth_m: float = spec("tile depth below the water-sediment interface, m", lo=0.04, hi=100)
    top_m: float = spec("depth of the tile's first voxel layer below the interface "
                        "(negative: above), m", lo=-10, hi=10)
    voxel_m: float = spec("voxel edge, m", lo=1e-3, hi=1.0)
    close_after_pings: int | None = spec(
        "a tile is complete once this many consecutive pings' along-track reach has "
        "stayed clear of it (works forward, reversing and stopped; omitted: 20; "
        "docs/worker.md)", lo=1, hi=100000, default=20)


@dataclass(frozen=True)
class ConditioningConfig:
    decimation: int = spec("decimation of the complex baseband relative to the ADC rate",
                           lo=1, hi=64)
    upsample: int = spec("band-limited (FFT) upsampling of the decimated baseband before "
                         "interpolation", lo=1, hi=64)


@dataclass(frozen=True)
class SedimentLayerConfig:
    """One sediment layer above the half-space of ``sediment_sound_speed_m_s`` (a core
    sample's stratum, top first)."""
    thickness_m: float = spec("the layer's thickness, m", lo=0.0, hi=100.0)
    sound_speed_m_s: float = spec("the layer's sound speed, m/s", lo=1000, hi=3000)


@dataclass(frozen=True)
class ImagingConfig:
    water_sound_speed_m_s: float = spec("water sound speed for imaging delays, m/s",
                                        lo=1000, hi=2500)
    interface: str = spec("interface depth source: the first ping's body depth plus "
                          "altitude (navigation), that and each ping's own altitude for its "
                          "height (altitude), or interface_down_m (fixed)",
                          choices=("navigation", "altitude", "fixed"))
    interface_down_m: float = spec("interface depth in the survey frame when fixed, m",
                                   lo=-1e4, hi=1e4)
    track_line: str = spec("tile frame: from the first ping's pose or given",
                           choices=("first_ping", "fixed"))
    line_origin_ne_m: tuple[float, float] = spec("fixed line origin (north, east), m", length=2)
    line_heading_deg: float = spec("fixed line heading, deg from north", lo=-360, hi=360)
    beam_gating: bool = spec("only voxels inside both beam cones are summed")
    delays: str = spec("travel times: straight rays at water_sound_speed_m_s; 'table': per-ping "
                       "refraction table; 'exact': Fermat path per voxel and element",
                       choices=("straight", "table", "exact"))
    sediment_sound_speed_m_s: float = spec(
        "sediment sound speed for refracted delays (the half-space below any "
        "sediment_layers; with [seabed] speed = 'estimate' the value kept where the echoes "
        "do not constrain it), m/s", lo=1000, hi=3000)
    sediment_layers: tuple[SedimentLayerConfig, ...] = spec(
        "sediment layers between the interface and the half-space, top first (table "
        "delays only; omitted: none)", min_length=0)
    table_step_m: float = spec("refraction table spacing in offset and depth, m",
                               lo=1e-4, hi=0.5)
    interpolation: str = spec("sample interpolation", choices=("nearest", "linear", "cubic"))
    precision: str = spec("kernel arithmetic", choices=("float32", "float64"))
    apodisation: str = spec("receive-aperture weighting", choices=("none", "hann"))
    device: str = spec("where the kernel runs", choices=("cpu", "cuda"))
    gpu_pings_per_launch: int | None = spec(
        "on the GPU, pings of a tile imaged by one kernel launch (each voxel summed over "
        "them, then added once); omitted: 16", lo=1, hi=256, default=16)
    interface_slope_deg: tuple[float, float] | None = spec(
        "the interface as a plane: its slope along the track line and across it, deg, "
        "positive where it deepens ahead and to starboard (voxel depths are then below "
        "the plane at each column; with [seabed] speed = 'estimate' it is estimated); "
        "omitted: level", lo=-45, hi=45, length=2, default=(0.0, 0.0))
    interface_relief_m: tuple[tuple[float, ...], ...] | None = spec(
        "the interface's relief about that plane: its depth below the plane, m, at the "
        "nodes of a grid along the track line (rows) and across it (columns) from "
        "interface_relief_origin_m in steps of interface_relief_step_m (bilinear between "
        "nodes, the edge's value beyond them; with [seabed] relief = 'estimate' it is "
        "estimated from the interface's echo); omitted: none", lo=-5, hi=5)
    interface_relief_origin_m: tuple[float, float] | None = spec(
        "along and across the track line of the relief's first node, m", length=2,
        default=(0.0, 0.0))
    interface_relief_step_m: tuple[float, float] | None = spec(
        "the relief's node spacing along and across the track line, m", lo=0.01, hi=100,
        length=2, default=(0.25, 0.25))


@dataclass(frozen=True)
class BackgroundConfig:
    kernel_m: tuple[float, float, float] = spec(
        "median kernel extent (along, cross, depth), m; rounded to odd voxel counts",
        length=3, lo=0.0, hi=100.0)
    method: str = spec("'exact' median, or 'histogram': the median of magnitudes quantised "
                       "to histogram_bin_db bins (error at most half a bin)",
                       choices=("exact", "histogram"))
    histogram_bin_db: float = spec("histogram method: bin width, dB", lo=1e-3, hi=6.0)
    boundary: str = spec("how windows extend past the tile's faces (scipy.ndimage modes; "
                         "'truncate': only voxels inside)",
                         choices=("reflect", "mirror", "nearest", "truncate"))
    ignore_zeros: bool = spec("leave exactly-zero voxels (no ping reached them) out of the "
                              "median")
    floor_db: float = spec("smallest background divided by, dB re the tile's median "
                           "background", lo=-300, hi=0)
    coverage_whitening: bool | None = spec(
        "divide each magnitude by the square root of the ping-channel pairs that reached "
        "the voxel before the median, and multiply the median back (the background then "
        "follows the coverage; omitted: true)", default=True)
    across_seams: bool | None = spec(
        "take the neighbouring tiles' planes across each along-track seam into the "
        "background windows and the previous tile's contacts as sidelobe sources, so that "
        "a tile's edge is processed like its middle (the streaming worker, svss process "
        "and svss batch, whose products are made in tile order: docs/batch.md; omitted: "
        "true)", default=True)
    below_edge_from_m: float | None = spec(
        "below this depth under the interface, m, each voxel's background is the greater "
        "of its window's median and the median of the window just beneath it (a "
        "greatest-of estimate: the upper edge of a brighter layer below, a multiple or a "
        "layer boundary, is judged against that layer, not normalised into a bright edge; "
        "omitted: off)", lo=-10.0, hi=100.0, default=None)


@dataclass(frozen=True)
class DepthGainConfig:
    db_per_m: float = spec("depth-varying gain added to the normalised level before "
                           "compression (display only: detections use the level without "
                           "it), dB/m (0: none)", lo=-200, hi=200)
    start_m: float = spec("depth below the interface where the gain starts (0 dB above), m",
                          lo=-10, hi=100)


@dataclass(frozen=True)
class DrcConfig:
    floor_db: float = spec("normalised level shown as 0 (and everything below), dB re "
                           "background", lo=-100, hi=100)
    knee_db: float = spec("normalised level above which levels are compressed, dB re "
                          "background", lo=-100, hi=200)
    ceiling_db: float = spec("level the compressed map approaches (shown as 1), dB re "
                             "background", lo=-100, hi=300)


@dataclass(frozen=True)
class DetectionConfig:
    threshold_db: float = spec("detection threshold on the normalised level, dB re "
                               "background", lo=0, hi=200)
    min_voxels: int = spec("smallest contact, voxels above the threshold", lo=1, hi=10**9)
    merge_m: tuple[float, float, float] = spec(
        "contacts whose peaks are closer than this (along, cross, depth) are merged into "
        "the stronger one, m", length=3, lo=0.0, hi=100.0)
    sidelobe_db: float = spec("a contact this much (or more) weaker than a stronger one "
                              "within sidelobe_m is taken for its sidelobe and dropped, dB",
                              lo=0, hi=300)
    sidelobe_m: float = spec("sidelobe suppression radius, m (0: none)", lo=0.0, hi=100)
    sidelobe_footprint: bool | None = spec(
        "also take for a sidelobe a contact sidelobe_db weaker (peak magnitude) that one "
        "ping's projector cone sees together with the stronger one (omitted: true)",
        default=True)
    point_threshold_db: float | None = spec(
        "a region above threshold_db is a contact only if its peak reaches this level "
        "or it is an extended object (extended_min_m3), dB re background (omitted: "
        "threshold_db: every region)", lo=0, hi=200)
    extended_min_m3: float | None = spec(
        "smallest volume above threshold_db that makes a region a contact whatever its "
        "peak, m^3 (omitted: none)", lo=0.0, hi=1e3)
    min_coverage_fraction: float | None = spec(
        "voxels imaged by fewer pings than this fraction of the full coverage at their "
        "depth never detect (omitted: 0.5)", lo=0.0, hi=1.0, default=0.5)
    later_echo_m: tuple[float, float, float] | None = spec(
        "a weaker contact within this (along, cross) of a stronger one and up to this "
        "depth below it is that object's later echo (its ringing, its internal paths) "
        "and merges into it, m (omitted: none)", length=3, lo=0.0, hi=10.0)
    layer_false_alarms_per_m3: float | None = spec(
        "a threshold per depth layer from the layer's own clutter: the level its fitted "
        "tail reaches this many false alarms per m^3 at, where above threshold_db "
        "(omitted: threshold_db everywhere)", lo=1e-12, hi=1e3)
    max_per_tile: int = spec("most contacts kept per tile (strongest first)", lo=1,
                             hi=10**6)
    match_radius_m: float = spec("scoring: a detection within this distance of a true "
                                 "target detects it, m", lo=0.0, hi=100)


@dataclass(frozen=True)
class QuicklookConfig:
    depth_slices_m: tuple[float, ...] = spec("depths below the interface of the depth "
                                             "slices shown, m", min_length=0)
    dpi: int = spec("PNG resolution, dots per inch", lo=20, hi=600)
    max_labels: int | None = spec("contacts labelled on the views, strongest first (the "
                                  "rest are listed; omitted: 12)", lo=0, hi=1000,
                                  default=12)


@dataclass(frozen=True)
class ProductsConfig:
    background: BackgroundConfig = spec("background estimation by a 3-D median")
    depth_gain: DepthGainConfig = spec("depth-varying gain")
    drc: DrcConfig = spec("dynamic range compression for display")
    detection: DetectionConfig = spec("contacts in the normalised volume")
    quicklook: QuicklookConfig = spec("PNG quicklooks")
    store_volumes: bool = spec("write the background and the compressed volume into the "
                               "tile file (each as large as the magnitude)")


@dataclass(frozen=True)
class PingGateConfig:
    max_speed_m_s: float = spec("largest platform speed between accepted pings, m/s; a "
                                "ping further from the last accepted one is a jump",
                                lo=0.01, hi=100)
    jump_slack_m: float = spec("position noise allowed on top of the speed bound, m",
                               lo=0.0, hi=1000)
    max_roll_deg: float = spec("largest plausible roll, deg", lo=0.1, hi=89)
    max_pitch_deg: float = spec("largest plausible pitch, deg", lo=0.1, hi=89)
    height_m: tuple[float, float] = spec("plausible projector height above the interface "
                                         "(min, max), m", length=2)
    max_line_offset_m: float = spec("largest cross-track distance of the array from the "
                                    "track line, m", lo=0.0, hi=1e5)
    reanchor_pings: int = spec("consecutive mutually consistent pings that are taken as "
                               "the new track after a jump", lo=2, hi=1000)
    # what a pose its navigation flagged may image (svss_daq.ping NAV_*); a pose without
    # heading or without position never does
    held: str = spec("a pose extrapolated past the last navigation record (NAV_HELD)",
                     choices=("image", "refuse"))
    dead_reckoned: str = spec("a position dead-reckoned on the DVL, no GPS fix at the "
                              "ping (NAV_DEAD_RECKONED)", choices=("image", "refuse"))
    clock_retimed: str = spec("a pose from instrument records re-timed by their receive "
                              "times (clocks in disagreement, NAV_CLOCK_RETIMED)",
                              choices=("image", "refuse"))
    heading_from_course: str = spec("a heading from the GPS course over ground "
                                    "(NAV_HEADING_FROM_COURSE)", choices=("image", "refuse"))
    heading_from_compass: str = spec("a heading from the DVL's magnetic compass "
                                     "(NAV_HEADING_FROM_COMPASS)", choices=("image", "refuse"))


@dataclass(frozen=True)
class LimitsConfig:
    memory_gib: float = spec("memory the imager's open tiles (image planes) and one "
                             "tile's products may take, GiB; it bounds how many tiles are "
                             "open at once and how many one ping may reach",
                             lo=0.001, hi=4096)


@dataclass(frozen=True)
class MicronavConfig:
    """Micronavigation (docs/micronavigation.md): in the re-navigation of a recorded run
    (``enabled``; svss_proc.micronav.renav) and in the tile worker on the live poses
    (``live``; svss_proc.micronav.live). The navigation's own step sigma is the
    navigation configuration's (devices.toml ``[navigation]``)."""
    enabled: bool = spec("fuse the echoes' ping-to-ping increments with the re-navigated "
                         "poses (svss process / svss batch; --micronav overrides)")
    live: bool = spec("the tile worker estimates each ping's displacement from the "
                      "previous one and images it at the pose fused with the live "
                      "navigation's increment (docs/worker.md)")
    acceleration_sigma_m_s2: float = spec(
        "the fusion's prior on the platform's acceleration (a second difference of the "
        "ping positions of this times the ping interval squared), m/s^2 (1 sigma)",
        lo=1e-4, hi=100.0)
    anchor_sigma_m: float = spec("weak pull of the fused positions toward the "
                                 "navigation's, m (1 sigma)", lo=1e-3, hi=1e4)
    max_seed_sigma_m: float = spec(
        "the estimator starts from the navigation's increment where its sigma is below "
        "this, else from the last echo increment (a DVL dropout), m", lo=1e-5, hi=1.0)
    bias_min_steps: int = spec(
        "the echoes' mean increment error (their surge bias) is measured against the "
        "navigation's on at least this many steps with bottom lock and taken out of "
        "every echo increment; fewer: not", lo=1, hi=10**6)
    passes: int = spec("estimator passes per ping pair (b re-placed where the first "
                       "found it)", lo=1, hi=4)
    translations: int = spec("common sub-apertures per ping pair, interpolated to zero "
                             "offset", lo=1, hi=2)


@dataclass(frozen=True)
class AutofocusConfig:
    """Autofocus on isolated responses (svss_proc.micronav.autofocus,
    docs/autofocus.md): which responses it may focus on and the guard
    that keeps its corrections only where the image gets no worse."""
    enabled: bool = spec("a stage of svss process and svss batch: each run imaged with its "
                         "poses, focused on its isolated responses and imaged again with "
                         "the corrected poses where the guard accepts them "
                         "(--autofocus / --no-autofocus override it)")
    points: int = spec("isolated responses focused on, at most", lo=1, hi=100)
    candidates: int = spec("local maxima of the image examined, brightest first", lo=1,
                           hi=100000)
    interface_clearance_m: float = spec(
        "responses this close below the interface (tile depth 0) or above it are not "
        "picked: the interface's own echo, m", lo=0.0, hi=10.0)
    background_m: tuple[float, float, float] = spec(
        "half-size (along, cross, depth) of the box around a response whose median "
        "magnitude is its local background, m", length=3)
    core_m: tuple[float, float, float] = spec(
        "half-size (along, cross, depth) of a response's own main lobe, left out of its "
        "background and of its neighbours, m", length=3)
    min_contrast_db: float = spec("a response's peak over its local background (median), "
                                  "at least, dB", lo=0.0, hi=100.0)
    min_isolation_db: float = spec("a response's peak over the brightest voxel of its "
                                   "box outside its main lobe, at least, dB", lo=0.0,
                                   hi=100.0)
    min_separation_m: float = spec("picked responses at least this far apart, m", lo=0.0,
                                   hi=100.0)
    peak_search_m: float = spec("a point's peak is the largest magnitude within this of "
                                "it (the points are moved to their peaks before the fit), "
                                "m", lo=0.0, hi=1.0)
    peak_step_m: float = spec("the grid step of that search, m", lo=1e-4, hi=0.1)
    holdout_min_points: int = spec(
        "with at least this many responses every third is held out of the fit and judges "
        "it (fewer: none held out)", lo=2, hi=100)
    point_guard: float = spec("a focused point may fall to 1 - this of its peak (the "
                              "points' summed power must grow)", lo=0.0, hi=1.0)
    holdout_guard: float = spec("a held-out point may fall to 1 - this of its peak (their "
                                "summed power must not fall)", lo=0.0, hi=1.0)
    sharpness_tolerance: float = spec(
        "the image's sharpness (mean |I|^4 below the interface clearance, "
        "over the points' along-track span and region_margin_m) may fall by this "
        "fraction", lo=0.0, hi=1.0)
    region_margin_m: float = spec("the sharpness region extends this far along-track "
                                  "beyond the outermost points, m", lo=0.0, hi=100.0)


@dataclass(frozen=True)
class SeabedConfig:
    """The sediment's sound speed from the echoes (svss_proc.seabed, docs/seabed.md): the
    speed that best focuses the isolated buried responses of a run."""
    speed: str = spec("the sediment speed the tiles are imaged with: 'estimate' (from the "
                      "echoes; imaging.sediment_sound_speed_m_s kept where nothing below "
                      "the interface constrains it) or 'configured' (as given)",
                      choices=("estimate", "configured"))
    speed_range_m_s: tuple[float, float] = spec(
        "the speeds searched, m/s (the seed's sediments: 1476 silt to 1767 sand)",
        length=2)
    coarse_step_m_s: float = spec("the first scan's step, m/s", lo=1.0, hi=500.0)
    fine_step_m_s: float = spec("the second scan's step about the first's best, m/s",
                                lo=0.5, hi=100.0)
    points: int = spec("isolated buried responses focused on, at most", lo=1, hi=100)
    rounds: int = spec("picks and scans: each round after the first picks the responses "
                       "again on an image made with the last round's estimate (focused "
                       "there, deeper responses stand out of their background)", lo=1,
                       hi=5)
    min_points: int = spec("responses needed for an estimate (fewer: the configured "
                           "speed kept, saying so)", lo=1, hi=100)
    min_depth_m: float = spec("responses at least this far below the interface: the "
                              "speed must act on them, m", lo=0.0, hi=10.0)
    min_contrast_db: float = spec("a response's peak over its local background (median), "
                                  "at least, dB", lo=0.0, hi=100.0)
    min_isolation_db: float = spec("a response's peak over the brightest voxel of its box "
                                   "outside its main lobe, at least, dB", lo=0.0, hi=100.0)
    search_voxel_m: float = spec("voxel edge of the image the responses are picked from "
                                 "(coarser than the tiles': cheaper), m", lo=1e-3, hi=0.2)
    box_m: tuple[float, float, float] = spec(
        "half-size (along, cross, depth) of the box imaged about each response at each "
        "trial speed, m (its depth follows the speed)", length=3)
    box_step_m: float = spec("voxel edge of those boxes, m", lo=1e-3, hi=0.1)
    layers: bool = spec("a two-layer profile where the picking image shows a layer "
                        "boundary with responses above and below it")
    boundary_min_db: float = spec("a layer boundary: a depth whose median level stands "
                                  "this far over the median of the levels about it, dB",
                                  lo=0.0, hi=60.0)
    boundary_window_m: float = spec("the depth span of those levels, m", lo=0.05, hi=10.0)
    disagree_sigmas: float = spec("a configured speed this many of the estimate's "
                                  "standard deviations away is reported as disagreeing",
                                  lo=0.0, hi=100.0)
    slope: str | None = spec("the interface's slope the tiles are imaged over: 'estimate' "
                             "(along the track from the navigation's bed depths, across it "
                             "from the interface's own echo) or 'configured' "
                             "(imaging.interface_slope_deg); omitted: configured",
                             choices=("estimate", "configured"), default="configured")
    relief: str | None = spec("the interface's relief about its plane: 'estimate' (from "
                              "the interface's echo, column by column, where it stands out "
                              "of its own uncertainty) or 'configured' "
                              "(imaging.interface_relief_m); omitted: configured",
                              choices=("estimate", "configured"), default="configured")


@dataclass(frozen=True)
class ProcessingConfig:
    tile: TileConfig = spec("image tile geometry")
    conditioning: ConditioningConfig = spec("signal conditioning")
    imaging: ImagingConfig = spec("image formation")
    ping_gate: PingGateConfig = spec("plausibility of each ping's pose before it is imaged")
    limits: LimitsConfig = spec("bounds on the imager's memory")
    products: ProductsConfig | None = spec("image products (omitted: tiles carry the image "
                                           "only)")
    micronav: MicronavConfig | None = spec("micronavigation in the re-navigation and "
                                           "the tile worker (omitted: off in both)")
    autofocus: AutofocusConfig | None = spec("autofocus on isolated responses (omitted: "
                                             "config/processing.toml's)")
    seabed: SeabedConfig | None = spec("the sediment's speed from the echoes (omitted: "
                                       "the configured speed, as given)")

    def config_problem(self) -> tuple[str, str] | None:
        """(dotted key, what is wrong) across tables, or None (checked on load)."""
        for i, layer in enumerate(self.imaging.sediment_layers):
            if layer.thickness_m < self.tile.voxel_m:
                return (f"imaging.sediment_layers[{i}].thickness_m",
                        f"got {layer.thickness_m!r} m, thinner than a voxel "
                        f"(tile.voxel_m = {self.tile.voxel_m!r} m): a layer must span at "
                        f"least one voxel")
        relief = self.imaging.interface_relief_m
        if relief is not None:
            widths = {len(row) for row in relief}
            if not relief or len(widths) != 1 or min(widths) < 1:
                return ("imaging.interface_relief_m", f"expected rows of equal length (one "
                        f"row per node along the track), got lengths {sorted(widths)}")
        if self.imaging.sediment_layers and self.imaging.delays != "table":
            return ("imaging.sediment_layers", "layers need imaging.delays = 'table' (got "
                    f"{self.imaging.delays!r})")
        sb = self.seabed
        if sb is not None:
            lo, hi = sb.speed_range_m_s
            if not (1000.0 <= lo < hi <= 3000.0):
                return ("seabed.speed_range_m_s", f"got {[lo, hi]}: expected two speeds "
                        "in [1000, 3000] m/s, the first below the second")
            if sb.min_points > sb.points:
                return ("seabed.min_points", f"got {sb.min_points}, more than seabed.points "
                        f"({sb.points})")
        return None


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


# ----------------------------------------------------------------------- the loader


def _expected(f: dataclasses.Field, tp: Any) -> str:
    m = f.metadata
    what = _type_name(tp)
    if m.get("choices"):
        what += f" one of {list(m['choices'])}"
    if m.get("lo") is not None or m.get("hi") is not None:
        what += f" in [{m.get('lo')}, {m.get('hi')}]"
    if m.get("length") is not None:
        what += f" of length {m['length']}"
    if m.get("min_length"):
        what += f" of at least {m['min_length']} entries"
    return f"{what} ({m.get('doc', '')})"


def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin in (types.UnionType, typing.Union):
        return " or ".join(_type_name(a) for a in typing.get_args(tp) if a is not type(None))
    if origin is tuple:
        args = typing.get_args(tp)
        return f"array of {_type_name(args[0])}"
    if dataclasses.is_dataclass(tp):
        return "table"
    return {float: "number", int: "integer", str: "string", bool: "boolean"}.get(tp, str(tp))


def _convert(value: Any, tp: Any, f: dataclasses.Field, key: str, file: str) -> Any:
    def fail(msg: str) -> ConfigError:
        return ConfigError(f"{file}: key '{key}': {msg}; expected {_expected(f, tp)}")

    origin = typing.get_origin(tp)
    if origin in (types.UnionType, typing.Union):
        inner = [a for a in typing.get_args(tp) if a is not type(None)][0]
        return None if value is None else _convert(value, inner, f, key, file)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise fail(f"got {type(value).__name__}")
        return _build(tp, value, key, file)
    if origin is tuple:
        if not isinstance(value, list):
            raise fail(f"got {type(value).__name__}")
        m = f.metadata
        if m.get("length") is not None and len(value) != m["length"]:
            raise fail(f"got {len(value)} entries")
        if m.get("min_length") and len(value) < m["min_length"]:
            raise fail(f"got {len(value)} entries")
        inner = typing.get_args(tp)[0]
        inner_field = f
        if typing.get_origin(inner) is tuple:  # nested arrays: check inner length by type
            n_inner = len(typing.get_args(inner)) if typing.get_args(inner)[-1] is not Ellipsis else None
            inner_field = dataclasses.field(metadata={**m, "length": n_inner, "min_length": None})
        return tuple(_convert(v, inner, inner_field, f"{key}[{i}]", file)
                     for i, v in enumerate(value))
    if tp is bool:
        if not isinstance(value, bool):
            raise fail(f"got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise fail(f"got {value!r}")
    elif tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise fail(f"got {value!r}")
        value = float(value)
        if value != value:
            raise fail("got NaN")
    elif tp is str:
        if not isinstance(value, str):
            raise fail(f"got {value!r}")
    m = f.metadata
    if m.get("choices") and value not in m["choices"]:
        raise fail(f"got {value!r}")
    if m.get("lo") is not None and value < m["lo"]:
        raise fail(f"got {value!r}, below the minimum")
    if m.get("hi") is not None and value > m["hi"]:
        raise fail(f"got {value!r}, above the maximum")
    return value


def _build(cls: type[T], data: dict, prefix: str, file: str) -> T:
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        where = f"table '{prefix}'" if prefix else "top level"
        raise ConfigError(f"{file}: unknown key '{_join(prefix, unknown[0])}' in {where}; "
                          f"expected one of {sorted(fields)}")
    kwargs = {}
    for name, f in fields.items():
        key = _join(prefix, name)
        tp = hints[name]
        if name not in data:
            optional = typing.get_origin(tp) in (types.UnionType, typing.Union)
            if optional:
                kwargs[name] = f.metadata.get("default")
                continue
            if typing.get_origin(tp) is tuple and f.metadata.get("min_length") == 0:
                kwargs[name] = ()
                continue
            raise ConfigError(f"{file}: missing key '{key}'; expected {_expected(f, tp)}")
        kwargs[name] = _convert(data[name], tp, f, key, file)
    obj = cls(**kwargs)
    check = getattr(obj, "config_problem", None)
    if check is not None:
        problem = check()
        if problem is not None:
            raise ConfigError(f"{file}: key '{_join(prefix, problem[0])}': {problem[1]}")
    return obj


def _join(prefix: str, name: str) -> str:
    return f"{prefix}.{name}" if prefix else name


#: the shipped file of each top-level schema (config/), whose values a "missing key"
#: error quotes: a file written before a key existed is told what to add
SHIPPED_FILES = {"ProcessingConfig": "processing.toml", "HardwareConfig": "hardware.toml",
                 "DaqConfig": "daq.toml", "DevicesConfig": "devices.toml",
                 "AcquireConfig": "acquire.toml"}


def _toml_text(v: Any) -> str:
    """``v`` written as TOML."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_text(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {_toml_text(x)}" for k, x in v.items()) + "}"
    return repr(v)


def _shipped_hint(cls: type, key: str, source: str) -> str:
    """What the shipped file of schema ``cls`` has for dotted ``key`` ('' when it has
    none, or is the file being read)."""
    name = SHIPPED_FILES.get(cls.__name__)
    if name is None or "[" in key:
        return ""
    shipped = config_path(name)
    try:
        if Path(source).resolve() == shipped.resolve():
            return ""
        node = read_toml(shipped)
    except (ConfigError, OSError):
        return ""
    *tables, leaf = key.split(".")
    for t in tables:
        node = node.get(t) if isinstance(node, dict) else None
    if not isinstance(node, dict) or leaf not in node:
        return ""
    where = f" under [{'.'.join(tables)}]" if tables else ""
    return (f"; a key newer than this file? the shipped {shipped} has "
            f"{leaf} = {_toml_text(node[leaf])}{where}: add it (docs/config.md)")


def from_dict(cls: type[T], data: dict, source: str = "<dict>") -> T:
    """Build and validate schema ``cls`` from a parsed TOML mapping. A missing key is
    an error naming it and, where the shipped file of the schema has it, what to add."""
    try:
        return _build(cls, data, "", source)
    except ConfigError as exc:
        m = re.search(r": missing key '([^']+)'", str(exc))
        if m is None:
            raise
        hint = _shipped_hint(cls, m.group(1), source)
        if not hint:
            raise
        raise ConfigError(str(exc) + hint) from None


def read_toml(path: str | os.PathLike) -> dict:
    """Parse a TOML file, raising :class:`ConfigError` naming the file on failure."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{path}: configuration file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None


def load(cls: type[T], path: str | os.PathLike) -> T:
    """Read the TOML file ``path`` and validate it against schema ``cls``."""
    return from_dict(cls, read_toml(path), str(path))


def loads(cls: type[T], text: str, source: str = "<string>") -> T:
    """Validate TOML ``text`` against schema ``cls``."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: not valid TOML: {exc}") from None
    return from_dict(cls, data, source)


def config_dir() -> Path:
    """The configuration folder: ``$SVSS_CONFIG_DIR`` or the project's ``config/``."""
    env = os.environ.get(CONFIG_ENV)
    path = Path(env) if env else Path(__file__).resolve().parents[1] / "config"
    if not path.is_dir():
        raise ConfigError(f"{path}: configuration folder not found "
                          f"(set {CONFIG_ENV} to the project's config/ folder)")
    return path


def config_path(name: str) -> Path:
    """Path of a file inside the configuration folder, e.g. ``'hardware.toml'``."""
    return config_dir() / name


def digest(text: str) -> str:
    """Short, stable identity of a configuration text (first 16 hex digits of SHA-256)."""
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class Loaded(typing.Generic[T]):
    """A validated configuration with the exact text it came from."""
    value: T
    text: str
    source: str

    @property
    def id(self) -> str:
        return digest(self.text)


def load_with_text(cls: type[T], path: str | os.PathLike) -> Loaded[T]:
    """Like :func:`load` but keep the file's text (for provenance and config ids)."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ConfigError(f"{path}: configuration file not found") from None
    return Loaded(loads(cls, text, str(path)), text, str(path))


def loaded_from_text(cls: type[T], text: str, source: str) -> Loaded[T]:
    """Validate a configuration text carried in a file or message."""
    return Loaded(loads(cls, text, source), text, source)


# -------------------------------------------------------------------------- security


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
