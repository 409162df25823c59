"""The autofocus stage's switch: ``--autofocus / --no-autofocus`` of `svss process` and
`svss batch` over ``[autofocus] enabled`` of the processing configuration (one key, read
through svss_daq.config; an invalid value named with its file and key)."""

from __future__ import annotations

from pathlib import Path

import pytest

from svss.cli import build_parser
from svss_daq.config import ConfigError, ProcessingConfig, config_path, loaded_from_text
from svss_proc.micronav.af_stage import autofocus_wanted


def _processing(enabled: str):
    text = Path(config_path("processing.toml")).read_text()
    assert text.count("\nenabled = false               # a stage of svss process") == 1
    text = text.replace("\nenabled = false               # a stage of svss process",
                        f"\nenabled = {enabled}               # a stage of svss process")
    return loaded_from_text(ProcessingConfig, text, "processing-af.toml").value


@pytest.mark.parametrize("command", [["process", "r.h5"], ["batch", "r.h5"]])
def test_the_flags_override_the_configuration(command):
    parse = build_parser().parse_args
    base = [*command, "--out", "o"]
    assert parse(base).autofocus is None
    assert parse([*base, "--autofocus"]).autofocus is True
    assert parse([*base, "--no-autofocus"]).autofocus is False
    on, off = _processing("true"), _processing("false")
    assert autofocus_wanted(None, on) and not autofocus_wanted(None, off)
    assert autofocus_wanted(True, off) and not autofocus_wanted(False, on)


def test_off_by_default_and_without_the_table():
    default = loaded_from_text(ProcessingConfig, Path(config_path("processing.toml"))
                               .read_text(), "processing.toml").value
    assert default.autofocus.enabled is False
    demo = loaded_from_text(ProcessingConfig, Path(config_path("processing-demo.toml"))
                            .read_text(), "processing-demo.toml").value
    assert demo.autofocus is None and not autofocus_wanted(None, demo)


def test_an_invalid_value_names_the_file_and_the_key():
    with pytest.raises(ConfigError, match=r"processing-af\.toml.*enabled"):
        _processing('"yes"')
