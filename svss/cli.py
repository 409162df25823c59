"""``svss``: the SVSS command-line tool.

    svss demo --out DIR                  whole chain on the built-in scene
    svss acquire [--config FILE] [--devices FILE] [--pings N | --duration S]
    svss status [--connect ENDPOINT] [--json] [--follow]
    svss view [--tiles DIR] [--connect ENDPOINT] [--address A] [--port N]
    svss simulate --scene FILE --out RUN.h5
    svss process RUN.h5 --out DIR [--renavigate | --no-renavigate] [--micronav]
                 [--autofocus | --no-autofocus] [--sediment-speed estimate|configured]
    svss batch RUN.h5 [RUN2.h5 ...] --out DIR [--scheduler ADDRESS] [--workers N]
               [--renavigate | --no-renavigate] [--micronav | --no-micronav]
               [--autofocus | --no-autofocus] [--sediment-speed estimate|configured]
    svss worker --connect ENDPOINT --out DIR [--service E] [--runs N]
    svss replay RUN.h5 [RUN2.h5 ...] [--endpoint E] [--service E] [--realtime]
    svss inspect FILE [--json | --verify]
    svss products TILES_DIR [--out DIR] [--origin LAT LON [HEIGHT]]
    svss score TILES_DIR --scene FILE [--radius M] [--out REPORT.json]
    svss sim-device --scene FILE [--time-scale S] [--faults FILE] [--from-run RUN.h5]
                    [--devices-out FILE] [--workers N] [--no-navigation] [--lead S]
    svss keys --out DIR [--name NAME] [--force]
    svss trade --out DIR [--quick] [--budget-s S] [--areas imaging,simulation,normalisation]
    svss reproduce --out DIR [--quick] [--seeds N] [--no-field]
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading
from pathlib import Path

from svss_daq.config import (ConfigError, DaqConfig, HardwareConfig, ProcessingConfig,
                             config_path, load, load_with_text, CONFIG_ENV)

from svss.compile_notice import announce_compiling

log = logging.getLogger("svss")


def _setup_logging(verbosity: int) -> None:
    level = logging.WARNING if verbosity < 0 else logging.DEBUG if verbosity > 0 else logging.INFO
    logging.basicConfig(level=level, stream=sys.stderr,
                        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
                        datefmt="%H:%M:%S")


def _hardware(args):
    return load_with_text(HardwareConfig, args.hardware or config_path("hardware.toml"))


def _processing(args, default: str = "processing.toml"):
    return load_with_text(ProcessingConfig, args.processing or config_path(default))


def cmd_simulate(args) -> int:
    from sim_device.environment import water_sound_speed
    from sim_device.environment_source import EnvironmentSource
    from sim_device.scene import load_scene
    from svss_daq.acquisition import acquire
    from svss_daq.rawfile import RawRunWriter

    hw = _hardware(args)
    scene = load_scene(args.scene)
    daq = load(DaqConfig, config_path("daq.toml"))
    source = EnvironmentSource(hw, scene)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    with RawRunWriter(args.out, hw, overwrite=args.force,
                      flush_every_pings=daq.recorder.flush_every_pings,
                      flush_interval_s=daq.recorder.flush_interval_s,
                      environment={"sound_speed_indicative": water_sound_speed(scene)},
                      run_attrs={"scene_name": scene.scene.name}) as rec:
        n = acquire(iter(source), rec, None, scene.scene.name, total=source.n_pings)
    print(f"wrote {args.out} ({n} pings)")
    return 0


def cmd_process(args) -> int:
    from svss_proc.run_worker import process_raw

    files = process_raw(args.run, args.out, _processing(args), force=args.force,
                        renavigate=args.renavigate, micronav=args.micronav,
                        autofocus=args.autofocus, sediment_speed=args.sediment_speed)
    for p in files:
        print(p)
    return 0


def cmd_batch(args) -> int:
    from svss_proc.batch.run import BatchError, format_summary, require_dask, run_batch

    try:
        require_dask()                  # before any work; the message names the extra
        summary = run_batch(args.run, args.out, _processing(args),
                            scheduler=args.scheduler, workers=args.workers,
                            force=args.force, renavigate=args.renavigate,
                            micronav=args.micronav, autofocus=args.autofocus,
                            sediment_speed=args.sediment_speed)
    except (ImportError, BatchError) as exc:
        log.error("%s", exc)
        return 2 if isinstance(exc, ImportError) else 1
    print(format_summary(summary))
    return 0


def cmd_worker(args) -> int:
    from svss_daq.config import worker_section
    from svss_proc.worker import serve

    daq = load(DaqConfig, config_path("daq.toml"))
    sub = daq.subscriber
    gap_wait = args.gap_wait if args.gap_wait is not None else sub.gap_wait_s
    files = serve(args.connect, args.out, _hardware(args), _processing(args),
                  idle_timeout_s=args.idle_timeout, receive_hwm=sub.receive_hwm,
                  force=args.force, service=args.service,
                  curve=daq.security, runs=args.runs, gap_wait_s=gap_wait,
                  reorder_pings=sub.reorder_pings,
                  max_sequence_jump=sub.max_sequence_jump,
                  max_listed_gaps=sub.max_listed_gaps, behind=worker_section(daq),
                  timings=args.timings,
                  **({"service_timeout_s": daq.service.request_timeout_s,
                      "max_pings_per_reply": daq.service.max_pings_per_reply,
                      "progress_interval_s": daq.service.progress_interval_s}
                     if daq.service is not None else {}))
    for p in files:
        print(p)
    return 0


def cmd_replay(args) -> int:
    import contextlib
    import time

    from svss_daq.acquisition import acquire
    from svss_daq.ping_gate import PingGate
    from svss_daq.catchup_stores import RawRunStore, ReplayStore
    from svss_daq.ping_service import PingService, service_options
    from svss_daq.publisher import PingPublisher, publisher_end_timeout_s
    from svss_daq.rawfile import RawRunReader

    daq = load(DaqConfig, config_path("daq.toml"))
    store = RawRunStore(args.run)
    replay = ReplayStore(store)
    service_endpoint = args.service
    with contextlib.ExitStack() as stack:
        stack.callback(store.close)
        pub = stack.enter_context(PingPublisher(
            args.endpoint or daq.publisher.endpoint, daq.publisher.send_hwm,
            curve=daq.security, end_timeout_s=publisher_end_timeout_s(daq)))
        service = None
        if service_endpoint:
            service = stack.enter_context(PingService(
                service_endpoint, replay, curve=daq.security,
                **service_options(daq.service)))
        n_total = sum(store.info(r, refresh=False).n_pings for r in store.run_ids())
        print(f"replaying {', '.join(args.run)} ({n_total} pings) on {pub.endpoint}",
              flush=True)
        if service is not None:
            print(f"catch-up service on {service.endpoint}", flush=True)
        pub.wait_for_subscribers(args.subscribers, timeout_s=args.wait)
        t0, first = time.monotonic(), None
        for run_id in store.run_ids():
            replay.begin(run_id)
            readers = [stack.enter_context(RawRunReader(p)) for p in store.paths(run_id)]
            gate = PingGate(readers[0].hardware, name=f"replay of run {run_id}")
            pings = (p for r in readers for p in r if gate.admit(p))
            if args.realtime:
                def paced(pings=pings):
                    nonlocal first
                    for p in pings:
                        first = first if first is not None else p.transmit_time_ns
                        delay = (p.transmit_time_ns - first) * 1e-9 - (time.monotonic() - t0)
                        if delay > 0:
                            time.sleep(delay)
                        yield p
                pings = paced()
            acquire(pings, None, pub, run_id, total=sum(len(r) for r in readers))
            replay.end(run_id)
            if args.realtime:              # the next run starts after a line's turn
                first = None
                t0 = time.monotonic() + args.pause
            time.sleep(args.pause if not args.realtime else 0)
        if service is not None and args.linger:
            log.info("serving the recording on %s for %.0f s more", service.endpoint,
                     args.linger)
            time.sleep(args.linger)
    return 0


def cmd_acquire(args) -> int:
    import json

    from svss_daq.acquire_config import load_acquire
    from svss_daq.daemon import AcquisitionDaemon

    setup = load_acquire(args.config or config_path("acquire.toml"), devices=args.devices,
                         out_dir=args.out, hardware=args.hardware)
    endpoints = {}
    if args.ephemeral_ports:
        endpoints = {k: "tcp://127.0.0.1:*" for k in ("publisher", "service", "status")}
    daemon = AcquisitionDaemon(setup, run_id=args.run_id, endpoints=endpoints)
    try:
        daemon.bind()
        if args.endpoints_out:
            tmp = Path(args.endpoints_out).with_suffix(".tmp")
            tmp.write_text(json.dumps({"run_id": daemon.run_id, **daemon.endpoints}))
            os.replace(tmp, args.endpoints_out)
        print(json.dumps({"run_id": daemon.run_id, **daemon.endpoints}), flush=True)
        daemon.start(wait_subscribers=args.wait_subscribers)
        daemon.run(max_pings=args.pings, duration_s=args.duration)
    except BaseException:
        daemon.stop()
        raise
    for p in daemon.recorder.segments:
        print(p)
    if daemon.failure:
        log.error("run %s failed: %s", daemon.run_id, daemon.failure)
        return 3
    return 0


def cmd_status(args) -> int:
    import json

    from svss_daq.status import StatusSubscriber, format_status

    endpoint = args.connect
    if endpoint is None:
        from svss_daq.acquire_config import AcquireConfig
        endpoint = load(AcquireConfig, args.config or config_path("acquire.toml")
                        ).status.endpoint
    curve = load(DaqConfig, config_path("daq.toml")).security
    with StatusSubscriber(endpoint, curve=curve) as sub:
        if not args.follow:
            s = sub.next(args.timeout)
            if s is None:
                log.error("no status message from %s within %g s (is svss acquire "
                          "running?)", endpoint, args.timeout)
                return 1
            print(json.dumps(s, indent=2) if args.json else format_status(s), flush=True)
            return 0
        # --follow: until SIGINT/SIGTERM, through daemons coming up, runs starting and
        # ending; a quiet stream is said once, then waited on
        quiet, run = False, None
        while True:
            s = sub.next(args.timeout)
            if s is None:
                if not quiet:
                    log.warning("no status from %s for %g s: %s; waiting", endpoint,
                                args.timeout, "no daemon yet" if run is None else
                                f"run {run} is over or its daemon stopped")
                quiet = True
                continue
            if quiet or s.get("run_id") != run:
                log.info("status of run %s from %s", s.get("run_id"), endpoint)
            quiet, run = False, s.get("run_id")
            print(json.dumps(s) if args.json else format_status(s) + "\n", flush=True)


def cmd_view(args) -> int:
    from svss_daq.acquire_config import AcquireConfig, view_section
    from svss.view.server import serve

    cfg = load(AcquireConfig, args.config or config_path("acquire.toml"))
    view = view_section(cfg)
    endpoint = args.connect or cfg.status.endpoint
    curve = load(DaqConfig, config_path("daq.toml")).security
    tiles = Path(args.tiles) if args.tiles else None
    if tiles is not None and not tiles.is_dir():
        log.warning("%s: no such folder yet; the page shows its tiles once the worker "
                    "makes it", tiles)

    def ready(url: str) -> None:
        print(url, flush=True)

    serve(endpoint, tiles, args.address or view.address,
          view.port if args.port is None else args.port, curve=curve, ready=ready)
    return 0


def _print_written(command: str, files) -> int:
    """The files ``svss COMMAND`` wrote, one a line on stdout; the exit status 0."""
    print(f"svss {command} wrote:")
    for p in files:
        print(f"  {p}")
    return 0


def cmd_demo(args) -> int:
    from svss.demo import DemoError, run_demo

    try:
        lead = {} if args.lead is None else {"lead_s": args.lead}
        files = run_demo(Path(args.out), scene=args.scene, hardware=args.hardware,
                         processing=args.processing, force=args.force, **lead)
    except DemoError as exc:
        log.error("%s", exc)
        return 1
    return _print_written("demo", files)


def cmd_inspect(args) -> int:
    import json

    from svss.summary import format_summary, summarise, verify

    if args.verify:
        ok, lines = verify(args.file)
        for line in lines:
            print(line)
        return 0 if ok else (1 if ok is False else 3)
    summary = summarise(args.file)
    print(json.dumps(summary, indent=2) if args.json else format_summary(summary))
    return 0


def _positive(kind):
    """An argparse type: a number of ``kind`` above zero."""
    def convert(text: str):
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not v > 0:
            raise argparse.ArgumentTypeError(f"{text} is not above zero")
        return v
    convert.__name__ = f"positive {kind.__name__}"
    return convert


def _tcp_port(text: str) -> int:
    """An argparse type: a TCP port for the web page, 0 (any free one) to 65535."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port number") from None
    if not 0 <= v <= 65535:
        raise argparse.ArgumentTypeError(f"web port {v} is outside 0-65535")
    return v


def cmd_products(args) -> int:
    from svss_proc.products.run_products import write_run_products

    origin = None
    if args.origin is not None:
        if len(args.origin) not in (2, 3):
            log.error("--origin takes LAT LON [HEIGHT] (deg, deg, m); got %d values",
                      len(args.origin))
            return 2
        origin = (args.origin[0], args.origin[1],
                  args.origin[2] if len(args.origin) == 3 else 0.0)
    if not Path(args.tiles).is_dir():
        log.error("%s: not a folder; svss products takes a run's tile folder (the one "
                  "holding its tile_NNNN.h5 files)", args.tiles)
        return 2
    files = write_run_products(args.tiles, args.out, origin)
    if not files:
        log.error("%s: no tiles with products; nothing written", args.tiles)
        return 1
    return _print_written("products", files)


def cmd_score(args) -> int:
    import json

    from svss.score import format_report, score_tiles

    report = score_tiles(args.tiles, args.scene, args.radius, args.level)
    print(format_report(report))
    if args.out:
        Path(args.out).write_text(json.dumps(report, indent=2))
        log.info("wrote %s", args.out)
    return 0


def cmd_sim_device(args) -> int:
    import time

    from sim_device.device_process import SimDevice

    dev = SimDevice(_hardware(args), args.scene, time_scale=args.time_scale,
                    faults=args.faults, from_run=args.from_run, workers=args.workers,
                    config=args.sim_config, navigation=not args.no_navigation,
                    lead_s=args.lead)
    try:
        dev.start()
        text = dev.devices_toml()
        if args.devices_out:
            tmp = Path(args.devices_out).with_suffix(".tmp")
            tmp.write_text(text)
            os.replace(tmp, args.devices_out)
            log.info("devices configuration written to %s", args.devices_out)
        sys.stdout.write(text)
        sys.stdout.flush()
        from svss_daq.signals import raise_if_stopped
        while True:  # until SIGINT / SIGTERM (KeyboardInterrupt)
            time.sleep(0.5)
            raise_if_stopped()
    finally:
        dev.close()


def cmd_keys(args) -> int:
    from svss_daq.security import generate_keys

    public, secret = generate_keys(args.out, args.name, overwrite=args.force)
    print(f"wrote {public} (public key, mode 0644)")
    print(f"wrote {secret} (secret key, mode 0600: never copy it off this machine)")
    if args.name == "server":
        print(f"on this server, in the [security] table of daq.toml:\n"
              f"  server_secret_key = \"{secret.resolve()}\"\n"
              f"  authorized_clients = \"FOLDER\"  (each client's NAME.key goes there)\n"
              f"copy {public.name} to every client, and there set:\n"
              f"  server_public_key = \"PATH/TO/{public.name}\"")
    else:
        print(f"on this client, in the [security] table of daq.toml:\n"
              f"  client_secret_key = \"{secret.resolve()}\"\n"
              f"copy {public.name} into the server's authorized_clients folder and "
              f"restart the server")
    return 0


def cmd_trade(args) -> int:
    from svss.trade.runner import AREAS, print_table, run_trade

    areas = tuple(a for a in args.areas.split(",") if a)
    bad = [a for a in areas if a not in AREAS]
    if bad or not areas:
        log.error("--areas: expected a comma-separated subset of %s, got %r",
                  ",".join(AREAS), args.areas)
        return 2
    res = run_trade(_hardware(args), _processing(args).value, Path(args.out),
                    quick=args.quick, budget_s=args.budget_s, areas=areas)
    print_table(res)
    return 0


def cmd_reproduce(args) -> int:
    from svss.reproduce.run import run

    path = run(args.out, quick=args.quick, n_seeds=args.seeds, field=not args.no_field)
    print(f"svss reproduce wrote {path}")
    return 0


def _version() -> str:
    """The installed distribution's version ("unknown" when run from a bare checkout)."""
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version("svss")
    except PackageNotFoundError:
        return "unknown (not installed)"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="svss", description="Sediment Volume Search Sonar: "
                                "acquisition, simulation and 3-D imaging.")
    p.add_argument("--version", action="version", version=f"svss {_version()}")
    p.add_argument("-v", "--verbose", action="count", default=0, help="more logging")
    p.add_argument("-q", "--quiet", action="store_true", help="warnings and errors only")
    p.add_argument("--config-dir", help=f"configuration folder (default: ${CONFIG_ENV} or "
                   "the project's config/)")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def force(sp, what):
        sp.add_argument("--force", action="store_true", help=f"replace {what} (refused "
                        "otherwise)")

    def renavigate(sp):
        sp.add_argument("--renavigate", action=argparse.BooleanOptionalAction,
                        default=None, help="recompute every pose from the run's "
                        "recorded NMEA sentences and PD0 ensembles with the smoother "
                        "(refused for a run without them), or image with the poses "
                        "recorded live (--no-renavigate); default: re-navigate where "
                        "the run records them (docs/worker.md, Poses)")
        sp.add_argument("--micronav", action=argparse.BooleanOptionalAction,
                        default=None, help="fuse the re-navigated poses with the "
                        "ping-to-ping increments measured from the echoes' common phase "
                        "centres (docs/micronavigation.md); default: the processing "
                        "configuration's [micronav] enabled")
        sp.add_argument("--autofocus", action=argparse.BooleanOptionalAction,
                        default=None, help="image each run, focus it on its isolated "
                        "responses and image it again with the corrected poses where the "
                        "guard accepts them (docs/autofocus.md); default: the processing "
                        "configuration's [autofocus] enabled")
        sp.add_argument("--sediment-speed", choices=("estimate", "configured"),
                        default=None, help="the sediment's sound speed the tiles are "
                        "imaged with: estimated from the echoes (the speed that focuses "
                        "the buried responses best; the configured one kept where nothing "
                        "below the interface constrains it) or as configured "
                        "(docs/seabed.md); default: the processing configuration's "
                        "[seabed] speed")

    def common(sp, processing=True):
        sp.add_argument("--hardware", help="hardware TOML (default: config/hardware.toml)")
        if processing:
            sp.add_argument("--processing", help="processing TOML "
                            "(default: config/processing.toml)")

    sp = sub.add_parser("demo", help="run the whole chain on the built-in scene, in "
                        "separate processes: sim-device -> acquire -> ZeroMQ -> worker -> "
                        "tiles and PNGs")
    sp.add_argument("--out", required=True, help="output folder")
    sp.add_argument("--scene", help="scene TOML (default: config/scenes/demo_seabed.toml)")
    sp.add_argument("--lead", type=float, default=None, metavar="S",
                    help="simulated seconds before the track's first ping, for the "
                    "acquisition to start (default 12; a shorter lead on a busy machine "
                    "can miss the first pings and their targets: the demo warns)")
    force(sp, "the demo's earlier outputs in --out")
    common(sp)
    sp.set_defaults(func=cmd_demo)

    sp = sub.add_parser("acquire", help="the acquisition daemon: drive the sonar and the "
                        "navigation, record every ping, publish pings and status")
    sp.add_argument("--config", default=None, help="acquisition TOML (default: "
                    "config/acquire.toml)")
    sp.add_argument("--devices", help="devices TOML replacing the one the acquisition "
                    "TOML names (e.g. what svss sim-device printed)")
    sp.add_argument("--out", help="raw-run folder replacing run.out_dir")
    sp.add_argument("--hardware", help="hardware TOML replacing run.hardware")
    sp.add_argument("--run-id", help="run id (default: run.name and the UTC start time)")
    sp.add_argument("--pings", type=_positive(int), default=None,
                    help="stop once this many pings were delivered (pings delivered "
                    "beside the last one are recorded too)")
    sp.add_argument("--duration", type=_positive(float), default=None,
                    help="stop after this many seconds")
    sp.add_argument("--ephemeral-ports", action="store_true", help="bind the publisher, "
                    "catch-up service and status stream to free loopback ports")
    sp.add_argument("--endpoints-out", help="write the bound endpoints (JSON) here")
    sp.add_argument("--wait-subscribers", type=int, default=0, help="start pinging only "
                    "when this many subscribers are on the ping stream")
    sp.set_defaults(func=cmd_acquire)

    sp = sub.add_parser("status", help="print the acquisition daemon's status")
    sp.add_argument("--connect", help="status endpoint (default: acquire.toml's)")
    sp.add_argument("--config", help="acquisition TOML naming the status endpoint")
    sp.add_argument("--timeout", type=float, default=5.0,
                    help="seconds to wait for a status (--follow: before saying none came)")
    sp.add_argument("--follow", action="store_true",
                    help="keep printing, waiting for a daemon and across runs, until "
                    "interrupted")
    sp.add_argument("--json", action="store_true",
                    help="print the status as JSON (--follow: one object a line)")
    sp.set_defaults(func=cmd_status)

    sp = sub.add_parser("view", help="serve the operator's live web page (alarms, "
                        "status, survey map, tiles and contacts) on loopback")
    sp.add_argument("--tiles", help="the tile worker's output folder (svss worker --out)")
    sp.add_argument("--connect", help="status endpoint (default: acquire.toml's)")
    sp.add_argument("--config", help="acquisition TOML naming the status endpoint and "
                    "the page's [view] address and port")
    sp.add_argument("--address", help="address to serve on, replacing [view] address")
    sp.add_argument("--port", type=_tcp_port, help="web port to serve on, replacing "
                    "[view] port (0: a free port; the URL is printed)")
    sp.set_defaults(func=cmd_view)

    sp = sub.add_parser("simulate", help="simulate a scene into a raw-run file")
    sp.add_argument("--scene", required=True, help="scene TOML")
    sp.add_argument("--out", required=True, help="raw-run HDF5 file to write")
    force(sp, "an existing --out file")
    common(sp, processing=False)
    sp.set_defaults(func=cmd_simulate)

    sp = sub.add_parser("process", help="image a raw-run file into tiles")
    sp.add_argument("run", help="raw-run HDF5 file")
    sp.add_argument("--out", required=True, help="output folder")
    sp.add_argument("--processing", help="processing TOML (default: config/processing.toml)")
    force(sp, "tiles and manifest of an earlier run in --out")
    renavigate(sp)
    sp.set_defaults(func=cmd_process)

    sp = sub.add_parser("batch", help="reprocess raw runs into tiles on Dask distributed, "
                        "one task per tile (docs/batch.md)")
    sp.add_argument("run", nargs="+", help="raw-run HDF5 file(s) (a run's segment files "
                    "together), on a path every worker sees")
    sp.add_argument("--out", required=True, help="output folder (OUT/RUN/tile_NNNN.h5, "
                    "OUT/survey_index.csv); a rerun skips the tiles already there")
    sp.add_argument("--processing", help="processing TOML (default: config/processing.toml)")
    sp.add_argument("--scheduler", help="Dask scheduler address, e.g. tcp://HOST:8786 "
                    "(default: a local cluster of --workers processes)")
    sp.add_argument("--workers", type=int, default=None, help="worker processes of the "
                    "local cluster (default: the CPU count)")
    force(sp, "tiles of an earlier batch made with another processing configuration")
    renavigate(sp)
    sp.set_defaults(func=cmd_batch)

    sp = sub.add_parser("worker", help="image pings received over ZeroMQ")
    sp.add_argument("--connect", required=True, help="publisher endpoint")
    sp.add_argument("--out", required=True, help="output folder")
    sp.add_argument("--idle-timeout", type=float, default=None,
                    help="finish after this many seconds without a message")
    sp.add_argument("--service", help="catch-up service endpoint (svss acquire / svss "
                    "replay): missed pings are fetched from the recording and a killed "
                    "worker resumes (docs/worker.md)")
    sp.add_argument("--runs", type=int, default=None,
                    help="exit after this many runs have ended (default: stay up)")
    sp.add_argument("--gap-wait", type=float, default=None,
                    help="without --service: seconds to wait for a missing ping before "
                    "skipping it (default: daq.toml subscriber.gap_wait_s)")
    sp.add_argument("--timings", metavar="FILE", help="write per run the CPU and wall "
                    "time of each stage, every ping's lag behind the sonar and every "
                    "tile's times as JSON to FILE (benchmarks/bench_live.py)")
    force(sp, "tiles, manifest and run folders of an earlier run in --out (without it, "
          "a folder holding this worker's journal is resumed)")
    common(sp)
    sp.set_defaults(func=cmd_worker)

    sp = sub.add_parser("replay", help="publish recorded raw runs as ping messages and "
                        "serve them to catch-up clients")
    sp.add_argument("run", nargs="+", help="raw-run HDF5 file(s) (a run's segment files "
                    "together)")
    sp.add_argument("--endpoint", help="endpoint to bind (default: config/daq.toml)")
    sp.add_argument("--service", help="also serve the recording to catch-up clients "
                    "(svss worker --service) on this endpoint (daq.toml [service] "
                    "endpoint is the usual one)")
    sp.add_argument("--linger", type=float, default=0.0, help="keep serving the "
                    "recording this many seconds after the last run")
    sp.add_argument("--pause", type=float, default=0.0, help="seconds between runs")
    sp.add_argument("--subscribers", type=int, default=1, metavar="N",
                    help="start publishing once N subscribers have subscribed (default 1)")
    sp.add_argument("--realtime", action="store_true", help="pace pings at their recorded "
                    "transmit times")
    sp.add_argument("--wait", type=float, default=60.0,
                    help="seconds to wait for a subscriber")
    sp.set_defaults(func=cmd_replay)

    sp = sub.add_parser("inspect", help="summarise a tile file or a raw-run file")
    sp.add_argument("file", help="tile or raw-run HDF5 file")
    sp.add_argument("--json", action="store_true", help="print the summary as JSON")
    sp.add_argument("--verify", action="store_true",
                    help="read the whole file against its checksums: exit 0 sound, 1 "
                         "damaged (each damaged ping or dataset named), 3 written without "
                         "checksums")
    sp.set_defaults(func=cmd_inspect)

    sp = sub.add_parser("products", help="(re)write a run's products from its tiles: "
                        "contacts (CSV, GeoJSON with latitude/longitude) and the MIP mosaic "
                        "(docs/products.md)")
    sp.add_argument("tiles", help="folder of a run's tile_*.h5 files")
    sp.add_argument("--out", help="output folder (default: the tiles' folder)")
    sp.add_argument("--origin", type=float, nargs="+", metavar="VALUE",
                    help="survey origin LAT LON [HEIGHT] (deg, deg, m) for tiles whose "
                    "pings carried no geodetic position (simulated runs)")
    sp.set_defaults(func=cmd_products)

    sp = sub.add_parser("score", help="score a folder of tiles' detections against a "
                        "simulated scene's targets")
    sp.add_argument("tiles", help="folder of tile_*.h5 files")
    sp.add_argument("--scene", required=True, help="scene TOML the run was simulated from")
    sp.add_argument("--radius", type=float, default=None, help="match radius, m (default: "
                    "products.detection.match_radius_m of the tiles' processing)")
    sp.add_argument("--out", help="also write the report as JSON to this file")
    sp.add_argument("--level", choices=("run", "tile"), default="run",
                    help="score the run's contacts (filtered across tiles; default) or "
                    "every tile's own detections")
    sp.set_defaults(func=cmd_score)

    sp = sub.add_parser("sim-device", help="serve a simulated sonar (sequencer on a pty, "
                        "digitiser on TCP) and navigation (DVL, GPS on ptys) for the "
                        "acquisition drivers; prints their devices configuration")
    sp.add_argument("--scene", required=True, help="scene TOML")
    sp.add_argument("--time-scale", type=float, default=1.0,
                    help="simulated seconds per host second (default 1: real time)")
    sp.add_argument("--faults", help="faults TOML (docs/sim_device.md)")
    sp.add_argument("--from-run", help="stream this raw run (svss simulate) instead of "
                    "synthesising")
    sp.add_argument("--devices-out", help="also write the devices configuration here")
    sp.add_argument("--workers", type=int, default=None, help="synthesis worker processes "
                    "(default: sim-device.toml sonar.workers; 0: chosen from the cost)")
    sp.add_argument("--sim-config", help="simulated device TOML "
                    "(default: config/sim-device.toml)")
    sp.add_argument("--no-navigation", action="store_true", help="sonar only: no DVL, GPS")
    sp.add_argument("--lead", type=float, default=0.0, help="start the simulated clock "
                    "this many seconds before the track's start: the instruments run "
                    "meanwhile and a sequencer started within the lead pings from the "
                    "track's first ping")
    common(sp, processing=False)
    sp.set_defaults(func=cmd_sim_device)

    sp = sub.add_parser("keys", help="generate a ZeroMQ CURVE key pair for the server "
                        "(--name server) or a client (docs/security.md)")
    sp.add_argument("--out", required=True, help="folder to write NAME.key (public) and "
                    "NAME.key_secret (secret, mode 0600) into")
    sp.add_argument("--name", default="server", help="key pair name: 'server' (default) "
                    "or a client's name")
    force(sp, "an existing key pair of that name")
    sp.set_defaults(func=cmd_keys)

    sp = sub.add_parser("trade", help="measure speed against accuracy of every imaging, "
                        "simulation and normalisation option on this machine "
                        "(docs/trade.md)")
    sp.add_argument("--out", required=True, help="folder for trade.csv, trade.json, "
                    "trade.md and pareto_<area>.png")
    sp.add_argument("--quick", action="store_true", help="tiny workloads (seconds)")
    sp.add_argument("--budget-s", type=float, default=15.0, help="real-time budget per "
                    "tile, s (default 15: a 15 m tile at 1 m/s)")
    sp.add_argument("--areas", default="imaging,simulation,normalisation",
                    help="comma-separated areas to measure")
    common(sp)
    sp.set_defaults(func=cmd_trade)

    sp = sub.add_parser("reproduce", help="simulate and image the seed paper's scenes, "
                        "measure its statements and write a report with figures "
                        "(docs/reproduce.md)")
    sp.add_argument("--out", required=True, help="output folder (report.md, PNGs, "
                    "results.json)")
    sp.add_argument("--quick", action="store_true", help="shortened run (minutes)")
    sp.add_argument("--seeds", type=int, default=None, help="seabed realisations of the "
                    "seed's configuration (default 5; quick: 2)")
    sp.add_argument("--no-field", action="store_true", help="leave out the test field")
    sp.set_defaults(func=cmd_reproduce)
    return p


def _stop_on_sigterm() -> None:
    """SIGTERM stops a command as SIGINT does (KeyboardInterrupt: files are flushed and
    closed on the way out)."""
    from svss_daq.signals import clear_stop, quiet_unraisable, stop_handler
    clear_stop()
    sys.unraisablehook = quiet_unraisable
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, stop_handler)
        # a command started in the background by a shell inherits SIGINT ignored, and
        # Python then leaves it ignored: an explicit SIGINT must still stop it
        signal.signal(signal.SIGINT, stop_handler)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    _setup_logging(-1 if args.quiet else args.verbose)
    if args.config_dir:
        os.environ[CONFIG_ENV] = str(Path(args.config_dir).resolve())
    _stop_on_sigterm()
    announce_compiling()
    try:
        return args.func(args)
    except KeyboardInterrupt as exc:
        log.warning("svss %s stopped by %s; what was done is flushed", args.command,
                    exc.args[0] if exc.args else "SIGINT")
        return 130
    except SystemError as exc:
        # a stop signal that landed inside a C extension's callback (numba loading a
        # cached kernel) comes out as its SystemError, caused by the KeyboardInterrupt
        from svss_daq.signals import stop_cause
        ki = stop_cause(exc)
        if ki is None:
            raise
        log.warning("svss %s stopped by %s (inside %s); what was done is flushed",
                    args.command, ki.args[0] if ki.args else "SIGINT", type(exc).__name__)
        return 130
    except (ConfigError, FileNotFoundError, FileExistsError, ValueError, TimeoutError,
            OSError) as exc:
        log.error("%s", exc)
        return 2
