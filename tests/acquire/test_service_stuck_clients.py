"""``svss acquire`` (a real process against ``svss sim-device``) with catch-up clients
that never read their replies: the daemon's memory stays bounded, a reading client is
served beside them at once, and after the run the daemon lingers only while replies
are taken whole (``catch_up.linger_s``), not until ``max_linger_s``."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import pytest
import zmq

from svss_daq.ping_service import PingFetcher

from .conftest import acquire_toml

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="needs Linux pseudo-terminals and /proc")
# longer than the 10 s a stuck reply blocked the service thread: each kept the daemon up
LINGER_S = 12.0
MAX_LINGER_S = 60.0
QUEUE_MIB = 16 * 0.48          # daq.toml service.client_queue pings of 480 kB


def _rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


@pytest.mark.slow
def test_clients_that_never_read_neither_grow_nor_keep_the_daemon(rig, tmp_path):
    """Issue 27 item 2: such clients grew the daemon by ~450 MiB each, blocked the
    service thread 10 s per stuck reply (a reading client's fetch timed out) and kept
    the daemon lingering until max_linger_s."""
    cfg = acquire_toml(tmp_path, catch_up={"linger_s": LINGER_S,
                                           "max_linger_s": MAX_LINGER_S})
    dev = rig.device("--time-scale", "2")
    acq = rig.acquire(dev, "--pings", "60", config=cfg)
    f = PingFetcher(acq.endpoints["service"], timeout_s=30)
    ctx = zmq.Context()
    stuck = []
    try:
        deadline = time.monotonic() + 60
        while not [r for r in f.runs() if r.run_id == "run1" and r.n_pings >= 5]:
            assert time.monotonic() < deadline, acq.logs()[-3000:]
            time.sleep(0.1)
        base = _rss_mib(acq.proc.pid)
        for _ in range(3):
            s = ctx.socket(zmq.DEALER)
            s.setsockopt(zmq.RCVHWM, 1)
            s.setsockopt(zmq.RCVBUF, 4096)
            s.setsockopt(zmq.LINGER, 0)
            s.connect(acq.endpoints["service"])
            for _ in range(60):
                s.send(json.dumps({"schema": "svss.fetch", "version": 1, "run_id": "run1",
                                   "first": 0, "last": 10**6}).encode())
            stuck.append(s)
        # a reading client beside them, until the run has ended: served at once
        f.timeout_s = 5.0
        peak, worst = base, 0.0
        while True:
            t = time.perf_counter()
            [info] = [r for r in f.runs() if r.run_id == "run1"]
            pings, _ = f.fetch("run1", info.first, min(info.first + 15, info.last))
            worst = max(worst, time.perf_counter() - t)
            peak = max(peak, _rss_mib(acq.proc.pid))
            assert pings and worst < 3.0, worst
            if info.ended:
                break
            assert time.monotonic() < deadline + 120, acq.logs()[-3000:]
            time.sleep(0.1)
        ended = time.monotonic()
        # the last reply taken whole was the fetch above: the daemon leaves linger_s
        # after it (it stayed max_linger_s)
        rc = acq.wait(MAX_LINGER_S + 60)
        left_after = time.monotonic() - ended
    finally:
        f.close()
        for s in stuck:
            s.close(linger=0)
        ctx.term()
    assert rc == 0, acq.logs()[-3000:]
    assert left_after < LINGER_S + 15, left_after
    assert peak - base < 3 * QUEUE_MIB + 100, (base, peak)
    logs = acq.logs()
    assert "request refused unanswered" in logs
