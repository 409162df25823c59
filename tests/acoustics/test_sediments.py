"""Sediment table: content of config/sediments.toml and the loader's error messages."""

import math

import pytest

from svss_daq.config import ConfigError, config_path
from sim_device.acoustics.sediments import (Sediment, SedimentConfigError,
                                            cm4_to_si_spectral_strength, load_sediments)

GOOD = """
[meta]
schema = 1

[sediments.mud]
density_kg_m3 = 1200.0
sound_speed_m_s = 1480.0
loss_parameter = 0.002
spectral_strength_si = 2.0e-5
spectral_exponent = 3.25
sigma2 = 0.001
rms_roughness_m = 0.005
"""


def _write(tmp_path, text):
    p = tmp_path / "sed.toml"
    p.write_text(text)
    return p


def _with(text, old, new):
    assert old in text
    return text.replace(old, new)


def test_default_table_holds_the_seed_sediments():
    table = load_sediments()
    assert {"medium_sand", "very_fine_silt", "clay"} <= set(table)
    sand = table["medium_sand"]
    # Seed Table 1 and TR 9407 row
    assert (sand.density, sand.sound_speed, sand.loss_parameter) == (1845.0, 1767.0, 0.01624)
    assert (sand.spectral_strength, sand.spectral_exponent) == (1.410e-4, 3.25)
    assert sand.rms_roughness == 0.01 and sand.volume_strength_db == -20.0
    assert sand.density_ratio(1000.0) == pytest.approx(1.845)
    assert sand.sound_speed_ratio(1500.0) == pytest.approx(1.1782, abs=5e-4)
    assert sand.kappa(1500.0) == pytest.approx((1 + 0.01624j) / (1767 / 1500))
    assert float(sand.attenuation_db_per_m(20e3)) == pytest.approx(10.0, rel=0.005)
    assert sand.sigma2() == pytest.approx(1e-3, rel=0.01)        # −20 dB/m ↔ σ2 ≈ 0.001
    assert sand.volume_scattering_coefficient(20e3) == pytest.approx(0.01, rel=1e-12)
    silt = table["very_fine_silt"]
    assert silt.sound_speed_ratio(1500.0) < 1 and silt.loss_parameter == 0.00194
    assert float(silt.attenuation_db_per_m(20e3)) == pytest.approx(1.4, rel=0.05)
    assert silt.sigma2() == pytest.approx(1e-3, rel=0.05)
    clay = table["clay"]
    assert clay.sigma2() == 0.001 and clay.density_ratio(1000.0) == pytest.approx(1.145)
    assert clay.sound_speed_ratio(1500.0) == pytest.approx(0.98)
    for s in table.values():
        assert s.source and s.description


def test_same_path_explicitly(tmp_path):
    assert load_sediments(config_path("sediments.toml")) == load_sediments()


def test_good_minimal_table(tmp_path):
    mud = load_sediments(_write(tmp_path, GOOD))["mud"]
    assert mud.sigma2() == 0.001 and mud.volume_strength_db is None
    assert mud.ratios(1000.0, 1500.0) == pytest.approx((1.2, 1480 / 1500, 0.002))


def test_cm4_convention_and_derived_delta(tmp_path):
    text = _with(GOOD, "spectral_strength_si = 2.0e-5", "spectral_strength_cm4 = 5.18e-4")
    text = _with(text, "loss_parameter = 0.002",
                 "reference_frequency_hz = 20000.0\nattenuation_db_m = 1.4")
    mud = load_sediments(_write(tmp_path, text))["mud"]
    assert mud.spectral_strength == pytest.approx(5.18e-4 * 10 ** (2 * 3.25 - 8))
    assert mud.spectral_strength == pytest.approx(1.638e-5, rel=1e-3)   # PHYSICS.md units trap
    assert float(mud.attenuation_db_per_m(20e3)) == pytest.approx(1.4, rel=1e-12)
    assert cm4_to_si_spectral_strength(1.0, 4.0) == 1.0


@pytest.mark.parametrize("old,new,key,expect", [
    ("rms_roughness_m = 0.005", "rms_roughness_m = 0.005\ncolour = 'grey'", "colour",
     "unknown key"),
    ("spectral_exponent = 3.25", "spectral_exponent = '3.25'", "spectral_exponent",
     "a number"),
    ("spectral_exponent = 3.25", "spectral_exponent = true", "spectral_exponent", "a number"),
    ("spectral_exponent = 3.25", "spectral_exponent = 4.0", "spectral_exponent",
     "a number in (2, 4)"),
    ("density_kg_m3 = 1200.0", "density_kg_m3 = 1.2", "density_kg_m3",
     "a number in [500, 5000]"),
    ("loss_parameter = 0.002", "loss_parameter = -0.002", "loss_parameter", "[0, 1]"),
    ("sound_speed_m_s = 1480.0\n", "", "sound_speed_m_s", "required key is missing"),
    ("sigma2 = 0.001",
     "sigma2 = 0.001\nvolume_strength_db_m = -25.0\nreference_frequency_hz = 2e4", "sigma2",
     "exactly one of 'sigma2' and 'volume_strength_db_m'"),
    ("sigma2 = 0.001", "volume_strength_db_m = -25.0", "reference_frequency_hz",
     "quoted at it"),
    ("loss_parameter = 0.002",
     "loss_parameter = 0.002\nreference_frequency_hz = 20000.0\nattenuation_db_m = 5.0",
     "attenuation_db_m", "within 5% of"),
    ("spectral_strength_si = 2.0e-5",
     "spectral_strength_si = 2.0e-5\nspectral_strength_cm4 = 5.0e-4",
     "spectral_strength_si", "exactly one of"),
    ("spectral_strength_si = 2.0e-5\n", "", "spectral_strength_si", "exactly one of"),
    ("loss_parameter = 0.002\n", "", "loss_parameter", "or 'attenuation_db_m'"),
])
def test_errors_name_file_sediment_key_and_expectation(tmp_path, old, new, key, expect):
    path = _write(tmp_path, _with(GOOD, old, new))
    with pytest.raises(SedimentConfigError) as err:
        load_sediments(path)
    msg = str(err.value)
    assert str(path) in msg and "sediment 'mud'" in msg and f"key '{key}'" in msg
    assert expect in msg
    assert isinstance(err.value, ConfigError) and isinstance(err.value, ValueError)


def test_file_level_errors(tmp_path):
    with pytest.raises(SedimentConfigError, match="not valid TOML"):
        load_sediments(_write(tmp_path, "[meta\nschema = 1"))
    with pytest.raises(SedimentConfigError, match="cannot read"):
        load_sediments(tmp_path / "missing.toml")
    with pytest.raises(SedimentConfigError, match=r"schema: expected the integer 1"):
        load_sediments(_write(tmp_path, _with(GOOD, "schema = 1", "schema = 2")))
    with pytest.raises(SedimentConfigError, match=r"unknown top-level key"):
        load_sediments(_write(tmp_path, GOOD + "\n[water]\ndensity = 1000.0\n"))
    with pytest.raises(SedimentConfigError, match=r"at least one \[sediments"):
        load_sediments(_write(tmp_path, "[meta]\nschema = 1\n"))
    with pytest.raises(SedimentConfigError, match="plain identifier"):
        load_sediments(_write(tmp_path, _with(GOOD, "[sediments.mud]", '[sediments."my mud"]')))


def test_dataclass_validates_and_is_frozen():
    s = Sediment("x", 1500.0, 1600.0, 0.01, 1e-4, 3.25, sigma2_value=0.001)
    with pytest.raises(AttributeError):
        s.density = 1.0
    with pytest.raises(ValueError, match="spectral_exponent"):
        Sediment("x", 1500.0, 1600.0, 0.01, 1e-4, 2.0, sigma2_value=0.001)
    with pytest.raises(ValueError, match="exactly one"):
        Sediment("x", 1500.0, 1600.0, 0.01, 1e-4, 3.25)
    t = s.replace(volume_strength_db=-20.0, sigma2_value=None, reference_frequency=20e3)
    alpha = 20 * 2 * math.pi * 20e3 * 0.01 / (1600.0 * math.log(10))
    assert t.sigma2() == pytest.approx(0.01 / alpha, rel=1e-12)
