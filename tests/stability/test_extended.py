"""The stability suite with many more examples per sweep (``-m extended``)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.extended
def test_stability_suite_with_twenty_times_the_examples():
    env = dict(os.environ, SVSS_STABILITY_SCALE="20")
    res = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                          "-m", "not extended", "tests/stability"], check=False, cwd=ROOT,
                         env=env, capture_output=True, text=True, timeout=3600)
    assert res.returncode == 0, res.stdout[-4000:] + res.stderr[-2000:]
