"""Scene files: the seed's two scenes as the paper describes them, the environment they
resolve to, and errors that name the file and the key."""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import pytest

from sim_device.acoustics import coppens_sound_speed, load_sediments
from sim_device.environment import build_environment, water_sound_speed
from sim_device.scene import load_scene
from svss_daq.config import ConfigError, HardwareConfig, config_dir, config_path, load

SCENES = config_dir() / "scenes"


@pytest.mark.parametrize("name, sediment", [("seed_cylinder_sand", "medium_sand"),
                                            ("seed_cylinder_silt", "very_fine_silt")])
def test_seed_scenes(name, sediment):
    sc = load_scene(SCENES / f"{name}.toml")
    hw = load(HardwareConfig, config_path("hardware.toml"))
    # PHYSICS.md section 8: sensor 2 m above the interface, water 2.5 m, 1 cm roughness
    array_height = sc.track.altitude_m - hw.lever_arms.array_m[2]
    assert array_height == pytest.approx(2.0)
    assert sc.medium.depth_m == pytest.approx(2.5)
    env = build_environment(sc)
    assert [ly.sediment.name for ly in env.layers] == [sediment]
    assert env.layers[0].sediment.rms_roughness == pytest.approx(0.01)
    assert env.water_depth == 2.5 and env.surface_reflection == -1.0
    assert sc.noise.sea_state == 3.0
    # the cylinder, 1 m under the track, for the target model
    (cyl,) = sc.targets
    assert (cyl.kind, cyl.material) == ("cylinder", "aluminium")
    assert cyl.length_m == pytest.approx(0.61) and 2 * cyl.radius_m == pytest.approx(0.315)
    assert cyl.depth_m == pytest.approx(1.0) and cyl.cross_m == 0.0


def test_demo_scene_is_a_homogeneous_medium():
    sc = load_scene(SCENES / "demo.toml")
    env = build_environment(sc)
    assert not env.has_seabed and not env.has_surface and sc.points
    assert env.media(27500.0).n == 1


def test_layer_overrides_and_sound_speed_from_temperature():
    sc = load_scene(SCENES / "seed_cylinder_sand.toml")
    layer = dataclasses.replace(sc.seabed.layers[0], density_kg_m3=1900.0,
                                volume_strength_db_m=-25.0, rms_roughness_m=0.005)
    sc2 = dataclasses.replace(sc, seabed=dataclasses.replace(sc.seabed, layers=(layer,)))
    sed = build_environment(sc2).layers[0].sediment
    base = load_sediments()["medium_sand"]
    assert sed.density == 1900.0 and sed.rms_roughness == 0.005
    assert sed.sound_speed == base.sound_speed
    assert 10 * math.log10(sed.volume_scattering_coefficient(20000.0)) == \
        pytest.approx(-25.0, abs=1e-9)
    # the attenuation may be given instead of the loss parameter
    att = dataclasses.replace(sc.seabed.layers[0], attenuation_db_m=12.0)
    sed = build_environment(dataclasses.replace(
        sc, seabed=dataclasses.replace(sc.seabed, layers=(att,)))).layers[0].sediment
    assert sed.attenuation_db_per_m(20000.0) == pytest.approx(12.0, rel=1e-12)
    med = dataclasses.replace(sc.medium, sound_speed_m_s=None, temperature_c=12.0,
                              salinity_ppt=0.0, absorption="francois_garrison")
    sc3 = dataclasses.replace(sc, medium=med)
    assert water_sound_speed(sc3) == pytest.approx(
        float(coppens_sound_speed(12.0, 0.0, 1.25)), rel=1e-12)
    env = build_environment(sc3)
    assert 0 < env.water_absorption_np_per_m(27500.0) < 1e-3


def _edited(tmp_path: Path, old: str, new: str, name="seed_cylinder_sand.toml") -> Path:
    text = (SCENES / name).read_text()
    assert re.search(old, text, flags=re.M), old
    out = tmp_path / name
    out.write_text(re.sub(old, new, text, count=1, flags=re.M))
    return out


@pytest.mark.parametrize("old, new, key", [
    (r"^sound_speed_m_s = 1500.0", "", "medium.sound_speed_m_s"),
    (r"^depth_m = 2.5", "depth_m = 3.0", "medium.depth_m"),
    (r"^depth_m = 2.5", "", "medium.depth_m"),
    (r'^sediment = "medium_sand".*$', 'sediment = "medium_sand"\nthickness_m = 1.0',
     "seabed.layers[0].thickness_m"),
    (r'^sediment = "medium_sand".*$',
     'sediment = "medium_sand"\nloss_parameter = 0.02\nattenuation_db_m = 9.0',
     "seabed.layers[0].attenuation_db_m"),
    (r"^\[scattering\]", "[scatteringx]", "scatteringx"),
    (r'^interface_model = "apl_uw"', 'interface_model = "constant"',
     "scattering.interface_strength_db"),
    (r"^sea_state = 3.0.*$", "sea_state = 5.0", "noise.sea_state"),
    (r"^ambient_band_hz = .*$", "", "noise.ambient_band_hz"),
    (r"^length_m = 0.61", "", "targets[0].length_m"),
    (r"^multipath_order = 2.*$", "multipath_order = 2.5", "surface.multipath_order"),
    (r'^kind = "flat".*$', 'kind = "wavy"', "surface.kind"),
    (r"^precision = .*$", 'precision = "float16"', "scattering.precision"),
])
def test_bad_scenes_are_named(tmp_path, old, new, key):
    path = _edited(tmp_path, old, new)
    with pytest.raises(ConfigError) as err:
        load_scene(path)
    msg = str(err.value)
    assert str(path) in msg and key in msg, msg


def test_two_layer_seabed_needs_thickness_above(tmp_path):
    path = _edited(tmp_path, r'^sediment = "medium_sand".*$',
                   'sediment = "very_fine_silt"\n\n[[seabed.layers]]\nsediment = "medium_sand"')
    with pytest.raises(ConfigError, match=r"seabed.layers\[0\].thickness_m"):
        load_scene(path)
    ok = _edited(tmp_path, r'^sediment = "medium_sand".*$',
                 'sediment = "very_fine_silt"\nthickness_m = 1.0\n\n[[seabed.layers]]\n'
                 'sediment = "clay"')
    env = build_environment(load_scene(ok))
    assert [(ly.top_m, ly.bottom_m) for ly in env.layers] == [(0.0, 1.0), (1.0, float("inf"))]
    assert env.medium_at(0.5) == 1 and env.medium_at(1.5) == 2 and env.medium_at(-0.1) == 0


def test_unknown_sediment_is_named(tmp_path):
    path = _edited(tmp_path, r'^sediment = "medium_sand".*$', 'sediment = "basalt"')
    with pytest.raises(ValueError, match=r"seabed.layers\[0\].sediment.*basalt"):
        build_environment(load_scene(path))
