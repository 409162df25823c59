#!/usr/bin/env python
"""Sustained throughput and latency of the acquisition daemon (``svss acquire``).

The daemon's ping path -- pairing with the transmit record, assembly, recording to the
rotating SWMR raw file, publishing on the ping stream -- is driven from memory as fast as
it goes (and, for the latency, paced at given rates), with a subscriber in another
process timing each ping's arrival. What is measured, in one run:

* ``max``: pings/s and MB/s to disk and ZeroMQ at full speed, with every ping checked in
  the recording afterwards (none may be lost) and counted at the subscriber;
* ``paced``: publish-to-receive latency (p50, p99, max) at 10 (nominal), 100 and 200
  pings/s (20x the nominal 4.8 MB/s);
* ``pose``: cost of one navigation solution (``Navigator.poses`` at one time with the
  daemon's 60 s of 5 Hz GPS, heading and DVL history), which the daemon adds per ping.

The devices themselves are left out: ``svss sim-device`` makes at most ~60-80 pings/s on
this machine (docs/sim_device.md), below what is measured here.

Usage::

    python benchmarks/bench_acquire.py --out benchmarks/results/bench_acquire.json [--quick]
"""

from __future__ import annotations

import argparse
import json
import logging
import multiprocessing as mp
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from svss_daq.acquire_config import load_acquire  # noqa: E402
from svss_daq.config import DevicesConfig, config_path, load  # noqa: E402
from svss_daq.daemon import AcquisitionDaemon  # noqa: E402
from svss_daq.navigation import DvlSample, GpsFix, HeadingSample, Navigator  # noqa: E402
from svss_daq.protocols.digitiser import CompletePing  # noqa: E402
from svss_daq.protocols.sequencer import PingEvent  # noqa: E402
from svss_daq.rawfile import RawRunReader  # noqa: E402

log = logging.getLogger("bench_acquire")


def _subscriber(endpoint: str, n_expected: int, conn) -> None:
    """Receive pings; send back (sequence, receive time ns) pairs."""
    import zmq

    from svss_daq import messages
    from svss_daq.subscriber import subscribe
    sock = subscribe(endpoint, 100000, zmq.Context.instance())
    conn.send("ready")
    got = []
    while True:
        if not sock.poll(20000):
            break
        msg = messages.recv(sock)
        t = time.time_ns()
        if isinstance(msg, messages.RunEnd):
            break
        got.append((msg.sequence, t))
    conn.send(got)


def _setup(tmp: Path):
    tmp.mkdir(parents=True, exist_ok=True)
    devices = tmp / "devices.toml"
    text = (ROOT / "config" / "devices.toml").read_text()
    # no navigation links: the pose cost is measured on its own (below)
    keep, skip = [], False
    for line in text.splitlines():
        if line.startswith("["):
            skip = line.strip() in ("[dvl]", "[gps]")
        if not skip:
            keep.append(line)
    devices.write_text("\n".join(keep) + "\n")
    load(DevicesConfig, devices)
    return load_acquire(config_path("acquire.toml"), devices=devices, out_dir=tmp / "runs")


def run_trial(rate_hz: float | None, n: int, tmp: Path, run_id: str) -> dict:
    setup = _setup(tmp)
    daemon = AcquisitionDaemon(setup, run_id=run_id, endpoints={
        k: "tcp://127.0.0.1:*" for k in ("publisher", "service", "status")})
    daemon.bind()
    ctx = mp.get_context("spawn")
    here, there = ctx.Pipe()
    sub = ctx.Process(target=_subscriber, args=(daemon.endpoints["publisher"], n, there))
    sub.start()
    assert here.recv() == "ready"
    daemon.publisher.wait_for_subscribers(1, 30)
    hw = setup.hardware.value
    dig = hw.digitiser
    rng = np.random.default_rng(0)
    samples = [rng.integers(-2**23, 2**23, (dig.n_channels, dig.window_samples),
                            dtype=np.int32) for _ in range(4)]
    order = hw.sequencer.projector_order
    sent: dict[int, int] = {}
    publish = daemon.publisher.publish

    def timed(msg, **kw):
        if hasattr(msg, "sequence"):
            sent[msg.sequence] = time.time_ns()
        return publish(msg, **kw)
    daemon.publisher.publish = timed
    ws = round(dig.window_start_s * 1e9)
    t_start = time.perf_counter()
    for i in range(n):
        if rate_hz:
            due = t_start + i / rate_hz
            while time.perf_counter() < due:
                time.sleep(min(0.001, max(due - time.perf_counter(), 0)))
        t_tx = time.time_ns()
        data = CompletePing(i, t_tx, t_tx + ws, samples[i % 4])
        daemon.pipeline.handle(data, PingEvent(i, order[i % len(order)], t_tx))
    elapsed = time.perf_counter() - t_start
    daemon.stop()
    got = here.recv()
    sub.join(30)
    recorded = 0
    for f in daemon.recorder.segments:
        with RawRunReader(f) as run:
            recorded += len(run)
    lat = np.array([(t - sent[s]) * 1e-6 for s, t in got if s in sent])
    mb = n * samples[0].nbytes / 1e6
    out = {"rate_hz": rate_hz, "pings": n, "elapsed_s": elapsed,
           "pings_per_s": n / elapsed, "mb_per_s": mb / elapsed,
           "recorded": recorded, "received": len(got),
           "publish_dropped": daemon.counters.publish_dropped,
           "segments": len(daemon.recorder.segments),
           "latency_ms": {"p50": float(np.percentile(lat, 50)) if lat.size else None,
                          "p99": float(np.percentile(lat, 99)) if lat.size else None,
                          "max": float(lat.max()) if lat.size else None}}
    log.info("%s: %.0f pings/s, %.0f MB/s, recorded %d/%d, received %d, latency p50 %.2f "
             "p99 %.2f ms", "max" if rate_hz is None else f"{rate_hz:g}/s",
             out["pings_per_s"], out["mb_per_s"], recorded, n, len(got),
             out["latency_ms"]["p50"] or -1, out["latency_ms"]["p99"] or -1)
    return out


def pose_cost(reps: int) -> dict:
    """Seconds per ping of ``Navigator.poses`` with 60 s of 5 Hz data, for pings posed
    one by one and in batches."""
    nav_cfg = load(DevicesConfig, config_path("devices.toml")).navigation
    from svss_daq.config import HardwareConfig
    hw = load(HardwareConfig, config_path("hardware.toml"))
    nav = Navigator(nav_cfg, hw.lever_arms, history_s=60.0)
    t0 = 1_800_000_000 * 10**9
    for k in range(300):
        t = t0 + k * 200_000_000
        nav.add_fix(GpsFix(t, 41.5 + k * 2e-6, -70.6, 0.0, 2))
        nav.headings.append(HeadingSample(t, 0.1))
        nav.dvl.append(DvlSample(t + 10**7, (1.0, 0.0, 0.0), (2.3, 2.3, 2.3, 2.3)))
    t_end = t0 + 299 * 200_000_000
    out = {"history_s": 60, "samples_per_source": 300}
    for batch in (1, 5, 20):        # pings posed together (the daemon's loop batches them)
        times = [t_end - 50_000_000 - j * 10_000_000 for j in range(batch)]
        nav.poses(times)
        start = time.perf_counter()
        for _ in range(reps):
            nav.poses(times)
        dt = (time.perf_counter() - start) / reps
        out[f"s_per_ping_batch_{batch}"] = dt / batch
        log.info("pose: %.2f ms per ping in batches of %d", dt / batch * 1e3, batch)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", help="write the figures as JSON here")
    ap.add_argument("--quick", action="store_true", help="fewer pings")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    logging.getLogger("svss_daq").setLevel(logging.WARNING)
    n_max = 300 if args.quick else 1500
    res = {"machine": {"cpus": os.cpu_count(), "platform": platform.platform(),
                       "python": platform.python_version()},
           "command": "python benchmarks/bench_acquire.py" + (" --quick" if args.quick
                                                             else ""),
           "nominal": {"pings_per_s": 10.0, "mb_per_s": 4.8}}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        res["max"] = run_trial(None, n_max, tmp / "max", "max")
        res["paced"] = [run_trial(r, int(r * (3 if args.quick else 8)), tmp / f"p{r:g}",
                                  f"p{r:g}") for r in (10.0, 100.0, 200.0)]
    res["pose"] = pose_cost(50 if args.quick else 300)
    m = res["max"]
    print(f"\nacquisition daemon, {os.cpu_count()} cores: record + publish")
    print(f"{'trial':>8} {'pings/s':>9} {'MB/s':>7} {'x nominal':>9} {'recorded':>9} "
          f"{'received':>9} {'p50 ms':>7} {'p99 ms':>7} {'max ms':>7}")
    for name, r in [("max", m)] + [(f"{p['rate_hz']:g}/s", p) for p in res["paced"]]:
        la = r["latency_ms"]
        print(f"{name:>8} {r['pings_per_s']:9.1f} {r['mb_per_s']:7.1f} "
              f"{r['mb_per_s'] / 4.8:9.1f} {r['recorded']:>5}/{r['pings']:<4}"
              f"{r['received']:>8} {la['p50']:7.2f} {la['p99']:7.2f} {la['max']:7.2f}")
    po = res["pose"]
    print("navigation pose per ping: " + ", ".join(
        f"{po[f's_per_ping_batch_{b}'] * 1e3:.2f} ms (batches of {b})" for b in (1, 5, 20)))
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(res, indent=2))
        print(f"wrote {args.out}")
    lost = [r for r in [m, *res["paced"]] if r["recorded"] != r["pings"]]
    return 1 if lost else 0


if __name__ == "__main__":
    sys.exit(main())
