"""Sediment descriptions (APL-UW TR 9407 style) and their TOML loader.

A :class:`Sediment` holds absolute SI properties; the ratios the models use
(ρ = ρ_sed/ρ_w, ν = c_sed/c_w, κ = (1 + iδ)/ν) come from its methods given the water.
``config/sediments.toml`` documents the file format; :func:`load_sediments` reads it
with :mod:`tomllib` and rejects anything it does not understand with a message that
names the file, the sediment, the key and what was expected.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from svss_daq.config import ConfigError, config_path

from .attenuation import loss_parameter_from_attenuation, sediment_attenuation_db_per_m

__all__ = ["Sediment", "SedimentConfigError", "load_sediments", "parse_sediments",
           "cm4_to_si_spectral_strength", "DEFAULT_SEDIMENTS_FILE"]

log = logging.getLogger(__name__)

#: File name of the default table inside the configuration folder.
DEFAULT_SEDIMENTS_FILE = "sediments.toml"

#: Relative disagreement allowed between a quoted attenuation and the one δ implies
#: (the seed quotes 1.4 dB/m for a δ that gives 1.435 dB/m).
ATTENUATION_CONSISTENCY = 0.05


class SedimentConfigError(ConfigError):
    """A sediment table that cannot be used; the message says where and why."""


def cm4_to_si_spectral_strength(w2_cm4: float, spectral_exponent: float) -> float:
    """Convert w2 from the cm convention (W in cm⁴, K in rad/cm) to SI m^(4−γ).

    w2_SI = w2_cm4 × 10^(2γ − 8) (PHYSICS.md section 1).
    """
    return w2_cm4 * 10.0 ** (2.0 * spectral_exponent - 8.0)


@dataclass(frozen=True)
class Sediment:
    """A fluid sediment half-space (SI units).

    name; density kg/m³; sound_speed m/s; loss_parameter δ (k_sed = (ω/c_sed)(1 + iδ));
    spectral_strength w2 of W(K) = w2 K^−γ in m^(4−γ); spectral_exponent γ (2 < γ < 4);
    rms_roughness h (m, for Eckart's coherent reflection); volume scattering given either
    as sigma2 (σ2 = σ_v/α_dB) or as volume_strength_db (dB re 1 m⁻¹ at
    reference_frequency); quoted_attenuation_db_per_m: the attenuation quoted at
    reference_frequency (Hz), kept for provenance. description/source: free text.
    """

    name: str
    density: float
    sound_speed: float
    loss_parameter: float
    spectral_strength: float
    spectral_exponent: float
    rms_roughness: float = 0.0
    sigma2_value: float | None = None
    volume_strength_db: float | None = None
    reference_frequency: float | None = None
    quoted_attenuation_db_per_m: float | None = None
    description: str = ""
    source: str = ""

    def __post_init__(self) -> None:
        problems = _field_problems(self)
        if problems:
            raise ValueError(f"sediment {self.name!r}: " + "; ".join(problems))

    # ---------------------------------------------------------------- derived ratios
    def density_ratio(self, water_density: float) -> float:
        """ρ = ρ_sed/ρ_w (water_density kg/m³)."""
        return self.density / water_density

    def sound_speed_ratio(self, water_sound_speed: float) -> float:
        """ν = c_sed/c_w (water_sound_speed m/s)."""
        return self.sound_speed / water_sound_speed

    def kappa(self, water_sound_speed: float) -> complex:
        """κ = (1 + iδ)/ν, the complex sediment-to-water wavenumber ratio."""
        return (1.0 + 1j * self.loss_parameter) / self.sound_speed_ratio(water_sound_speed)

    def ratios(self, water_density: float, water_sound_speed: float) -> tuple[float, float, float]:
        """(ρ, ν, δ) for the given water."""
        return (self.density_ratio(water_density), self.sound_speed_ratio(water_sound_speed),
                self.loss_parameter)

    # ------------------------------------------------------------ derived quantities
    def attenuation_db_per_m(self, frequency):
        """Sediment attenuation α(f) in dB/m (frequency Hz), linear in f."""
        return sediment_attenuation_db_per_m(frequency, self.sound_speed, self.loss_parameter)

    def sigma2(self) -> float:
        """σ2 = σ_v/α_dB, given directly or from the volume strength at reference_frequency."""
        if self.sigma2_value is not None:
            return self.sigma2_value
        sv = 10.0 ** (self.volume_strength_db / 10.0)
        return float(sv / self.attenuation_db_per_m(self.reference_frequency))

    def volume_scattering_coefficient(self, frequency) -> float:
        """σ_v = σ2 α_dB(f) in m⁻¹ (grows with f as the attenuation does)."""
        return self.sigma2() * self.attenuation_db_per_m(frequency)

    def replace(self, **changes: Any) -> "Sediment":
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)


def _field_problems(s: Sediment) -> list[str]:
    out = []
    for key in _RANGES:
        v = getattr(s, _FIELD_OF_KEY[key])
        if v is None:
            continue
        if not (isinstance(v, (int, float)) and _in_range(key, v)):
            out.append(f"{_FIELD_OF_KEY[key]}={v!r} outside {_range_text(key)}")
    if (s.sigma2_value is None) == (s.volume_strength_db is None):
        out.append("give exactly one of sigma2_value and volume_strength_db")
    if s.volume_strength_db is not None and s.reference_frequency is None:
        out.append("volume_strength_db needs reference_frequency")
    if s.quoted_attenuation_db_per_m is not None and s.reference_frequency is None:
        out.append("quoted_attenuation_db_per_m needs reference_frequency")
    if s.volume_strength_db is not None and s.loss_parameter == 0:
        out.append("volume_strength_db needs loss_parameter > 0 (sigma2 = sigma_v/alpha)")
    return out


# ------------------------------------------------------------------------- TOML
# key in the file -> (field of Sediment, expected type description)
_FIELD_OF_KEY = {
    "density_kg_m3": "density",
    "sound_speed_m_s": "sound_speed",
    "loss_parameter": "loss_parameter",
    "spectral_strength_si": "spectral_strength",
    "spectral_exponent": "spectral_exponent",
    "rms_roughness_m": "rms_roughness",
    "sigma2": "sigma2_value",
    "volume_strength_db_m": "volume_strength_db",
    "reference_frequency_hz": "reference_frequency",
    "attenuation_db_m": "quoted_attenuation_db_per_m",
}
#: Accepted ranges (inclusive) of the numeric keys.
_RANGES = {
    "density_kg_m3": (500.0, 5000.0),
    "sound_speed_m_s": (300.0, 6000.0),
    "loss_parameter": (0.0, 1.0),
    "spectral_strength_si": (0.0, 1.0),
    "spectral_exponent": (2.0, 4.0),   # open interval, see _in_range
    "rms_roughness_m": (0.0, 1.0),
    "sigma2": (0.0, 1.0),
    "volume_strength_db_m": (-150.0, 20.0),
    "reference_frequency_hz": (1.0, 1e7),
    "attenuation_db_m": (0.0, 1e4),
}
_EXTRA_NUMERIC = {"spectral_strength_cm4": (0.0, 1e4)}
_OPEN = {"spectral_exponent"}  # TR 9407 needs 0 < alpha = gamma/2 - 1 < 1


def _in_range(key: str, value: float) -> bool:
    lo, hi = _RANGES.get(key) or _EXTRA_NUMERIC[key]
    if not math.isfinite(value):
        return False
    if key in _OPEN:
        return lo < value < hi
    return lo <= value <= hi


def _range_text(key: str) -> str:
    lo, hi = _RANGES.get(key) or _EXTRA_NUMERIC[key]
    return f"({lo:g}, {hi:g})" if key in _OPEN else f"[{lo:g}, {hi:g}]"
_TEXT_KEYS = {"description", "source"}
_REQUIRED = ("density_kg_m3", "sound_speed_m_s", "spectral_exponent")
_ALL_KEYS = set(_RANGES) | set(_EXTRA_NUMERIC) | _TEXT_KEYS


def load_sediments(path: str | Path | None = None) -> dict[str, Sediment]:
    """Read a sediment table (TOML, format in ``config/sediments.toml``) → {name: Sediment}.

    path defaults to ``sediments.toml`` in the configuration folder
    (:func:`svss_daq.config.config_path`). Raises SedimentConfigError naming the file,
    sediment, key and expectation for a missing or unknown key, a wrong type or an
    out-of-range value, or when the file is missing, unreadable or not TOML.
    """
    path = Path(path) if path is not None else config_path(DEFAULT_SEDIMENTS_FILE)
    try:
        with path.open("rb") as fh:
            data = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise SedimentConfigError(f"{path}: not valid TOML: {exc}") from exc
    except OSError as exc:
        raise SedimentConfigError(f"{path}: cannot read the sediment table: {exc}") from exc
    return parse_sediments(data, origin=str(path))


def parse_sediments(data: Mapping[str, Any],
                    origin: str = "<sediment table>") -> dict[str, Sediment]:
    """Validate an already-parsed sediment table (see :func:`load_sediments`)."""
    unknown_top = set(data) - {"meta", "sediments"}
    if unknown_top:
        raise SedimentConfigError(
            f"{origin}: unknown top-level key(s) {sorted(unknown_top)}; "
            f"expected only [meta] and [sediments.<name>] tables")
    meta = data.get("meta", {})
    if not isinstance(meta, Mapping):
        raise SedimentConfigError(f"{origin}: [meta]: expected a table, got {meta!r}")
    schema = meta.get("schema")
    if isinstance(schema, bool) or schema != 1:
        raise SedimentConfigError(f"{origin}: [meta] schema: expected the integer 1, "
                                  f"got {schema!r}")
    unknown_meta = set(meta) - {"schema", "description"}
    if unknown_meta:
        raise SedimentConfigError(f"{origin}: [meta]: unknown key(s) {sorted(unknown_meta)}; "
                                  f"expected 'schema' and optionally 'description'")
    table = data.get("sediments")
    if not isinstance(table, Mapping) or not table:
        raise SedimentConfigError(f"{origin}: expected at least one [sediments.<name>] table")
    out = {}
    for name, entry in table.items():
        out[name] = _parse_one(origin, name, entry)
        log.debug("sediment %s from %s: %s", name, origin, out[name])
    return out


def _parse_one(origin: str, name: str, entry: Any) -> Sediment:
    where = f"{origin}: sediment '{name}'"

    def fail(key: str, expected: str, got: Any) -> SedimentConfigError:
        return SedimentConfigError(f"{where}: key '{key}': expected {expected}, got {got!r}")

    if not name.isidentifier():
        raise SedimentConfigError(f"{where}: the name must be a plain identifier "
                                  f"(letters, digits, underscores)")
    if not isinstance(entry, Mapping):
        raise SedimentConfigError(f"{where}: expected a table, got {type(entry).__name__}")
    for key in entry:
        if key not in _ALL_KEYS:
            raise fail(key, f"one of {sorted(_ALL_KEYS)} (unknown key)", entry[key])
    values: dict[str, Any] = {}
    for key, value in entry.items():
        if key in _TEXT_KEYS:
            if not isinstance(value, str):
                raise fail(key, "a string", value)
            values[key] = value
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise fail(key, "a number", value)
        if not _in_range(key, value):
            raise fail(key, f"a number in {_range_text(key)}", value)
        values[key] = float(value)
    for key in _REQUIRED:
        if key not in values:
            raise fail(key, "a number (required key is missing)", None)

    gamma = values["spectral_exponent"]
    if ("spectral_strength_si" in values) == ("spectral_strength_cm4" in values):
        raise fail("spectral_strength_si", "exactly one of 'spectral_strength_si' (m^(4-gamma)) "
                   "and 'spectral_strength_cm4'", values.get("spectral_strength_si"))
    w2 = values.get("spectral_strength_si")
    if w2 is None:
        w2 = cm4_to_si_spectral_strength(values["spectral_strength_cm4"], gamma)

    fref = values.get("reference_frequency_hz")
    quoted = values.get("attenuation_db_m")
    if (quoted is not None or "volume_strength_db_m" in values) and fref is None:
        raise fail("reference_frequency_hz",
                   "a number: 'attenuation_db_m' and 'volume_strength_db_m' are quoted at it",
                   None)
    delta = values.get("loss_parameter")
    if delta is None:
        if quoted is None:
            raise fail("loss_parameter", "a number, or 'attenuation_db_m' with "
                       "'reference_frequency_hz' to derive it from", None)
        delta = float(loss_parameter_from_attenuation(quoted, fref, values["sound_speed_m_s"]))
    elif quoted is not None:
        implied = float(sediment_attenuation_db_per_m(fref, values["sound_speed_m_s"], delta))
        if abs(implied - quoted) > ATTENUATION_CONSISTENCY * max(quoted, implied):
            raise fail("attenuation_db_m",
                       f"within {ATTENUATION_CONSISTENCY:.0%} of {implied:.4g} dB/m, the value "
                       f"loss_parameter={delta:g} gives at {fref:g} Hz", quoted)
    if ("sigma2" in values) == ("volume_strength_db_m" in values):
        raise fail("sigma2", "exactly one of 'sigma2' and 'volume_strength_db_m'",
                   values.get("sigma2"))
    if "volume_strength_db_m" in values and delta == 0:
        raise fail("volume_strength_db_m", "a lossy sediment (sigma2 = sigma_v / attenuation "
                   "needs loss_parameter > 0); give 'sigma2' instead",
                   values["volume_strength_db_m"])
    return Sediment(
        name=name,
        density=values["density_kg_m3"],
        sound_speed=values["sound_speed_m_s"],
        loss_parameter=delta,
        spectral_strength=w2,
        spectral_exponent=gamma,
        rms_roughness=values.get("rms_roughness_m", 0.0),
        sigma2_value=values.get("sigma2"),
        volume_strength_db=values.get("volume_strength_db_m"),
        reference_frequency=fref,
        quoted_attenuation_db_per_m=quoted,
        description=values.get("description", ""),
        source=values.get("source", ""),
    )
