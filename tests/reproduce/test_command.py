"""``svss reproduce --quick`` end to end in its own process (extended: minutes of
simulation; the pieces are tested by the default run in test_measures.py,
test_pieces.py and test_seed_results.py)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest


@pytest.mark.extended
def test_quick_run_writes_the_report_and_figures(tmp_path):
    out = tmp_path / "rep"
    proc = subprocess.run([sys.executable, "-m", "svss", "-q", "reproduce", "--quick",
                           "--out", str(out)], check=False, capture_output=True, text=True,
                          timeout=3600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    report = (out / "report.md").read_text()
    summary = json.loads((out / "results.json").read_text())
    for name in list(summary["figures"].values()) + [summary["field"]["figure"]]:
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"]({name})" in report
    for scene in ("sand", "silt"):
        assert scene in summary["figures"]
    sand = next(c for c in summary["cases"] if c["group"] == "main"
                and c["scene"] == "sand" and c["array"] == summary["seed_config"]["array"]
                and c["variant"]["axis"] == summary["seed_config"]["axis"])
    assert f"{sand['excess_db']:.1f} dB" in report
    assert f"peak {sand['first']['depth']:.3f} m" in report
