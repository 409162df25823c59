#!/usr/bin/env python
"""Does the tile worker keep up with the sonar? A recorded 80-channel survey line
replayed at its real rate through catch-up into ``svss worker`` with the default
processing and products, the acquisition daemon's recording load beside it.

For each survey line (the seed's sand scene and the test field, ``--pings`` each, simulated
once with ``svss simulate`` into ``--cache``) and each instruction-set build (``--isa``:
``native`` = what numba compiles for this machine; ``avx2`` = an AVX2-only target,
``window_gather.AVX2_TARGET``, with its own numba cache), in separate processes:

* ``svss replay RUN.h5 --realtime --service S --subscribers 2``: the pings at their
  recorded rate (10/s), with the catch-up service;
* ``svss worker --connect E --service S --runs 1 --timings T.json``: the default
  processing (config/processing.toml: 15 m tiles of 2 cm voxels, products on);
* a monitor (this process) subscribed to the stream, timing each ping's publication;
* the recording load: ``bench_acquire.py``'s daemon path (assembly, SWMR raw file,
  publishing, a subscriber process) at the nominal 10 pings/s of random 80 x 1500
  int32 samples, for as long as the worker runs (``--no-load``: without).

Reported per line and build: per tile the time from its last ping's publication to its
tile file (and quick look) on disk; the worker's backlog (pings published but not yet fed
to the imager) over time, its peak and its value when the line ends; CPU and wall time
per ping by stage (conditioning, imaging kernel, coverage, scheduling, products and their
parts, run products; the daemon's navigation pose per ping measured here with
``bench_acquire.pose_cost``); and the real-time margin: sonar time (pings x 0.1 s) over
the worker's processing time (the wall time of its stages: what it would need with
nothing to wait for). The numba caches are warmed first (a short ``svss process``-like
pass per build), so no compile is timed.

    python benchmarks/bench_live.py --out benchmarks/results/bench_live.json [--lines sand,field] [--isa native,avx2] [--quick]

``--micronav on,off`` runs each trial with the processing's ``[micronav] live`` on and
then off (default: on, as configured); the live micronavigation's time is the
``micronav`` stage (a part of each ping's, its conditioning not included) and its
refusals are reported from the run's manifest.

``--products process,inline`` runs each trial with daq.toml's ``[worker] products`` as
given (default: as configured, ``process``): the full products in a second process beside
the imaging, or inline. With the products process the worker's own ``products`` stage is
the hand-over (``products_wait``: any wait for the process while imaging; the wait for the
last tiles at the line's end, ``products_drain``, is in their latency, not in the
margin); the process's busy time (``products.process``) gets a margin of its own, and
the reported ``margin`` is the smaller of the two.

``--quick``: the sand line, native build only (``--lines sand --isa native``; the same
cached recording).
"""

from __future__ import annotations

import argparse
import json
import logging
import multiprocessing as mp
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.bench_isa import machine_isa  # noqa: E402
from svss_proc.imaging.window_gather import AVX2_TARGET  # noqa: E402

log = logging.getLogger("bench_live")

LINES = {"sand": ("seed_cylinder_sand", 450), "field": ("sayers_field", 260)}
ISAS = {"native": {}, "avx2": dict(AVX2_TARGET)}
#: top-level stages of the worker: their wall times add up to its processing time
TOP = ("ping", "products", "products_wait", "quicklook", "run_products")
#: parts of a ping's imaging (inside "ping"; micronav: the live micronavigation stage,
#: the ping's conditioning not included)
PING_PARTS = ("micronav", "conditioning", "imaging", "coverage", "scheduling")

WARM = """
import sys
from svss_daq.config import ProcessingConfig, config_path, load_with_text
from svss_daq.rawfile import RawRunReader
from svss_proc.run_worker import Worker
proc = load_with_text(ProcessingConfig, config_path("processing.toml"))
with RawRunReader(sys.argv[1]) as run:
    # the live worker's method (``[imaging] live_method``), as svss worker runs it
    w = Worker(run.hardware, proc, sys.argv[2], run_label="warm-up", live=True)
    w.imager.accumulator.warm_up()
    w.run((p for i, p in zip(range(int(sys.argv[3])), run)))
print("warm", w.clock.totals())
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def env_for(isa: str, cache_root: Path) -> dict:
    env = {**os.environ, **ISAS[isa],
           "PYTHONPATH": os.pathsep.join([str(ROOT)] + [p for p in [
               os.environ.get("PYTHONPATH")] if p])}
    if isa != "native":
        env["NUMBA_CACHE_DIR"] = str(cache_root / f"numba-{isa}")
    return env


def svss_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "svss", *args]


def survey_line(name: str, pings: int, cache: Path) -> Path:
    """The raw run of line ``name`` with ``pings`` pings, simulated once into ``cache``."""
    scene, _ = LINES[name]
    cache.mkdir(parents=True, exist_ok=True)
    run = cache / f"{scene}_{pings}.h5"
    if run.exists():
        return run
    toml = cache / f"{scene}_{pings}.toml"
    text = (ROOT / "config" / "scenes" / f"{scene}.toml").read_text()
    text, n = re.subn(r"(?m)^n_pings = \d+", f"n_pings = {pings}", text)
    if n != 1:
        raise RuntimeError(f"{scene}.toml: no n_pings line")
    toml.write_text(text)
    log.info("simulating %s (%d pings) into %s: minutes", scene, pings, run)
    tmp = run.with_suffix(".partial.h5")
    subprocess.run(svss_cmd("-q", "simulate", "--scene", str(toml), "--out", str(tmp)),
                   cwd=ROOT, check=True)
    tmp.rename(run)
    return run


# --------------------------------------------------------------------------- load


def _writer_load(tmp: str, stop, ready) -> None:
    """bench_acquire.py's daemon path at 10 pings/s until ``stop`` is set."""
    from benchmarks.bench_acquire import _setup, _subscriber
    from svss_daq.daemon import AcquisitionDaemon
    from svss_daq.protocols.digitiser import CompletePing
    from svss_daq.protocols.sequencer import PingEvent
    logging.getLogger("svss_daq").setLevel(logging.WARNING)
    setup = _setup(Path(tmp))
    daemon = AcquisitionDaemon(setup, run_id="load", endpoints={
        k: "tcp://127.0.0.1:*" for k in ("publisher", "service", "status")})
    daemon.bind()
    ctx = mp.get_context("spawn")
    here, there = ctx.Pipe()
    sub = ctx.Process(target=_subscriber, args=(daemon.endpoints["publisher"], 0, there))
    sub.start()
    here.recv()
    daemon.publisher.wait_for_subscribers(1, 30)
    hw = setup.hardware.value
    dig = hw.digitiser
    rng = np.random.default_rng(0)
    samples = [rng.integers(-2**23, 2**23, (dig.n_channels, dig.window_samples),
                            dtype=np.int32) for _ in range(4)]
    order = hw.sequencer.projector_order
    ws = round(dig.window_start_s * 1e9)
    ready.set()
    t0, i = time.perf_counter(), 0
    while not stop.is_set():
        due = t0 + i / 10.0
        while time.perf_counter() < due:
            time.sleep(min(0.001, max(due - time.perf_counter(), 0)))
        t_tx = time.time_ns()
        daemon.pipeline.handle(CompletePing(i, t_tx, t_tx + ws, samples[i % 4]),
                               PingEvent(i, order[i % len(order)], t_tx))
        i += 1
    daemon.stop()
    here.recv()
    sub.join(30)


# --------------------------------------------------------------------------- monitor


class Monitor(threading.Thread):
    """Times each ping's publication (its arrival on a subscriber that does nothing
    else) and the end of the run."""

    def __init__(self, endpoint: str):
        super().__init__(daemon=True)
        import zmq
        from svss_daq.subscriber import subscribe
        self.sock = subscribe(endpoint, 100000, zmq.Context.instance())
        self.published: dict[int, float] = {}
        self.ended_at: float | None = None
        self.stop = threading.Event()

    def run(self) -> None:
        from svss_daq import messages
        while not self.stop.is_set():
            if not self.sock.poll(200):
                continue
            msg = messages.recv(self.sock)
            t = time.time()
            if isinstance(msg, messages.RunEnd):
                self.ended_at = t
                continue
            self.published.setdefault(msg.sequence, t)
        self.sock.close(linger=0)


# --------------------------------------------------------------------------- trial


def warm(run: Path, env: dict, tmp: Path, pings: int) -> None:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", WARM, str(run), str(tmp / "warm"), str(pings)],
                   cwd=ROOT, env=env, check=True, capture_output=True, text=True)
    log.info("caches warm (%.0f s)", time.perf_counter() - t0)


def processing_file(micronav: str, tmp: Path) -> Path:
    """config/processing.toml with ``[micronav] live`` as ``micronav`` says."""
    text = (ROOT / "config" / "processing.toml").read_text()
    on = "on" if micronav == "on" else "off"
    new, n = re.subn(r"(?m)^(\[micronav\][^\[]*?^live = )\w+",
                     lambda m: m.group(1) + ("true" if on == "on" else "false"), text)
    if n != 1:
        raise RuntimeError("processing.toml: no [micronav] live line")
    path = tmp / f"processing-micronav-{on}.toml"
    path.write_text(new)
    return path


def daq_dir(products: str | None, tmp: Path) -> Path | None:
    """A configuration folder like config/ with daq.toml's ``[worker] products`` as
    ``products`` says (None: the shipped folder as it is)."""
    if products is None:
        return None
    d = tmp / f"config-products-{products}"
    shutil.copytree(ROOT / "config", d)
    text = (d / "daq.toml").read_text()
    new, n = re.subn(r'(?m)^products = "\w+"', f'products = "{products}"', text)
    if n != 1:
        raise RuntimeError("daq.toml: no [worker] products line")
    (d / "daq.toml").write_text(new)
    return d


def trial(run: Path, isa: str, cache_root: Path, tmp: Path, load: bool,
          micronav: str = "on", products: str | None = None) -> dict:
    env = env_for(isa, cache_root)
    cfg = daq_dir(products, tmp)
    if cfg is not None:
        env = {**env, "SVSS_CONFIG_DIR": str(cfg)}
    proc = processing_file(micronav, tmp)
    pub, svc = f"tcp://127.0.0.1:{free_port()}", f"tcp://127.0.0.1:{free_port()}"
    out, timings = tmp / "tiles", tmp / "timings.json"
    procs: list[subprocess.Popen] = []
    stop = ready = loader = None
    try:
        if load:
            ctx = mp.get_context("spawn")
            stop, ready = ctx.Event(), ctx.Event()
            loader = ctx.Process(target=_writer_load, args=(str(tmp / "load"), stop, ready))
            loader.start()
            if not ready.wait(120):
                raise RuntimeError("the recording load did not start")
        replay = subprocess.Popen(svss_cmd(
            "-q", "replay", str(run), "--endpoint", pub, "--service", svc, "--realtime",
            "--subscribers", "2", "--linger", "3600", "--wait", "300"), cwd=ROOT, env=env,
            stdout=subprocess.DEVNULL, stderr=open(tmp / "replay.log", "w"))
        procs.append(replay)
        mon = Monitor(pub)
        mon.start()
        wlog = open(tmp / "worker.log", "w")
        worker = subprocess.Popen(svss_cmd(
            "worker", "--connect", pub, "--service", svc, "--out", str(out), "--runs", "1",
            "--timings", str(timings), "--processing", str(proc)), cwd=ROOT, env=env,
            stdout=subprocess.DEVNULL,
            stderr=wlog)
        procs.append(worker)
        t_start = time.time()
        _, status, rusage = os.wait4(worker.pid, 0)
        worker.returncode = os.waitstatus_to_exitcode(status)
        t_done = time.time()
        mon.stop.set()
        mon.join(5)
        if worker.returncode != 0:
            raise RuntimeError(f"svss worker exited {worker.returncode}: "
                               f"{(tmp / 'worker.log').read_text()[-3000:]}")
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
                try:
                    p.wait(30)
                except subprocess.TimeoutExpired:
                    p.kill()
        if loader is not None:
            stop.set()
            loader.join(60)
            if loader.is_alive():
                loader.kill()
    t = json.loads(timings.read_text())["runs"]
    (r,) = t.values()
    out = summarise(r, mon.published, mon.ended_at, t_start, t_done,
                    rusage.ru_utime + rusage.ru_stime)
    (manifest,) = sorted((tmp / "tiles").glob("*/manifest.json"))   # the run's
    out["micronav"] = json.loads(manifest.read_text()).get("micronav")
    return out


def summarise(r: dict, published: dict, ended_at, t_start: float, t_done: float,
              worker_cpu_s: float) -> dict:
    pings = r["pings"]
    interval = r["ping_interval_s"]
    st = r["stage_times"]
    fed = np.array([p[0] for p in r["pings_fed"]])
    pub_t = np.array(sorted(published.values()))
    t0 = pub_t[0]
    sonar_s = pings * interval
    busy = {k: st.get(k, {}).get("wall_s", 0.0) for k in TOP}
    busy["fetch"] = r["fetch_s"]
    busy_s = sum(busy.values())
    # the products process (daq.toml [worker] products = "process"): its own busy time
    side_s = st.get("products.process", {}).get("wall_s", 0.0)
    margin_main = sonar_s / busy_s
    margin_side = sonar_s / side_s if side_s > 0 else None
    # backlog: published but not yet fed, every 0.5 s from the first ping to the end
    grid = np.arange(t0, max(t_done, pub_t[-1]) + 0.5, 0.5)
    backlog = (np.searchsorted(pub_t, grid, side="right")
               - np.searchsorted(np.sort(fed), grid, side="right"))
    end_i = int(np.searchsorted(grid, pub_t[-1]))
    tiles = []
    for e in r["tiles"]:
        last = published.get(e["last_ping"])
        row = {"tile": e["tile"], "pings": e["pings"], "last_ping": e["last_ping"],
               "deferred": e["quicklook_unix_s"] is not None}
        if last is not None:
            row["latency_s"] = round(e["written_unix_s"] - last, 2)
            if e["quicklook_unix_s"] is not None:
                row["quicklook_latency_s"] = round(e["quicklook_unix_s"] - last, 2)
        tiles.append(row)
    per_ping = {k: {"cpu_ms": None if v["cpu_s"] is None else 1e3 * v["cpu_s"] / pings,
                    "wall_ms": 1e3 * v["wall_s"] / pings, "calls": v["calls"]}
                for k, v in st.items()}
    other = st["ping"]["wall_s"] - sum(st.get(k, {}).get("wall_s", 0.0) for k in PING_PARTS)
    per_ping["ping.other"] = {"cpu_ms": None, "wall_ms": 1e3 * other / pings, "calls": None}
    return {"pings": pings, "published": len(published), "sonar_s": sonar_s,
            "processing_s": round(busy_s, 2), "processing_by_stage_s": {
                k: round(v, 2) for k, v in busy.items()},
            "margin": round(min(margin_main, margin_side or margin_main), 3),
            "margin_worker": round(margin_main, 3),
            "products_process_s": round(side_s, 2) if side_s else None,
            "margin_products_process": (None if margin_side is None
                                        else round(margin_side, 3)),
            "worker_cpu_s": round(worker_cpu_s, 1),
            # cores the worker kept busy per core-second of sonar time: above the
            # machine's cores it cannot keep up even alone (start-up included)
            "worker_cpu_per_sonar_s": round(worker_cpu_s / sonar_s, 2),
            "elapsed_first_ping_to_done_s": round(t_done - t0, 1),
            "done_after_last_ping_s": round(t_done - pub_t[-1], 1),
            "worker_started_before_first_ping_s": round(t0 - t_start, 1),
            "backlog_pings": {"peak": int(backlog.max()),
                              "at_last_ping": int(backlog[min(end_i, len(backlog) - 1)]),
                              "every_0.5_s": backlog.tolist()},
            "max_lag_s": r["behind"]["max_lag_s"], "behind": r["behind"],
            "tiles": tiles, "per_ping": per_ping, "stage_times": st}


# --------------------------------------------------------------------------- main


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="bench_live.json")
    ap.add_argument("--lines", default="sand,field")
    ap.add_argument("--isa", default="native,avx2")
    ap.add_argument("--pings", type=int, default=None,
                    help="pings per line (default: sand 450, field 260: the scene's own)")
    ap.add_argument("--cache", default=str(ROOT / "out" / "bench_live"),
                    help="folder of the simulated lines and the AVX2 numba cache")
    ap.add_argument("--no-load", action="store_true", help="without the recording load")
    ap.add_argument("--micronav", default="on",
                    help="[micronav] live in the worker's processing: on, off or "
                         "on,off (one trial each, in that order)")
    ap.add_argument("--products", default=None,
                    help="daq.toml [worker] products in the worker: process, inline or "
                         "process,inline (one trial each; default: as configured)")
    ap.add_argument("--quick", action="store_true",
                    help="the sand line, native build only (--lines sand --isa native)")
    args = ap.parse_args(argv)
    if args.quick:
        args.lines, args.isa = "sand", "native"
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    cache = Path(args.cache)
    from benchmarks.bench_acquire import pose_cost
    res = {"command": " ".join(["python"] + [os.path.relpath(sys.argv[0], ROOT)]
                               + sys.argv[1:]),
           "machine": machine_isa(), "load_before": os.getloadavg(),
           "recording_load": not args.no_load, "lines": {}}
    res["navigation_pose"] = pose_cost(100)
    nav_ms = 1e3 * res["navigation_pose"]["s_per_ping_batch_1"]
    isas = args.isa.split(",")
    for name in args.lines.split(","):
        run = survey_line(name, args.pings or LINES[name][1], cache)
        modes = args.products.split(",") if args.products else [None]
        for isa, mn, pm in ((i, m, q) for i in isas for m in args.micronav.split(",")
                            for q in modes):
            with tempfile.TemporaryDirectory(prefix="bench_live_") as tmp:
                tmp = Path(tmp)
                env = env_for(isa, cache)
                warm(run, env, tmp, 40)
                shutil.rmtree(tmp / "warm", ignore_errors=True)
                load0 = os.getloadavg()
                log.info("%s, %s build, micronavigation %s: replaying %s at its real rate "
                         "(load %.2f)", name, isa, mn, run.name, load0[0])
                r = trial(run, isa, cache, tmp, not args.no_load, mn, pm)
                r["load_during"] = [load0, os.getloadavg()]
                r["navigation_pose_ms_per_ping"] = nav_ms
                key = isa if args.micronav == "on" else f"{isa}, micronav {mn}"
                key = key if pm is None else f"{key}, products {pm}"
                res["lines"].setdefault(name, {})[key] = r
                log.info("%s %s: margin %.2f (sonar %.0f s, processing %.0f s), backlog "
                         "peak %d, %d at the last ping; tiles %s", name, key, r["margin"],
                         r["sonar_s"], r["processing_s"], r["backlog_pings"]["peak"],
                         r["backlog_pings"]["at_last_ping"],
                         [t.get("latency_s") for t in r["tiles"]])
    res["load_after"] = os.getloadavg()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(res, indent=1))
    print(report(res))
    print(f"saved {args.out}")
    return 0


def report(res: dict) -> str:
    lines = [f"{res['machine']['cpu']} ({', '.join(res['machine']['isa'])}), "
             f"{res['machine']['cores']} cores; load {res['load_before'][0]:.2f} before, "
             f"{res['load_after'][0]:.2f} after; recording load "
             f"{'on' if res['recording_load'] else 'off'}"]
    stages = ("micronav", "conditioning", "imaging", "coverage", "scheduling", "ping.other",
              "products",
              "products.chain", "products.background", "products.normalisation",
              "products.compression_and_mips", "products.detection", "products.quicklook_png",
              "products.tile_file", "products.process", "products_wait",
              "products_drain", "quicklook",
              "run_products")
    for name, by_isa in res["lines"].items():
        for isa, r in by_isa.items():
            lines.append(f"\n{name}, {isa}: {r['pings']} pings, sonar {r['sonar_s']:.0f} s, "
                         f"processing {r['processing_s']:.1f} s, margin {r['margin']:.2f}"
                         + ("" if r.get("products_process_s") is None else
                            f" (worker {r['margin_worker']:.2f}, products process "
                            f"{r['margin_products_process']:.2f})") + "; "
                         f"backlog peak {r['backlog_pings']['peak']} pings, "
                         f"{r['backlog_pings']['at_last_ping']} at the last ping; done "
                         f"{r['done_after_last_ping_s']:.1f} s after it; worker CPU "
                         f"{r['worker_cpu_s'] / r['sonar_s']:.2f} s per sonar s; load "
                         f"{r['load_during'][0][0]:.2f}/{r['load_during'][1][0]:.2f}")
            lines.append("  tile latency (last ping -> tile file), s: " + ", ".join(
                f"{t['tile']}: {t.get('latency_s', '?')}"
                + (f" (quick look {t['quicklook_latency_s']})" if t.get('deferred') else "")
                for t in r["tiles"]))
            lines.append(f"  {'stage':24s} {'CPU ms/ping':>12s} {'wall ms/ping':>13s}")
            for s in stages:
                v = r["per_ping"].get(s)
                if v is None:
                    continue
                cpu = "" if v["cpu_ms"] is None else f"{v['cpu_ms']:.1f}"
                lines.append(f"  {s:24s} {cpu:>12s} {v['wall_ms']:13.1f}")
            lines.append(f"  {'navigation (daemon)':24s} {r['navigation_pose_ms_per_ping']:12.2f}")
            if r.get("micronav"):
                lines.append(f"  micronavigation: {json.dumps(r['micronav'])}")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
