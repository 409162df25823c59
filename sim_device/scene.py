"""Scene files: the environment, the platform track and the targets a simulation shows.

The schema is declared here with :func:`svss_daq.config.spec`; the values live in
``config/scenes/*.toml`` (format and meaning: ``docs/simulator.md``). Optional tables
switch features on: without ``[seabed]`` the medium below the nominal interface is the
water itself (the demo's homogeneous medium); without ``[surface]`` there is no
multipath; without ``sea_state`` no ambient noise. :func:`load_scene` adds the checks
that involve several keys (e.g. the water depth against the track), naming file and key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from svss_daq.config import ConfigError, load, spec


@dataclass(frozen=True)
class SceneInfo:
    name: str = spec("scene name")
    description: str = spec("what the scene shows")
    seed: int = spec("random seed", lo=0, hi=2**63 - 1)


@dataclass(frozen=True)
class MediumConfig:
    """The water (and, without a [seabed], everything below the nominal interface)."""
    density_kg_m3: float = spec("density, kg/m^3", lo=500, hi=5000)
    sound_speed_m_s: float | None = spec(
        "sound speed, m/s (or give temperature_c and salinity_ppt)", lo=1000, hi=2500)
    temperature_c: float | None = spec("water temperature, deg C (Coppens sound speed, "
                                       "Francois-Garrison absorption)", lo=-2, hi=35)
    salinity_ppt: float | None = spec("salinity, ppt", lo=0, hi=45)
    depth_m: float | None = spec("water depth, surface to the water-sediment interface, m "
                                 "(must equal track.body_down_m + track.altitude_m)",
                                 lo=0.1, hi=1000)
    absorption: str | None = spec("water absorption model (absent: none)",
                                  choices=("none", "francois_garrison", "fixed"))
    absorption_db_m: float | None = spec("water absorption when absorption = 'fixed', dB/m",
                                         lo=0, hi=10)
    ph: float | None = spec("pH for Francois-Garrison (absent: 8)", lo=6, hi=9)


@dataclass(frozen=True)
class MotionConfig:
    """Sinusoidal platform motion about the nominal track (phases drawn from the seed)."""
    heave_m: float = spec("heave amplitude (down positive), m", lo=0, hi=5)
    heave_period_s: float = spec("heave period, s", lo=0.1, hi=1000)
    sway_m: float = spec("sway amplitude (starboard), m", lo=0, hi=5)
    sway_period_s: float = spec("sway period, s", lo=0.1, hi=1000)
    roll_deg: float = spec("roll amplitude, deg", lo=0, hi=30)
    roll_period_s: float = spec("roll period, s", lo=0.1, hi=1000)
    pitch_deg: float = spec("pitch amplitude, deg", lo=0, hi=30)
    pitch_period_s: float = spec("pitch period, s", lo=0.1, hi=1000)
    yaw_deg: float = spec("yaw amplitude about the track heading, deg", lo=0, hi=30)
    yaw_period_s: float = spec("yaw period, s", lo=0.1, hi=1000)


@dataclass(frozen=True)
class TrackConfig:
    start_time_utc: str = spec("time of the first ping, ISO 8601 UTC")
    start_ne_m: tuple[float, float] = spec("first ping's body origin (north, east), m", length=2)
    heading_deg: float = spec("track heading, deg from north", lo=-360, hi=360)
    speed_m_s: float = spec("platform speed over ground, m/s", lo=0.0, hi=20)
    altitude_m: float = spec("body origin height above the water-sediment interface, m",
                             lo=0.1, hi=100)
    body_down_m: float = spec("body origin depth below the sea surface, m", lo=-10, hi=100)
    n_pings: int = spec("number of pings", lo=1, hi=10**7)
    motion: MotionConfig | None = spec("platform motion (absent: a straight, level track)")


@dataclass(frozen=True)
class PointTarget:
    along_m: float = spec("along-track position from the first ping, m", lo=-1e4, hi=1e4)
    cross_m: float = spec("cross-track position, starboard positive, m", lo=-1e3, hi=1e3)
    depth_m: float = spec("depth below the water-sediment interface, m", lo=-100, hi=100)
    target_strength_db: float = spec("target strength, dB re 1 m^2", lo=-120, hi=40)


@dataclass(frozen=True)
class NoiseConfig:
    electronic_rms_counts: float = spec("white electronic noise per channel, ADC counts rms",
                                        lo=0.0, hi=1e7)
    sea_state: float | None = spec("Knudsen ambient noise sea state (absent: no ambient "
                                   "noise)", lo=0, hi=4)
    ambient_band_hz: tuple[float, float] | None = spec(
        "band of the receivers' ambient noise (low, high), Hz", length=2)


@dataclass(frozen=True)
class SedimentLayer:
    """One layer of the seabed: a sediment of config/sediments.toml, with overrides."""
    sediment: str = spec("sediment name in config/sediments.toml")
    thickness_m: float | None = spec("layer thickness, m (absent on the last layer: a "
                                     "half-space)", lo=1e-3, hi=1e3)
    density_kg_m3: float | None = spec("override: density, kg/m^3", lo=500, hi=5000)
    sound_speed_m_s: float | None = spec("override: sound speed, m/s", lo=100, hi=6000)
    loss_parameter: float | None = spec("override: loss parameter delta", lo=0, hi=1)
    spectral_strength_si: float | None = spec("override: roughness w2, m^(4-gamma)",
                                              lo=0, hi=1)
    spectral_exponent: float | None = spec("override: roughness gamma", lo=2.0001, hi=3.9999)
    volume_strength_db_m: float | None = spec(
        "override: volume scattering strength at the sediment's reference frequency, "
        "dB re 1/m", lo=-100, hi=0)
    rms_roughness_m: float | None = spec("override: rms roughness of the layer's top "
                                         "boundary (Eckart), m", lo=0, hi=1)
    attenuation_db_m: float | None = spec(
        "override: attenuation at the sediment's reference frequency, dB/m (sets the loss "
        "parameter; not with loss_parameter)", lo=0, hi=1e4)


@dataclass(frozen=True)
class UndulationTerm:
    """One sinusoid of an undulating interface (sim_device.bed_undulation)."""
    amplitude_m: float = spec("amplitude about the interface's plane, m (positive: "
                              "deeper at phase 0)", lo=-1, hi=1)
    wavelength_m: float = spec("wavelength, m", lo=0.5, hi=1000)
    direction_deg: float = spec("direction of the wave vector (normal to the crests) from "
                                "the along-track axis towards starboard, deg",
                                lo=-360, hi=360)
    phase_deg: float = spec("phase at the tile frame's origin, deg", lo=-360, hi=360)


@dataclass(frozen=True)
class SeabedConfig:
    layers: tuple[SedimentLayer, ...] = spec("sediment layers, top first", min_length=1)
    slope_deg: tuple[float, float] | None = spec(
        "the interface as a tilted plane through the level under the first ping: its "
        "slope along the track and across it, deg, positive where it deepens ahead and to "
        "starboard (layers parallel to it; sim_device.bed_plane); absent: level",
        lo=-30, hi=30, length=2)
    undulation: tuple[UndulationTerm, ...] = field(default=(), metadata=spec(
        "the interface undulating about its plane as a sum of sinusoids "
        "(sim_device.bed_undulation; over one sediment half-space); absent: a plane",
        min_length=0).metadata)


@dataclass(frozen=True)
class ScatteringConfig:
    """Point-based (PoSSM) scattering and its fidelity options."""
    interface: bool = spec("diffuse scattering from the water-sediment interface")
    volume: bool = spec("diffuse scattering from the sediment volume")
    specular: bool = spec("coherent (Eckart) returns of the interface and layer boundaries")
    interface_model: str = spec("interface backscatter model",
                                choices=("apl_uw", "constant"))
    interface_strength_db: float | None = spec(
        "interface scattering strength when interface_model = 'constant', dB re 1",
        lo=-100, hi=10)
    interface_density_per_m2: float = spec("interface scatterers per m^2", lo=1, hi=1e6)
    volume_density_per_m3: float = spec("volume scatterers per m^3", lo=1, hi=1e7)
    volume_max_depth_m: float = spec("volume scatterers no deeper than this below the "
                                     "interface, m", lo=0.0, hi=100)
    cell_m: float = spec("edge of the seeding cells (same seabed whatever the pings), m",
                         lo=0.01, hi=10)
    precision: str = spec("float64: double precision, refracted legs from the two-medium "
                          "table; exact: double precision, Brent's method for every "
                          "refracted leg; float32: single-precision scatterer and leg "
                          "storage", choices=("float64", "exact", "float32"))
    synthesis: str | None = spec("echo accumulation: fast (scatterer-parallel, float32 "
                                 "buffers) or reference (channel-parallel, the original "
                                 "kernel); absent: fast", choices=("fast", "reference"))
    scatterers_per_resolution_cell: float | None = spec(
        "scatterers per resolution cell of one ping at nadir (sim_device.fidelity); "
        "when given it sets both densities (interface_density_per_m2 and "
        "volume_density_per_m3 are then ignored)", lo=0.01, hi=1e4)
    volume_below_noise_db: float | None = spec(
        "each path's volume scatterers down to the depth where that path's nadir volume "
        "level is this far below the noise, dB (absent: down to volume_max_depth_m)",
        lo=-100, hi=200)
    device: str | None = spec("where the fast synthesis's pass 2 runs: cpu, or cuda (an "
                              "NVIDIA GPU through numba-cuda, sim_device.synthesis_gpu); "
                              "absent: cpu", choices=("cpu", "cuda"))


@dataclass(frozen=True)
class SurfaceConfig:
    kind: str = spec("sea surface: flat (image sources) or none (no multipath)",
                     choices=("flat", "none"))
    reflection_coefficient: float = spec("pressure reflection coefficient of the surface",
                                         lo=-1, hi=1)
    multipath_order: int = spec("boundary reflections a path may add to its direct form",
                                lo=0, hi=8)
    drop_below_noise_db: float = spec(
        "drop a multipath path whose expected level lies more than this far below the "
        "ambient + electronic noise, dB", lo=0, hi=200)


@dataclass(frozen=True)
class TransducerConfig:
    """Directivity of the simulated transducers inside the hardware's beam cones."""
    pattern: str = spec("shape inside the cone: flat (cone) or a piston that is -3 dB at "
                        "the cone edge", choices=("cone", "piston"))
    taper_deg: float = spec("raised-cosine taper across the cone edge, deg", lo=0, hi=30)
    back_lobe_db: float | None = spec("level of a back lobe (cone about -boresight) re the "
                                      "main lobe, dB (absent: none)", lo=-120, hi=0)


@dataclass(frozen=True)
class TargetConfig:
    """A target of the target-scattering model (:mod:`sim_device.targets`)."""
    kind: str = spec("target type (shell: a hollow sphere, empty or filled)",
                     choices=("cylinder", "sphere", "disc", "shell"))
    material: str = spec("material name in config/materials.toml, or 'rigid' (rigid, "
                         "fixed)")
    along_m: float = spec("centre along-track from the first ping, m", lo=-1e4, hi=1e4)
    cross_m: float = spec("centre cross-track, starboard positive, m", lo=-1e3, hi=1e3)
    depth_m: float = spec("centre depth below the water-sediment interface (negative: "
                          "above it, proud), m", lo=-100, hi=100)
    radius_m: float = spec("radius, m", lo=1e-4, hi=100)
    length_m: float | None = spec("cylinder length, m", lo=1e-4, hi=100)
    axis_heading_deg: float | None = spec("cylinder axis (disc: normal tilt direction) "
                                          "azimuth from along-track, deg", lo=-360, hi=360)
    axis_tilt_deg: float | None = spec("cylinder axis tilt from horizontal, positive end "
                                       "down (disc: normal tilt from vertical), deg",
                                       lo=-90, hi=90)
    description: str | None = spec("what the target is")
    thickness_m: float | None = field(default=None, metadata=spec(
        "disc: thickness of the rock slab (an elastic plate; absent: a half-space face); "
        "shell: wall thickness, m", lo=1e-5, hi=100).metadata)
    fill: str | None = field(default=None, metadata=spec(
        "shell: its fill, a fluid in config/materials.toml or 'vacuum' (empty or "
        "air-filled; absent: vacuum)").metadata)


@dataclass(frozen=True)
class TargetModelConfig:
    """Fidelity of the target-scattering model (speed against accuracy)."""
    truncation_tol: float = spec("relative tolerance of the modal series' truncation",
                                 lo=1e-16, hi=1e-1)
    freq_step_hz: float = spec("cylinders: step of the form table over projected "
                               "frequency, Hz (0: sum the series at every frequency)",
                               lo=0, hi=5000)
    bistatic: str = spec("cylinders: monostatic model along the bisector at Kell's "
                         "frequency f cos(beta/2) or at f", choices=("kell", "bisector"))
    material_loss: bool | None = field(default=None, metadata=spec(
        "materials' loss factors on (absent: true) or off (lossless targets)").metadata)
    ring_max_s: float | None = field(default=None, metadata=spec(
        "longest target ringing synthesised without windowing, s: longer responses are "
        "cut (tapered) there so they cannot wrap into the window (absent: the receive "
        "window's length plus the pulse's, so nothing visible is cut)", lo=1e-4,
        hi=10).metadata)


@dataclass(frozen=True)
class SceneConfig:
    scene: SceneInfo = spec("identity")
    medium: MediumConfig = spec("water")
    track: TrackConfig = spec("platform track")
    noise: NoiseConfig = spec("noise")
    points: tuple[PointTarget, ...] = spec("point scatterers", min_length=0)
    seabed: SeabedConfig | None = spec("sediment layers (absent: homogeneous medium)")
    scattering: ScatteringConfig | None = spec("PoSSM scattering (needed with a seabed)")
    surface: SurfaceConfig | None = spec("sea surface and multipath (absent: none)")
    transducers: TransducerConfig | None = spec("directivity (absent: hard cones)")
    targets: tuple[TargetConfig, ...] = spec("targets (target-scattering model)",
                                             min_length=0)
    target_model: TargetModelConfig | None = spec("target-model fidelity (absent: "
                                                  "defaults)")


def check_scene(sc: SceneConfig, source: str = "<scene>") -> SceneConfig:
    """Checks that involve several keys; raise :class:`ConfigError` naming the key."""
    def fail(key: str, msg: str) -> ConfigError:
        return ConfigError(f"{source}: key '{key}': {msg}")

    m = sc.medium
    has_ts = m.temperature_c is not None or m.salinity_ppt is not None
    if m.sound_speed_m_s is None and not (m.temperature_c is not None
                                          and m.salinity_ppt is not None):
        raise fail("medium.sound_speed_m_s", "give the sound speed, or both temperature_c "
                   "and salinity_ppt")
    if m.sound_speed_m_s is not None and has_ts and m.absorption != "francois_garrison":
        raise fail("medium.temperature_c", "give either sound_speed_m_s or temperature_c "
                   "and salinity_ppt (temperature is only used with francois_garrison)")
    if m.absorption == "fixed" and m.absorption_db_m is None:
        raise fail("medium.absorption_db_m", "needed when absorption = 'fixed'")
    if m.absorption == "francois_garrison" and (m.temperature_c is None
                                                or m.salinity_ppt is None):
        raise fail("medium.temperature_c", "francois_garrison needs temperature_c and "
                   "salinity_ppt")
    depth_nominal = sc.track.body_down_m + sc.track.altitude_m
    if m.depth_m is not None and not math.isclose(m.depth_m, depth_nominal, abs_tol=1e-6):
        raise fail("medium.depth_m", f"{m.depth_m} m, but track.body_down_m + "
                   f"track.altitude_m = {depth_nominal} m")
    if sc.surface is not None and sc.surface.kind == "flat" and m.depth_m is None:
        raise fail("medium.depth_m", "a flat surface needs the water depth")
    if sc.seabed is not None:
        layers = sc.seabed.layers
        for k, layer in enumerate(layers):
            last = k == len(layers) - 1
            if layer.attenuation_db_m is not None and layer.loss_parameter is not None:
                raise fail(f"seabed.layers[{k}].attenuation_db_m", "give the attenuation "
                           "or the loss parameter, not both")
            if last and layer.thickness_m is not None:
                raise fail(f"seabed.layers[{k}].thickness_m", "the last layer is a "
                           "half-space: leave its thickness out")
            if not last and layer.thickness_m is None:
                raise fail(f"seabed.layers[{k}].thickness_m", "missing (only the last "
                           "layer is a half-space)")
        if sc.seabed.undulation:
            check_undulation(sc, fail)
        if sc.scattering is None:
            raise fail("scattering", "a scene with a seabed needs a [scattering] table")
    if sc.scattering is not None:
        s = sc.scattering
        if s.interface_model == "constant" and s.interface_strength_db is None:
            raise fail("scattering.interface_strength_db", "needed when interface_model "
                       "= 'constant'")
        if s.device == "cuda":
            if s.synthesis == "reference":
                raise fail("scattering.device", "'cuda' runs the fast synthesis: leave "
                           "scattering.synthesis out or set it to 'fast', not 'reference'")
            try:
                from .synthesis_gpu import cuda_available
                gpu = cuda_available()
            except ImportError:                  # no numba.cuda at all
                gpu = False
            if not gpu:
                raise fail("scattering.device", "'cuda' asked for, but no CUDA GPU is "
                           "available to numba (install the 'gpu' extra, numba-cuda, on a "
                           "machine with an NVIDIA GPU, or set it to 'cpu')")
    n = sc.noise
    if n.sea_state is not None:
        if n.ambient_band_hz is None:
            raise fail("noise.ambient_band_hz", "needed with a sea state")
        lo, hi = n.ambient_band_hz
        if not 0 < lo < hi:
            raise fail("noise.ambient_band_hz", f"expected 0 < low < high, got {[lo, hi]}")
    for k, t in enumerate(sc.targets):
        if t.kind == "cylinder" and t.length_m is None:
            raise fail(f"targets[{k}].length_m", "a cylinder needs its length")
        if t.kind != "cylinder" and t.length_m is not None:
            raise fail(f"targets[{k}].length_m", f"only cylinders have a length (this "
                       f"target is a {t.kind})")
        if t.kind == "shell" and t.thickness_m is None:
            raise fail(f"targets[{k}].thickness_m", "a shell needs its wall thickness")
        if t.kind == "shell" and t.thickness_m > t.radius_m:
            raise fail(f"targets[{k}].thickness_m", f"{t.thickness_m} m is more than the "
                       f"radius {t.radius_m} m")
        if t.kind not in ("disc", "shell") and t.thickness_m is not None:
            raise fail(f"targets[{k}].thickness_m", f"only discs (slabs) and shells have a "
                       f"thickness (this target is a {t.kind})")
        if t.kind != "shell" and t.fill is not None:
            raise fail(f"targets[{k}].fill", f"only shells have a fill (this target is a "
                       f"{t.kind})")
    return sc


#: the steepest undulating interface a scene may have (its gradient's bound, |grad u|):
#: Fermat's crossings start from the level solution, exact for a seabed-like surface
MAX_UNDULATION_SLOPE = 0.5


def check_undulation(sc: SceneConfig, fail) -> None:
    """An undulating interface: over one sediment half-space, gentle enough for the
    crossing solver, with surface multipath of at most one reflection (a leg's seabed
    bounce would need the curved surface's image, which is not modelled)."""
    from .bed_undulation import Undulation
    if len(sc.seabed.layers) != 1:
        raise fail("seabed.undulation", "an undulating interface needs a single sediment "
                   f"half-space below it ({len(sc.seabed.layers)} layers given)")
    und = Undulation.from_terms([(t.amplitude_m, t.wavelength_m, t.direction_deg,
                                  t.phase_deg) for t in sc.seabed.undulation])
    if und.slope_bound > MAX_UNDULATION_SLOPE:
        raise fail("seabed.undulation", f"the terms' slopes add up to {und.slope_bound:.2f} "
                   f"(sum of 2 pi amplitude / wavelength), more than {MAX_UNDULATION_SLOPE}")
    if sc.surface is not None and sc.surface.multipath_order > 1:
        raise fail("surface.multipath_order", "over an undulating interface at most 1 (a "
                   "leg reflected by the curved seabed is not modelled)")
    if sc.scattering is not None and sc.scattering.device == "cuda":
        raise fail("scattering.device", "an undulating interface is synthesised on the CPU "
                   "(set it to 'cpu')")
    if sc.track.altitude_m <= und.amplitude_bound:
        raise fail("seabed.undulation", f"the crests ({und.amplitude_bound:.2f} m) reach the "
                   f"platform ({sc.track.altitude_m} m above the plane)")


def load_scene(path: str | Path) -> SceneConfig:
    """Read and validate a scene file."""
    return check_scene(load(SceneConfig, path), str(path))
