"""Bad sediment settings get an error naming the file and the key."""

from __future__ import annotations

from pathlib import Path

import pytest

from svss_daq.config import ConfigError, ProcessingConfig, config_path, load

SHIPPED = config_path("processing.toml").read_text()
LAYER = "\n[[imaging.sediment_layers]]\nthickness_m = {t}\nsound_speed_m_s = {c}\n"


def _load(tmp_path: Path, text: str):
    p = tmp_path / "processing.toml"
    p.write_text(text)
    return load(ProcessingConfig, p)


def _with_layer(t, c):
    # the layer table right after [imaging]'s keys (before the next table)
    head, tail = SHIPPED.split("\n[ping_gate]", 1)
    return head + LAYER.format(t=t, c=c) + "\n[ping_gate]" + tail


def test_a_configured_layer_loads(tmp_path):
    p = _load(tmp_path, _with_layer(0.5, 1476.0))
    assert [(x.thickness_m, x.sound_speed_m_s) for x in p.imaging.sediment_layers] == \
        [(0.5, 1476.0)]


@pytest.mark.parametrize("text, key, says", [
    (SHIPPED.replace("sediment_sound_speed_m_s = 1500.0", "sediment_sound_speed_m_s = -1767.0"),
     "imaging.sediment_sound_speed_m_s", "below the minimum"),
    (SHIPPED.replace("sediment_sound_speed_m_s = 1500.0", "sediment_sound_speed_m_s = 17670.0"),
     "imaging.sediment_sound_speed_m_s", "above the maximum"),
    (_with_layer(0.01, 1476.0), "imaging.sediment_layers[0].thickness_m", "thinner than a voxel"),
    (_with_layer(0.5, 150.0), "imaging.sediment_layers[0].sound_speed_m_s", "below the minimum"),
    (_with_layer(0.5, 1476.0).replace('delays = "table"', 'delays = "exact"'),
     "imaging.sediment_layers", "delays = 'table'"),
    (SHIPPED.replace("speed_range_m_s = [1400.0, 2100.0]", "speed_range_m_s = [2100.0, 1400.0]"),
     "seabed.speed_range_m_s", "the first below the second"),
    (SHIPPED.replace('speed = "estimate"', 'speed = "guess"'), "seabed.speed", "'guess'"),
    (SHIPPED.replace("\n[ping_gate]", "\ninterface_slope_deg = [3.0, 60.0]\n[ping_gate]", 1),
     "imaging.interface_slope_deg[1]", "above the maximum"),
    (SHIPPED.replace("\n[ping_gate]", "\ninterface_slope_deg = [3.0]\n[ping_gate]", 1),
     "imaging.interface_slope_deg", "got 1 entries"),
    (SHIPPED.replace('slope = "estimate"', 'slope = "tilted"'), "seabed.slope", "'tilted'"),
])
def test_bad_sediment_settings_name_the_key(tmp_path, text, key, says):
    with pytest.raises(ConfigError) as err:
        _load(tmp_path, text)
    msg = str(err.value)
    assert "processing.toml" in msg and f"'{key}'" in msg and says in msg, msg


def test_an_estimate_with_layers_images_through_the_table():
    """Only the refraction table refracts through layers: an estimated layered profile
    applied to a configuration with exact (per-voxel Fermat, half-space) delays makes it
    table delays, as the configuration's own check demands of configured layers."""
    from dataclasses import replace

    from svss_proc.seabed.speed import applied
    p = load(ProcessingConfig, config_path("processing.toml"))
    exact = replace(p, imaging=replace(p.imaging, delays="exact"))
    summary = {"status": "estimated", "sediment_sound_speed_m_s": 1767.0,
               "layers": [{"thickness_m": 0.5, "speed_m_s": 1476.0}]}
    got = applied(exact, summary)
    assert got.imaging.delays == "table" and got.config_problem() is None
    assert [(x.thickness_m, x.sound_speed_m_s) for x in got.imaging.sediment_layers] == \
        [(0.5, 1476.0)]
    assert got.imaging.sediment_sound_speed_m_s == 1767.0
    # a half-space estimate keeps exact delays
    half = applied(exact, {**summary, "layers": []})
    assert half.imaging.delays == "exact" and not half.imaging.sediment_layers


def test_a_configured_slope_loads_and_is_level_when_omitted(tmp_path):
    p = _load(tmp_path, SHIPPED.replace("\n[ping_gate]",
                                        "\ninterface_slope_deg = [3.0, -5.0]\n[ping_gate]", 1))
    assert p.imaging.interface_slope_deg == (3.0, -5.0)
    assert load(ProcessingConfig, config_path("processing.toml")).imaging.interface_slope_deg \
        == (0.0, 0.0)


def test_the_inspect_line_says_the_slope():
    from svss.summary import seabed_line
    line = seabed_line({"status": "estimated", "sediment_sound_speed_m_s": 1753.0,
                        "sigma_m_s": 34.3, "responses": [{}, {}],
                        "interface_slope_deg": [3.0, 4.81],
                        "interface_slope_sigma_deg": [0.004, 0.03]})
    assert line.startswith("1753 +/- 34 m/s estimated from 2 buried response(s)")
    assert "interface sloping +3.00 +/- 0.00 deg along, +4.81 +/- 0.03 deg across" in line
