"""The processing configuration's schema (``config/processing.toml``): tiles,
conditioning, imaging, the ping gate, limits, products, micronavigation, autofocus and
the seabed, in :class:`ProcessingConfig`. Declared with :func:`~svss_daq.config_loader.spec`
and loaded with :func:`~svss_daq.config_loader.load`; ``from svss_daq.config import
...`` gives every name here too.
"""

from __future__ import annotations

from dataclasses import dataclass

from .config_loader import spec


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
    method: str | None = spec(
        "imaging method of `svss process`, `svss batch` and a replay: 'exact' (one sum per "
        "voxel and channel) or 'factorised' (channels summed on a coarse lattice of "
        "columns, interpolated to the voxels: docs/imaging.md); omitted: exact",
        choices=("exact", "factorised"), default="exact")
    live_method: str | None = spec(
        "imaging method of the live worker (`svss worker`; with device = 'cuda' the exact "
        "method runs whatever this says); omitted: exact",
        choices=("exact", "factorised"), default="exact")
    factorised_step_m: tuple[float, float] | None = spec(
        "factorised method: spacing of the coarse columns along and across the track, m; "
        "omitted: [0.085, 0.07]", lo=0.005, hi=1.0, length=2, default=(0.085, 0.07))
    factorised_lobes: int | None = spec(
        "factorised method: lobes of the Lanczos interpolator (2 x lobes columns per "
        "axis); omitted: 3", lo=1, hi=8, default=3)
    gpu_pings_per_launch: int | None = spec(
        "on the GPU, pings of a tile imaged by one kernel launch (each voxel summed over "
        "them, then added once); omitted: 16", lo=1, hi=256, default=16)
    gpu_conditioning: str | None = spec(
        "on the GPU, where a ping's tap planes are made: 'device' (its ADC codes go up "
        "and the device conditions them) or 'host' (conditioned on the CPU, the planes "
        "uploaded); omitted: device", choices=("device", "host"), default="device")
    gpu_coverage: str | None = spec(
        "on the GPU, where a tile's coverage (pings and channels per voxel) is counted: "
        "'device' or 'host'; omitted: device", choices=("device", "host"),
        default="device")
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
class FeaturesConfig:
    enabled: bool = spec("measure each contact's features (its tail below it: extent, "
                         "decay, late-to-specular ratio; docs/contact_features.md)")
    footprint_min_m: tuple[float, float] = spec(
        "smallest footprint (along, cross) over which a contact's tail is averaged, m; "
        "its extent above the threshold where larger", length=2, lo=0.0, hi=10.0)
    footprint_max_m: tuple[float, float] = spec(
        "largest footprint (along, cross), m", length=2, lo=0.0, hi=10.0)
    peak_window_m: float = spec("the object's own (specular) window: apparent depth below "
                                "its peak, m", lo=0.0, hi=5.0)
    tail_window_m: float = spec("the tail window below the peak window (late energy), m",
                                lo=0.01, hi=10.0)
    background_within_db: float = spec(
        "the tail ends where its profile falls to within this of the local background, dB",
        lo=0.0, hi=60.0)
    below_run_m: float = spec("... and stays there over this apparent depth, m", lo=0.0,
                              hi=5.0)
    reference_boxes: int = spec("reference footprints beside the contact along-track, on "
                                "each side (the local background's mean and spread)",
                                lo=1, hi=100)
    reference_gap_m: float = spec("gap between the footprint and its references, m",
                                  lo=0.0, hi=10.0)
    min_fit_points: int = spec("fewest depth voxels for the decay's fit", lo=3, hi=10000)
    profile_m: float = spec("length of the tail profile kept per contact (tile file, PNG), m",
                            lo=0.0, hi=10.0)
    aspect_window_m: float = spec(
        "along-track window about a contact whose spectrum gives its look angles over "
        "the aperture (aspect_centre_deg, aspect_width_deg), m", lo=0.04, hi=20.0)
    point_aspect_deg: tuple[float, float] | None = spec(
        "a point scatterer's look-angle spreads (along, across) in this sonar's geometry, "
        "the references of aspect_point_fraction (measured on the training fields' spheres "
        "by benchmarks/fit_classifier.py), deg (omitted: the fraction not measured)",
        length=2, lo=0.01, hi=90.0, default=None)

    def config_problem(self) -> tuple[str, str] | None:
        for lo, hi in zip(self.footprint_min_m, self.footprint_max_m):
            if lo > hi:
                return ("footprint_min_m", f"{list(self.footprint_min_m)} exceeds "
                        f"footprint_max_m {list(self.footprint_max_m)}")
        return None


#: contact features a classifier may use (svss_proc.products.contact_features names)
CLASSIFY_FEATURES = ("tail_extent_m", "tail_decay_db_per_m", "late_to_specular_db",
                     "aspect_centre_deg", "aspect_width_deg", "aspect_cross_width_deg",
                     "aspect_point_fraction")
#: and those measured from the recorded pings at a run's end (contact_spectra), which
#: only the run-level model ([products.classify_pings]) may use
PING_FEATURES = ("late_over_background_db",)


@dataclass(frozen=True)
class ClassifyConfig:
    enabled: bool = spec("call each contact man-made, natural or undecided from its "
                         "features (docs/classification.md)")
    features: tuple[str, ...] = spec("the model's features, columns of the contacts",
                                     choices=CLASSIFY_FEATURES, min_length=1)
    mean: tuple[float, ...] = spec("each feature's mean over the training contacts "
                                   "(its standardisation), feature units",
                                   min_length=1, lo=-1e6, hi=1e6)
    scale: tuple[float, ...] = spec("each feature's standard deviation over them, feature "
                                    "units", min_length=1, lo=1e-9, hi=1e6)
    coefficients: tuple[float, ...] = spec(
        "logistic regression's weight of each standardised feature (log-odds of man-made "
        "per standard deviation)", min_length=1, lo=-1e3, hi=1e3)
    intercept: float = spec("log-odds of man-made at the training mean", lo=-1e3, hi=1e3)
    manmade_above: float = spec("p_manmade above this: man-made", lo=0.0, hi=1.0)
    natural_below: float = spec("p_manmade below this: natural (between the two: "
                                "undecided)", lo=0.0, hi=1.0)
    undecided_flags: tuple[int, ...] = spec(
        "feature_flags bits that leave a contact undecided (e.g. 32: aspect not measured)",
        lo=1, hi=1 << 30, min_length=0)

    def config_problem(self) -> tuple[str, str] | None:
        n = len(self.features)
        for key in ("mean", "scale", "coefficients"):
            if len(getattr(self, key)) != n:
                return (key, f"{len(getattr(self, key))} entries; expected one per feature "
                        f"({n}: {list(self.features)})")
        if len(set(self.features)) != n:
            return ("features", f"{list(self.features)} names a feature twice")
        if self.natural_below > self.manmade_above:
            return ("natural_below", f"{self.natural_below} exceeds manmade_above "
                    f"{self.manmade_above}")
        return None


@dataclass(frozen=True)
class PingClassifyConfig(ClassifyConfig):
    """The run-level model: the same keys, its features may include the pings' own
    (PING_FEATURES); it calls the contacts whose ping features were measured."""
    features: tuple[str, ...] = spec("the model's features, columns of the contacts (the "
                                     "image's and the pings')",
                                     choices=CLASSIFY_FEATURES + PING_FEATURES,
                                     min_length=1)

    def config_problem(self) -> tuple[str, str] | None:
        if not set(self.features) & set(PING_FEATURES):
            return ("features", f"{list(self.features)} names none of the pings' features "
                    f"{list(PING_FEATURES)}: this model would call no contact again")
        return super().config_problem()


@dataclass(frozen=True)
class SpectraConfig:
    start_s: float = spec("each ping's series starts this long after the contact's arrival "
                          "(past its specular echo), s", lo=0.0, hi=0.1)
    length_s: float = spec("and lasts this long (the ringing), s", lo=1e-4, hi=0.1)
    min_pings: int = spec("fewest pings whose projector cone held the contact", lo=1,
                          hi=100000)
    max_lines: int = spec("lines fitted (the strongest in the band is reported)", lo=1, hi=16)
    rel_threshold: float = spec("singular values kept, over the largest (the pencil's order)",
                                lo=1e-9, hi=1.0)
    reference_m: float = spec("the background's late response: the same series focused this "
                              "far along-track on either side of the contact, m", lo=0.05,
                              hi=20.0)
    min_over_background_db: float = spec(
        "a line is reported only where the contact's late response stands this far over "
        "the background's (the pencil finds lines in any band-limited series), dB",
        lo=-100.0, hi=100.0)


@dataclass(frozen=True)
class ProductsConfig:
    background: BackgroundConfig = spec("background estimation by a 3-D median")
    depth_gain: DepthGainConfig = spec("depth-varying gain")
    drc: DrcConfig = spec("dynamic range compression for display")
    detection: DetectionConfig = spec("contacts in the normalised volume")
    quicklook: QuicklookConfig = spec("PNG quicklooks")
    store_volumes: bool = spec("write the background and the compressed volume into the "
                               "tile file (each as large as the magnitude)")
    features: FeaturesConfig | None = spec(
        "each contact's features (docs/contact_features.md; omitted: none measured)",
        default=None)
    classify: ClassifyConfig | None = spec(
        "each contact called man-made, natural or undecided from its features "
        "(docs/classification.md; omitted: not classified)", default=None)
    spectra: SpectraConfig | None = spec(
        "each contact's strongest resonance line from the recorded pings, by svss process "
        "(docs/contact_features.md; omitted: not measured)", default=None)
    classify_pings: PingClassifyConfig | None = spec(
        "the run's contacts called again where the pings' features were measured (svss "
        "process; docs/classification.md; omitted: the image's call stands)",
        default=None)


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
        im = self.imaging
        if min(im.factorised_step_m) < self.tile.voxel_m:
            return ("imaging.factorised_step_m", f"got {list(im.factorised_step_m)} m, finer "
                    f"than a voxel (tile.voxel_m = {self.tile.voxel_m!r} m)")
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
