"""Shared fixtures: the project's configuration and small helpers."""

from __future__ import annotations

from pathlib import Path

import pytest

from svss_daq.config import HardwareConfig, ProcessingConfig, config_path, load_with_text

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = ROOT.parent / "shared" / "data"


@pytest.fixture(scope="session")
def hardware():
    return load_with_text(HardwareConfig, config_path("hardware.toml"))


@pytest.fixture(scope="session")
def demo_processing():
    return load_with_text(ProcessingConfig, config_path("processing-demo.toml"))
