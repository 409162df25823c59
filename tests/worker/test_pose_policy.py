"""The navigation's pose flags in processing: a pose without heading or without position
is refused with its reason and counted; what a held, dead-reckoned, re-timed or
fallback-heading pose may image is the processing configuration's ``[ping_gate]``
policy (held refused, the others imaged by default). The worker, ``svss process`` and
the batch plan judge alike."""

from __future__ import annotations

import dataclasses
import json
import logging
import math

import pytest

from svss_daq.config import ProcessingConfig, loaded_from_text
from svss_daq.ping import (NAV_BOTTOM_LOCK, NAV_CLOCK_RETIMED, NAV_DEAD_RECKONED, NAV_GPS_FIX,
                           NAV_HEADING_FROM_COMPASS, NAV_HEADING_FROM_COURSE, NAV_HELD,
                           NAV_NO_HEADING)
from svss_daq.rawfile import RawRunWriter
from svss_proc.batch.plan import plan_run
from svss_proc.run_worker import Worker, process_raw

from .conftest import stream_processing_text
from .test_tile_closing import pings

OK = NAV_GPS_FIX | NAV_BOTTOM_LOCK
#: ping index -> (quality, north NaN): the flags each test ping carries
FLAGGED = {1: (OK | NAV_NO_HEADING, False), 2: (0, True), 3: (OK | NAV_HELD, False),
           4: (NAV_DEAD_RECKONED | NAV_BOTTOM_LOCK, False),
           5: (OK | NAV_HEADING_FROM_COURSE, False), 6: (OK | NAV_CLOCK_RETIMED, False),
           7: (OK | NAV_HEADING_FROM_COMPASS, False)}
N_PINGS = 12


def processing(**policy):
    # no products: the tests count pings and refusals (tests/worker/conftest.py)
    text = stream_processing_text()
    for key, value in policy.items():
        old = next(ln for ln in text.splitlines() if ln.startswith(f"{key} ="))
        text = text.replace(old, f'{key} = "{value}"')
    return loaded_from_text(ProcessingConfig, text, "small-processing")


def flagged_pings(hardware):
    out = []
    for i, p in enumerate(pings(hardware, [0.1 * i for i in range(N_PINGS)])):
        q, nan = FLAGGED.get(i, (OK, False))
        nav = dataclasses.replace(p.nav, quality=q,
                                  north_m=math.nan if nan else p.nav.north_m)
        out.append(dataclasses.replace(p, nav=nav))
    return out


def run_worker(hardware, proc, out):
    w = Worker(hardware, proc, out)
    w.run(flagged_pings(hardware))
    return json.loads((out / "manifest.json").read_text())


def test_default_policy_refuses_no_heading_no_position_and_held(hardware, tmp_path, caplog):
    with caplog.at_level(logging.WARNING):
        m = run_worker(hardware, processing(), tmp_path / "default")
    assert m["refused"] == {"pose without heading": 1, "pose without position": 1,
                            "held pose": 1}
    assert m["pings"] == N_PINGS - 3 and m["pings_refused"] == 3
    # the imaged pings' flags are counted too
    assert m["pose_flags"] == {"bottom_lock": N_PINGS - 3, "clock_retimed": 1,
                               "dead_reckoned": 1, "gps_fix": N_PINGS - 4,
                               "heading_from_compass": 1, "heading_from_course": 1}
    assert "refused ping 2: pose without position (north_m NaN: no GPS fix and no dead " \
           "reckoning" in caplog.text
    assert "refused ping 1: pose without heading (NAV_NO_HEADING" in caplog.text
    assert 'refused ping 3: held pose (extrapolated past the last navigation record); ' \
           'ping_gate.held = "refuse"' in caplog.text


def test_the_policy_says_what_flagged_poses_may_image(hardware, tmp_path):
    m = run_worker(hardware, processing(held="image", dead_reckoned="refuse",
                                  clock_retimed="refuse", heading_from_course="refuse",
                                  heading_from_compass="refuse"), tmp_path / "strict")
    assert m["refused"] == {"pose without heading": 1, "pose without position": 1,
                            "dead-reckoned pose": 1, "re-timed pose": 1,
                            "heading from course": 1, "heading from compass": 1}
    assert m["pose_flags"]["held"] == 1 and m["pings"] == N_PINGS - 6


def test_svss_process_and_the_batch_plan_refuse_the_same(hardware, tmp_path):
    raw = tmp_path / "flagged.h5"
    with RawRunWriter(raw, hardware) as w:
        for p in flagged_pings(hardware):
            w.append(p)
    proc = processing()
    process_raw(raw, tmp_path / "processed", proc)
    m = json.loads((tmp_path / "processed" / "manifest.json").read_text())
    plan = plan_run("flagged", "flagged", [raw], proc)
    assert plan.refused == m["refused"] == {"pose without heading": 1,
                                            "pose without position": 1, "held pose": 1}
    planned = sorted({s for t in plan.tiles for s in t.sequences})
    assert planned == [i for i in range(N_PINGS) if i not in (1, 2, 3)]


@pytest.mark.parametrize("key", ["held", "dead_reckoned", "clock_retimed",
                                 "heading_from_course", "heading_from_compass"])
def test_a_policy_is_image_or_refuse(key):
    from svss_daq.config import ConfigError
    with pytest.raises(ConfigError, match=f"ping_gate.{key}"):
        processing(**{key: "maybe"})
