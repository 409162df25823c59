"""A run with pings missing between imaged ones (a recording with holes, as a sonar that
stopped pinging over a stretch of track leaves) says so at the top of its manifest:
how many pings are missing, and each gap's sequences and the track it spans (it said
``complete: true`` and ``skipped_pings: 0``, the gap only as ``sequence_gaps: 2``)."""

from __future__ import annotations

import json

import pytest

from svss_daq.config import ProcessingConfig, load_with_text
from svss_proc.run_worker import process_raw

from .conftest import simulate

HOLE = frozenset(range(10, 16))       # six pings, 0.6 m of track at 1 m/s and 10 Hz


@pytest.mark.slow
def test_the_manifest_says_which_pings_are_missing_and_over_what_track(
        tmp_path, small_proc_path):
    raw = simulate(tmp_path / "holed.h5", 30, skip=HOLE | {22})
    out = tmp_path / "tiles"
    process_raw(raw, out, load_with_text(ProcessingConfig, small_proc_path))
    text = (out / "manifest.json").read_text()
    m = json.loads(text)
    assert list(m)[:3] == ["complete", "missing_pings", "gaps"]   # read first
    assert m["missing_pings"] == 7 and m["sequence_gaps"] == 2
    assert [(g["first"], g["last"], g["pings"]) for g in m["gaps"]] == [(10, 15, 6),
                                                                       (22, 22, 1)]
    # the body moved 7 ping intervals across the first gap, 2 across the second
    assert m["gaps"][0]["distance_m"] == pytest.approx(0.7, abs=0.02)
    assert m["gaps"][1]["distance_m"] == pytest.approx(0.2, abs=0.02)
