"""A ping of a run the daemon does not announce cannot hijack a worker: one ping named
``../../evil run`` and its end marker, put on the stream mid-run, are refused and
counted; the worker (``--runs 1``, as ``svss demo`` starts it) stays on its run, images
every one of its pings, writes nothing of the foreign run and exits 0 at the real end.
The worker is a real ``svss worker`` process; the stream and the service are this
test's, on loopback, serving a simulated raw run as it is published."""

from __future__ import annotations

import dataclasses
import json

import pytest

from svss_daq import messages

from .conftest import N_SHORT, assert_same_tiles
from .test_end_marker import DEADLINE_S, streamed_worker, wait_for

EVIL = "../../evil run"


@pytest.mark.slow
def test_a_foreign_run_on_the_stream_is_refused_and_the_run_goes_on(
        short_run, short_processed, small_proc_path, tmp_path):
    with streamed_worker(short_run, small_proc_path, tmp_path) as (pub, svc, pings,
                                                                   worker, log, out):
        for p in pings[:15]:
            pub.publish(p, run_id="line1")
        # mid-run: one ping of a run nobody records, and its end marker
        forged = dataclasses.replace(pings[15], sequence=pings[15].sequence + 1000)
        pub.publish(forged, run_id=EVIL)
        pub.publish(messages.RunEnd(EVIL, 1))
        wait_for(lambda: worker.poll() is not None
                 or "end marker of run ../../evil run" in log.read_text(),
                 "the worker to take the foreign run's end marker")
        for p in pings[15:]:
            pub.publish(p, run_id="line1")
        svc.store.end("line1")
        pub.publish(messages.RunEnd("line1", len(pings)))
        assert worker.wait(DEADLINE_S) == 0, log.read_text()[-3000:]
    text = log.read_text()
    m = json.loads((out / "manifest.json").read_text())
    assert m["complete"] and m["pings"] == len(pings) == N_SHORT, m
    assert m["foreign_pings_refused"] == {EVIL: 1}, m
    assert m["end_markers_refused"] == 1, m
    assert list(m["runs"]) == ["line1"] and m["runs"]["line1"]["complete"]
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == ["line1"]
    assert not (tmp_path.parent / "evil run").exists()
    assert "does not announce that run" in text, text[-3000:]
    assert_same_tiles(short_processed, out / "line1")
