"""Materials table: content, loss convention and validation errors."""

import math

import numpy as np
import pytest

from sim_device.targets.materials import (DEFAULT_MATERIALS_FILE, ElasticMaterial, Fluid,
                                          MaterialsError, db_per_wavelength_to_delta,
                                          get_material, load_materials)
from svss_daq.config import ConfigError

GOOD_SOLID = """
[materials.rock]
density_kg_m3 = 2650.0
c_l_m_s = 4960.0
c_t_m_s = 2480.0
source = "test"
"""


def _write(tmp_path, text):
    p = tmp_path / "materials.toml"
    p.write_text(text)
    return p


def test_default_table_has_required_materials_with_sources():
    table = load_materials()
    for name in ("steel", "aluminium", "tungsten_carbide", "granite", "basalt", "cast_iron"):
        m = table.material(name)
        assert m.source.strip()
        assert 0 < m.c_t < m.c_l
    wc = table.material("tungsten_carbide")
    assert (wc.density, wc.c_l, wc.c_t) == (14900.0, 6853.0, 4171.0)   # PHYSICS.md §6
    sw = table.fluid("seawater_calibration")
    assert (sw.density, sw.sound_speed) == (1026.0, 1490.0)
    assert table.fluid("water_nominal").sound_speed == 1500.0


def test_loss_convention_gives_stated_attenuation_per_wavelength():
    basalt = get_material("basalt")
    assert basalt.alpha_l == pytest.approx(0.1)
    f = 30e3
    k = 2 * math.pi * f / basalt.complex_c_l
    lam = basalt.c_l / f
    # amplitude decay over one wavelength, in dB
    loss_db = 20 * math.log10(math.e) * k.imag * lam
    assert loss_db == pytest.approx(0.1, rel=1e-2)   # δ ≪ 1 so 1/(1+iδ) ≈ 1 − iδ
    assert k.imag > 0                                 # decays along exp(-iωt) propagation
    assert db_per_wavelength_to_delta(54.575) == pytest.approx(1.0, rel=1e-4)


def test_normal_incidence_reflection():
    water = Fluid("w", 1000.0, 1500.0)
    granite = get_material("granite").lossless()
    z1 = 2650.0 * 4960.0
    assert granite.normal_incidence_reflection(water) == pytest.approx(
        (z1 - 1.5e6) / (z1 + 1.5e6))
    same = ElasticMaterial("w_like", 1000.0, 1500.0, 0.0)
    assert abs(same.normal_incidence_reflection(water)) < 1e-15


@pytest.mark.parametrize("text, key, words", [
    ('[materials.rock]\ndensity_kg_m3 = 2650.0\nc_l_m_s = 4960.0\nsource = "x"\n',
     "c_t_m_s", "missing"),
    (GOOD_SOLID.replace("2650.0", "-1.0"), "density_kg_m3", "positive"),
    (GOOD_SOLID.replace("2480.0", "4500.0"), "c_t_m_s", "sqrt(3)/2"),
    (GOOD_SOLID.replace("4960.0", '"fast"'), "c_l_m_s", "positive finite number"),
    (GOOD_SOLID.replace('source = "test"', 'source = ""'), "source", "non-empty"),
    (GOOD_SOLID + "colour = 3\n", "colour", "unknown"),
    (GOOD_SOLID + "alpha_l_db_per_wavelength = -0.5\n", "alpha_l_db_per_wavelength",
     "dB per wavelength"),
    (GOOD_SOLID.replace("density_kg_m3", "density"), "density", "unknown"),
])
def test_validation_errors_name_file_material_key(tmp_path, text, key, words):
    p = _write(tmp_path, text)
    with pytest.raises(MaterialsError) as exc:
        load_materials(p)
    msg = str(exc.value)
    assert str(p) in msg
    assert "'rock'" in msg
    assert key in msg
    assert words in msg


def test_file_level_errors(tmp_path):
    with pytest.raises(MaterialsError, match="not found"):
        load_materials(tmp_path / "missing.toml")
    with pytest.raises(MaterialsError, match="not valid TOML"):
        load_materials(_write(tmp_path, "[materials.rock\n"))
    with pytest.raises(MaterialsError, match="unknown top-level"):
        load_materials(_write(tmp_path, GOOD_SOLID + "[rocks]\nx = 1\n"))
    with pytest.raises(MaterialsError, match="no material 'unobtainium'"):
        load_materials(_write(tmp_path, GOOD_SOLID)).material("unobtainium")
    bad_fluid = (GOOD_SOLID + '[fluids.mud]\ndensity_kg_m3 = 0\nsound_speed_m_s = 1500.0\n'
                 'source = "x"\n')
    with pytest.raises(MaterialsError, match=r"fluid 'mud': key 'density_kg_m3'"):
        load_materials(_write(tmp_path, bad_fluid))


def test_programmatic_construction_is_validated():
    with pytest.raises(MaterialsError, match="c_l"):
        ElasticMaterial("bad", 1000.0, float("nan"), 0.0)
    with pytest.raises(MaterialsError, match="sound_speed"):
        Fluid("bad", 1000.0, 0.0)
    assert DEFAULT_MATERIALS_FILE == "materials.toml"
    assert issubclass(MaterialsError, ConfigError)
    assert np.isfinite(get_material("steel").complex_c_t)


def test_loss_factor_key(tmp_path):
    """loss_factor = eta = 1/Q gives delta = eta/2 on both wave types (complex modulus
    M(1 - i eta): c~ = c sqrt(1 - i eta) = c/(1 + i eta/2) to first order), i.e. a
    resonance of width f/Q, and cannot be combined with the alpha keys."""
    text = GOOD_SOLID.replace('source = ', 'loss_factor = 1.0e-3\nsource = ', 1)
    m = load_materials(_write(tmp_path, text)).material("rock")
    eta = 1e-3
    exact = m.c_l * np.sqrt(1 - 1j * eta)
    assert m.complex_c_l == pytest.approx(exact, rel=1e-6)
    assert m.complex_c_t == pytest.approx(m.c_t * np.sqrt(1 - 1j * eta), rel=1e-6)
    # Q from the attenuation per wavelength: 1/Q = alpha lambda / pi (alpha in Np/m)
    alpha_np_per_wavelength = m.alpha_l / (20 * np.log10(np.e))
    assert np.pi / alpha_np_per_wavelength == pytest.approx(1 / eta)
    both = text.replace("loss_factor", "alpha_l_db_per_wavelength = 0.1\nloss_factor")
    with pytest.raises(MaterialsError, match="not both"):
        load_materials(_write(tmp_path, both))
    with pytest.raises(MaterialsError, match="loss_factor"):
        load_materials(_write(tmp_path, text.replace("1.0e-3", "-1.0")))
    # the shipped metals are lossy, tungsten carbide (no sourced value) is not
    table = load_materials()
    assert table.material("aluminium").alpha_l > 0
    assert table.material("tungsten_carbide").alpha_l == 0
    assert table.material("aluminium").lossless().alpha_t == 0
