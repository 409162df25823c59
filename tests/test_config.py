"""Configuration loading: every shipped file validates; bad files are named precisely."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest

from sim_device.scene import load_scene
from svss_daq.config import (ConfigError, DaqConfig, DevicesConfig, HardwareConfig,
                             ProcessingConfig, config_dir, load, load_with_text)

CONFIG = config_dir()


def test_shipped_files_validate():
    hw = load(HardwareConfig, CONFIG / "hardware.toml")
    assert hw.digitiser.n_channels == 80 and len(hw.projectors.positions_m) == 6
    assert hw.waveform.f_start_hz == 35000 and hw.waveform.f_stop_hz == 20000
    for name in ("processing.toml", "processing-demo.toml"):
        load(ProcessingConfig, CONFIG / name)
    load(DaqConfig, CONFIG / "daq.toml")
    devices = load(DevicesConfig, CONFIG / "devices.toml")
    assert devices.sequencer.baudrate == 115200 and devices.digitiser.port == 5600
    scenes = sorted((CONFIG / "scenes").glob("*.toml"))
    assert len(scenes) >= 4
    for path in scenes:
        sc = load_scene(path)
        raw = tomllib.loads(path.read_text())        # the file's own values, read here
        assert (sc.scene.name, sc.scene.seed, sc.track.n_pings, len(sc.points)) == (
            raw["scene"]["name"], raw["scene"]["seed"], raw["track"]["n_pings"],
            len(raw.get("points", []))), path.name


def _edited(tmp_path: Path, name: str, old: str, new: str) -> Path:
    text = (CONFIG / name).read_text()
    assert re.search(old, text, flags=re.M), old
    out = tmp_path / Path(name).name
    out.write_text(re.sub(old, new, text, count=1, flags=re.M))
    return out


@pytest.mark.parametrize("old, new, must_say", [
    (r"^bits = 24", "bits = 24\nbitz = 3", ["unknown key 'digitiser.bitz'", "bits"]),
    (r"^bits = 24", 'bits = "24"', ["digitiser.bits", "integer", "'24'"]),
    (r"^bits = 24", "bits = 24.5", ["digitiser.bits", "integer"]),
    (r"^sample_rate_hz = 125000.0", "sample_rate_hz = -5.0",
     ["digitiser.sample_rate_hz", "below the minimum", "1000.0"]),
    (r"^projector_half_angle_deg = 25.0", "", ["missing key",
                                               "beams.projector_half_angle_deg"]),
    (r"^boresight = .*$", "boresight = [0.0, 1.0]", ["beams.boresight", "length 3"]),
    (r"^window = \"taylor\"", 'window = "kaiser"', ["waveform.window", "'kaiser'", "taylor"]),
    (r"center_m = \[-0.182, 0.0, 0.0\]", "center_m = [-0.182, 0.0]",
     ["receive_array.sections[0].center_m", "length 3"]),
    (r"\[0.5185, -0.5725, 0.0\]", "[0.5185, -0.5725]",
     ["projectors.positions_m[0]", "length 3"]),
])
def test_bad_hardware_is_named(tmp_path, old, new, must_say):
    path = _edited(tmp_path, "hardware.toml", old, new)
    with pytest.raises(ConfigError) as err:
        load(HardwareConfig, path)
    msg = str(err.value)
    assert str(path) in msg
    for s in must_say:
        assert s in msg, msg


def test_bad_scene_and_processing_are_named(tmp_path):
    path = _edited(tmp_path, "scenes/demo.toml", r"^target_strength_db = -20.0",
                   "target_strength_db = true")
    with pytest.raises(ConfigError, match=r"points\[0\].target_strength_db.*number"):
        load_scene(path)
    path = _edited(tmp_path, "processing.toml", r'^interface = "altitude"',
                   'interface = "sonar"')
    with pytest.raises(ConfigError, match=r"imaging.interface.*'sonar'"):
        load(ProcessingConfig, path)


def test_not_toml_and_missing_file(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[digitiser\nbits = 3")
    with pytest.raises(ConfigError, match="bad.toml: not valid TOML"):
        load(HardwareConfig, bad)
    with pytest.raises(ConfigError, match="nope.toml: configuration file not found"):
        load(HardwareConfig, tmp_path / "nope.toml")


def test_config_id_follows_text(tmp_path):
    a = load_with_text(HardwareConfig, CONFIG / "hardware.toml")
    path = _edited(tmp_path, "hardware.toml", r"^gain_db = 0.0", "gain_db = 6.0")
    b = load_with_text(HardwareConfig, path)
    assert a.id != b.id and len(a.id) == 16
    assert load_with_text(HardwareConfig, CONFIG / "hardware.toml").id == a.id


def test_a_file_older_than_a_key_is_told_what_to_add(tmp_path):
    """A processing file written before a key existed (here [ping_gate] held): the error
    names the key and quotes the shipped file's line, with its table."""
    from svss_daq.config import ConfigError, ProcessingConfig, config_path, load
    old = tmp_path / "processing.toml"
    text = config_path("processing.toml").read_text()
    assert 'held = "refuse"' in text
    old.write_text(text.replace('held = "refuse"', "", 1))
    with pytest.raises(ConfigError) as err:
        load(ProcessingConfig, old)
    msg = str(err.value)
    assert msg.startswith(f"{old}: missing key 'ping_gate.held'")
    assert 'held = "refuse" under [ping_gate]: add it' in msg
    assert str(config_path("processing.toml")) in msg
