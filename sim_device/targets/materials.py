"""Material and host-fluid properties for target scattering models.

The table lives in ``config/materials.toml`` (parsed with :mod:`tomllib`; the file
documents its keys); every entry names its source.  Keys carry their units as in the
other configuration tables (``density_kg_m3``, ``c_l_m_s``, ``c_t_m_s``,
``alpha_l_db_per_wavelength``, ``alpha_t_db_per_wavelength``; fluids ``density_kg_m3``,
``sound_speed_m_s``).

Loss convention (time dependence exp(-iωt), as in the form functions): a medium with
attenuation α_λ dB/λ has the complex speed c̃ = c / (1 + iδ) with δ = α_λ / (40π log10 e),
so that k = ω/c̃ has a positive imaginary part (waves decay as they travel).
A loss factor η = 1/Q (``loss_factor``: the imaginary part of a complex modulus
M(1 − iη), applied to both wave types) is the same to first order: δ = η/2, i.e.
α_λ = 20π log10(e) η dB per wavelength; the loader converts it so.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from svss_daq.config import ConfigError, config_path

__all__ = [
    "DEFAULT_MATERIALS_FILE",
    "ElasticMaterial",
    "Fluid",
    "MaterialTable",
    "MaterialsError",
    "db_per_wavelength_to_delta",
    "get_fluid",
    "get_material",
    "load_materials",
    "loss_factor_to_db_per_wavelength",
]

#: File name of the default table inside the configuration folder
#: (:func:`svss_daq.config.config_path`).
DEFAULT_MATERIALS_FILE = "materials.toml"

#: Largest shear/compressional speed ratio of an isotropic solid (Poisson ratio > -1).
_MAX_CT_OVER_CL = math.sqrt(3.0) / 2.0


class MaterialsError(ConfigError):
    """Invalid materials table or material entry; the message names file, entry and key."""


def db_per_wavelength_to_delta(alpha_db_per_wavelength: float) -> float:
    """Loss parameter δ (dimensionless) from attenuation in dB per wavelength."""
    return float(alpha_db_per_wavelength) / (40.0 * math.pi * math.log10(math.e))


def loss_factor_to_db_per_wavelength(eta: float) -> float:
    """Attenuation (dB per wavelength) of a loss factor η = 1/Q (δ = η/2)."""
    return 20.0 * math.pi * math.log10(math.e) * float(eta)


def _where(origin: str, kind: str, name: str) -> str:
    return f"{origin}: {kind} '{name}'"


def _check_number(value: Any, *, where: str, key: str, expected: str,
                  positive: bool = True, allow_zero: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise MaterialsError(f"{where}: key '{key}' must be {expected}, got {value!r}")
    v = float(value)
    ok = math.isfinite(v) and (v > 0.0 or (allow_zero and v == 0.0) or not positive)
    if not ok:
        raise MaterialsError(f"{where}: key '{key}' must be {expected}, got {value!r}")
    return v


@dataclass(frozen=True)
class Fluid:
    """Host fluid (water, or a fluid sediment): density (kg/m³) and sound speed (m/s)."""

    name: str
    density: float
    sound_speed: float
    source: str = ""

    def __post_init__(self) -> None:
        where = _where("<Fluid>", "fluid", self.name)
        _check_number(self.density, where=where, key="density",
                      expected="a positive finite number (kg/m^3)")
        _check_number(self.sound_speed, where=where, key="sound_speed",
                      expected="a positive finite number (m/s)")

    def wavenumber(self, freq):
        """Acoustic wavenumber k = 2πf/c (rad/m) for frequency ``freq`` (Hz)."""
        return 2.0 * math.pi * freq / self.sound_speed

    @property
    def impedance(self) -> float:
        """Characteristic impedance ρc (Pa·s/m)."""
        return self.density * self.sound_speed


@dataclass(frozen=True)
class ElasticMaterial:
    """Isotropic solid: density (kg/m³), compressional ``c_l`` and shear ``c_t`` speeds
    (m/s), optional attenuations ``alpha_l``/``alpha_t`` (dB per wavelength).

    ``c_t = 0`` denotes a fluid-like target (no shear).
    """

    name: str
    density: float
    c_l: float
    c_t: float
    alpha_l: float = 0.0
    alpha_t: float = 0.0
    source: str = ""

    def __post_init__(self) -> None:
        _validate_solid_fields(self.name, self.density, self.c_l, self.c_t,
                               self.alpha_l, self.alpha_t, origin="<ElasticMaterial>")

    @property
    def complex_c_l(self) -> complex:
        """Complex compressional speed c_l/(1 + iδ_l) (m/s)."""
        return self.c_l / (1.0 + 1j * db_per_wavelength_to_delta(self.alpha_l))

    @property
    def complex_c_t(self) -> complex:
        """Complex shear speed c_t/(1 + iδ_t) (m/s); 0 for a fluid-like target."""
        return self.c_t / (1.0 + 1j * db_per_wavelength_to_delta(self.alpha_t))

    @property
    def is_fluid(self) -> bool:
        """True for a target without shear rigidity (c_t = 0)."""
        return self.c_t == 0.0

    def lossless(self) -> "ElasticMaterial":
        """The same material without loss."""
        return ElasticMaterial(self.name, self.density, self.c_l, self.c_t, 0.0, 0.0,
                               self.source)

    def normal_incidence_reflection(self, fluid: Fluid) -> complex:
        """Plane-wave pressure reflection coefficient at normal incidence from ``fluid``
        onto a half-space of this material, R = (ρ₁c̃_l − ρc)/(ρ₁c̃_l + ρc).

        Exact for an elastic half-space at normal incidence (no mode conversion there).
        """
        z1 = self.density * self.complex_c_l
        z = fluid.density * fluid.sound_speed
        return complex((z1 - z) / (z1 + z))


def _validate_solid_fields(name, density, c_l, c_t, alpha_l, alpha_t, *, origin: str,
                           keys: Mapping[str, str] | None = None) -> None:
    """Check a solid's values; ``keys`` maps field names to the names used in messages
    (the TOML keys when loading a file)."""
    k = keys or {f: f for f in ("density", "c_l", "c_t", "alpha_l", "alpha_t")}
    where = _where(origin, "material", name)
    _check_number(density, where=where, key=k["density"],
                  expected="a positive finite number (kg/m^3)")
    _check_number(c_l, where=where, key=k["c_l"],
                  expected="a positive finite number (m/s)")
    _check_number(c_t, where=where, key=k["c_t"],
                  expected="a finite number >= 0 (m/s; 0 means a fluid-like target)",
                  allow_zero=True)
    if c_t >= _MAX_CT_OVER_CL * c_l:
        raise MaterialsError(
            f"{where}: key '{k['c_t']}' must be below sqrt(3)/2 * {k['c_l']} = "
            f"{_MAX_CT_OVER_CL * c_l:.1f} m/s (Poisson ratio > -1), got {c_t!r}")
    for f, value in (("alpha_l", alpha_l), ("alpha_t", alpha_t)):
        _check_number(value, where=where, key=k[f],
                      expected="a finite number >= 0 (dB per wavelength)", allow_zero=True)


#: TOML key of each ElasticMaterial / Fluid field.
_SOLID_KEYS = {"density": "density_kg_m3", "c_l": "c_l_m_s", "c_t": "c_t_m_s",
               "alpha_l": "alpha_l_db_per_wavelength",
               "alpha_t": "alpha_t_db_per_wavelength"}
_FLUID_KEYS = {"density": "density_kg_m3", "sound_speed": "sound_speed_m_s"}
_SOLID_REQUIRED = ("density_kg_m3", "c_l_m_s", "c_t_m_s", "source")
_SOLID_OPTIONAL = ("alpha_l_db_per_wavelength", "alpha_t_db_per_wavelength", "loss_factor",
                   "description")
_FLUID_REQUIRED = ("density_kg_m3", "sound_speed_m_s", "source")
_FLUID_OPTIONAL = ("description",)


@dataclass(frozen=True)
class MaterialTable:
    """Parsed materials table: ``solids`` and ``fluids`` keyed by name."""

    path: str
    solids: Mapping[str, ElasticMaterial]
    fluids: Mapping[str, Fluid]

    def material(self, name: str) -> ElasticMaterial:
        """Solid by name; raises :class:`MaterialsError` listing known names."""
        try:
            return self.solids[name]
        except KeyError:
            raise MaterialsError(
                f"{self.path}: no material '{name}'; known: {sorted(self.solids)}") from None

    def fluid(self, name: str) -> Fluid:
        """Fluid by name; raises :class:`MaterialsError` listing known names."""
        try:
            return self.fluids[name]
        except KeyError:
            raise MaterialsError(
                f"{self.path}: no fluid '{name}'; known: {sorted(self.fluids)}") from None


def _check_keys(entry: Any, *, where: str, required: tuple, optional: tuple) -> None:
    if not isinstance(entry, dict):
        raise MaterialsError(f"{where}: expected a table of keys {list(required)}, "
                             f"got {type(entry).__name__}")
    missing = [k for k in required if k not in entry]
    unknown = [k for k in entry if k not in required + optional]
    if missing or unknown:
        parts = ([f"missing key(s) {missing}"] if missing else []) + \
                ([f"unknown key(s) {unknown}"] if unknown else [])
        raise MaterialsError(f"{where}: {'; '.join(parts)}; required keys are "
                             f"{list(required)}, optional {list(optional)}")
    src = entry["source"]
    if not isinstance(src, str) or not src.strip():
        raise MaterialsError(f"{where}: key 'source' must be a non-empty string naming "
                             f"the reference, got {src!r}")


def parse_materials(data: Mapping[str, Any], origin: str = "<materials>") -> MaterialTable:
    """Build a :class:`MaterialTable` from parsed TOML ``data``; ``origin`` names the file
    in error messages."""
    unknown = [k for k in data if k not in ("materials", "fluids", "meta")]
    if unknown:
        raise MaterialsError(f"{origin}: unknown top-level table(s) {unknown}; expected "
                             "'materials', 'fluids' (and optionally 'meta')")
    solids: dict[str, ElasticMaterial] = {}
    for name, entry in dict(data.get("materials", {})).items():
        where = _where(origin, "material", name)
        _check_keys(entry, where=where, required=_SOLID_REQUIRED, optional=_SOLID_OPTIONAL)
        fields = {f: entry.get(key, 0.0) for f, key in _SOLID_KEYS.items()}
        if "loss_factor" in entry:
            if any(k in entry for k in ("alpha_l_db_per_wavelength",
                                        "alpha_t_db_per_wavelength")):
                raise MaterialsError(f"{where}: give either 'loss_factor' or the "
                                     "alpha_*_db_per_wavelength keys, not both")
            eta = _check_number(entry["loss_factor"], where=where, key="loss_factor",
                                expected="a finite number >= 0 (1/Q)", allow_zero=True)
            if eta > 0.5:
                raise MaterialsError(f"{where}: key 'loss_factor' must be <= 0.5 (a small "
                                     f"loss, 1/Q), got {eta!r}")
            fields["alpha_l"] = fields["alpha_t"] = loss_factor_to_db_per_wavelength(eta)
        _validate_solid_fields(name=name, origin=origin, keys=_SOLID_KEYS, **fields)
        m = ElasticMaterial(name=name, source=entry["source"],
                            **{k: float(v) for k, v in fields.items()})
        solids[name] = m
    fluids: dict[str, Fluid] = {}
    for name, entry in dict(data.get("fluids", {})).items():
        where = _where(origin, "fluid", name)
        _check_keys(entry, where=where, required=_FLUID_REQUIRED, optional=_FLUID_OPTIONAL)
        _check_number(entry["density_kg_m3"], where=where, key="density_kg_m3",
                      expected="a positive finite number (kg/m^3)")
        _check_number(entry["sound_speed_m_s"], where=where, key="sound_speed_m_s",
                      expected="a positive finite number (m/s)")
        fluids[name] = Fluid(name=name, density=float(entry["density_kg_m3"]),
                             sound_speed=float(entry["sound_speed_m_s"]),
                             source=entry["source"])
    if not solids:
        raise MaterialsError(f"{origin}: table [materials] is missing or empty")
    return MaterialTable(path=origin, solids=solids, fluids=fluids)


def load_materials(path: str | Path | None = None) -> MaterialTable:
    """Load and validate the materials table (default ``config/materials.toml``, found
    with :func:`svss_daq.config.config_path`)."""
    p = Path(path) if path is not None else config_path(DEFAULT_MATERIALS_FILE)
    try:
        with open(p, "rb") as fh:
            data = tomllib.load(fh)
    except FileNotFoundError:
        raise MaterialsError(f"{p}: materials file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise MaterialsError(f"{p}: not valid TOML ({exc})") from None
    return parse_materials(data, origin=str(p))


def get_material(name: str, path: str | Path | None = None) -> ElasticMaterial:
    """Solid material ``name`` from the table at ``path`` (default table)."""
    return load_materials(path).material(name)


def get_fluid(name: str, path: str | Path | None = None) -> Fluid:
    """Host fluid ``name`` from the table at ``path`` (default table)."""
    return load_materials(path).fluid(name)
