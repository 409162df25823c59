"""The demo: the whole boat-side chain on a built-in scene, in separate processes.

``svss sim-device`` serves the simulated sonar and navigation on their real protocols;
``svss acquire`` drives them, records every ping (``runs/``) and publishes it; ``svss
worker`` subscribes (catching up from the recording if it misses a ping), images the
pings and writes tiles and quicklooks (``tiles/<run id>/``). Each process logs to
``logs/``; the worker's progress is shown.

Each process runs in its own session: Ctrl-C (or SIGTERM) reaches the demo alone, which
then stops each process once, in order -- the worker first (it writes its open tiles
and its manifest, marked incomplete), then the acquisition (it closes the recording with
its summary), then the simulated device -- waiting for each, and says what was written;
a process that did not finish its writing is named (:class:`DemoError`).
"""

from __future__ import annotations

import json
import logging
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

from sim_device.scene import load_scene
from svss_daq.config import config_path
from svss_daq.rawfile import RawFileError, RawRunReader
from svss_daq.signals import stop_once
from svss_proc.products.run_products import (CONTACTS_CSV, CONTACTS_GEOJSON, CONTACTS_GPKG,
                                           MOSAIC_H5, MOSAIC_PNG, MOSAIC_TIF)
from svss_proc.run_folder import prepare_output_dir, run_folder_name
from svss_proc.tiles import finished_tile_paths

log = logging.getLogger(__name__)

DEMO_SCENE = "scenes/demo_seabed.toml"
DEMO_PROCESSING = "processing-demo.toml"
DEMO_RUN = "demo"
#: simulated seconds the device's clock runs before the track starts: the daemon and the
#: worker start meanwhile, and the sequencer's first ping is then the track's first
DEMO_LEAD_S = 12.0
STARTUP_S = 120.0
#: a stopped process's time to write what it holds before it is killed, s: the worker's
#: open tiles (products and quicklooks, a few seconds each on a loaded machine); the
#: daemon's recording (drain, flush, summary; its catch-up service lingers at most
#: catch_up.linger_s after the worker's last request); the simulated device
STOP_S = {"worker": 300.0, "acquire": 120.0, "sim-device": 20.0}


class DemoError(RuntimeError):
    """A process of the demo failed or did not finish; the message says which."""


def _svss(*args: str) -> list[str]:
    return [sys.executable, "-m", "svss", *args]


def _wait_for_file(path: Path, proc: subprocess.Popen, what: str, log_path: Path,
                   timeout_s: float = STARTUP_S) -> None:
    deadline = time.monotonic() + timeout_s
    while not path.exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            tail = log_path.read_text(errors="replace")[-2000:] if log_path.exists() else ""
            raise DemoError(f"{what} did not start (exit code {proc.poll()}); its log "
                            f"{log_path} ends:\n{tail}")
        time.sleep(0.05)


def stop_process(proc: subprocess.Popen | None, timeout_s: float = 20.0,
                 sig: int = signal.SIGTERM) -> bool:
    """Send ``sig`` to a child process and wait for it (SIGKILL after ``timeout_s``);
    False when it had to be killed."""
    if proc is None or proc.poll() is not None:
        return True
    proc.send_signal(sig)
    try:
        proc.wait(timeout_s)
        return True
    except subprocess.TimeoutExpired:
        log.error("process %d still running %.0f s after %s: killed", proc.pid, timeout_s,
                  signal.Signals(sig).name)
        proc.kill()
        proc.wait()
        return False


def _start(args: list[str], **kw) -> subprocess.Popen:
    """A child in its own session: a terminal's Ctrl-C reaches the demo only, which
    stops its children one by one (:func:`_stop_all`)."""
    return subprocess.Popen(args, start_new_session=True, **kw)


def _stop_all(procs: dict[str, subprocess.Popen]) -> list[str]:
    """Stop the demo's processes once each, the worker first (SIGINT: each writes what
    it holds); the names of those that had to be killed."""
    killed = []
    for name in ("worker", "acquire", "sim-device"):
        if not stop_process(procs.get(name), STOP_S[name], signal.SIGINT):
            killed.append(name)
    return killed


def _after_stop(procs: dict[str, subprocess.Popen], killed: list[str], runs: Path,
                tiles: Path, logs: Path, why: str) -> None:
    """Say what the stopped demo wrote; :class:`DemoError` when a process did not
    finish writing (killed, failed, no manifest, a recording not closed)."""
    problems = [f"{n} killed after {STOP_S[n]:.0f} s" for n in killed]
    rc = {n: p.returncode for n, p in procs.items()}
    # 130: stopped by the signal; -SIGINT: it came as the process was exiting anyway
    if "worker" in rc and "worker" not in killed and rc["worker"] not in (
            0, 130, -signal.SIGINT):
        problems.append(f"worker exit code {rc['worker']}")
    folder = tiles / run_folder_name(DEMO_RUN)
    if "worker" in procs and not (tiles / "manifest.json").is_file():
        problems.append(f"the worker wrote no manifest in {tiles}")
    for seg in sorted(runs.glob(f"{DEMO_RUN}_*.h5")) if "acquire" in procs else ():
        try:
            with RawRunReader(seg) as r:
                summary = r.summary
        except RawFileError as exc:
            summary, trouble = None, str(exc)
        else:
            trouble = "no acquisition summary: not closed"
        if summary is None:        # (``why``, the stop's cause, is not this file's)
            problems.append(f"{seg}: {trouble} (acquire exit code {rc.get('acquire')}; "
                            f"see {logs / 'acquire.log'})")
    if problems:
        raise DemoError(f"svss demo stopped by {why}, but not cleanly: "
                        + "; ".join(problems))
    n = len(finished_tile_paths(folder)) if folder.is_dir() else 0
    log.info("svss demo stopped by %s: the worker wrote %d tile(s) and its manifest "
             "(incomplete) in %s, the acquisition closed the recording", why, n, folder)


def run_demo(out: Path, scene: str | None = None, hardware: str | None = None,
             processing: str | None = None, worker_timeout_s: float = 600.0,
             force: bool = False, lead_s: float = DEMO_LEAD_S) -> list[Path]:
    """Run the demo into ``out``; return every file written (raw runs first). An earlier
    demo's outputs there are refused unless ``force``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    hw_path = Path(hardware or config_path("hardware.toml")).resolve()
    proc_path = Path(processing or config_path(DEMO_PROCESSING)).resolve()
    scene_path = Path(scene or config_path(DEMO_SCENE)).resolve()
    n_pings = load_scene(scene_path).track.n_pings
    runs, tiles, logs = out / "runs", out / "tiles", out / "logs"
    old = sorted(runs.glob(f"{DEMO_RUN}_*.h5")) if runs.exists() else []
    if old and not force:
        raise FileExistsError(f"{old[0]} exists (an earlier demo); pass --force to replace "
                              "the demo's outputs")
    for p in old:
        p.unlink()
    if force and (tiles / run_folder_name(DEMO_RUN)).exists():
        shutil.rmtree(tiles / run_folder_name(DEMO_RUN))
    prepare_output_dir(tiles, force)
    logs.mkdir(exist_ok=True)
    devices, endpoints = out / "devices.toml", out / "endpoints.json"
    for p in (devices, endpoints):
        p.unlink(missing_ok=True)
    procs: dict[str, subprocess.Popen] = {}
    interrupted: KeyboardInterrupt | None = None
    with stop_once("stopping the demo's processes"):
        try:
            _run_chain(procs, scene_path, hw_path, proc_path, runs, tiles, logs, devices,
                       endpoints, n_pings, worker_timeout_s, force, lead_s)
        except KeyboardInterrupt as exc:
            interrupted = exc
        finally:
            killed = _stop_all(procs)
        if interrupted is not None:
            _after_stop(procs, killed, runs, tiles, logs,
                        interrupted.args[0] if interrupted.args else "SIGINT")
            raise interrupted
    first = re.search(r"first ping is track ping (\d+)",
                      (logs / "sim-device.log").read_text(errors="replace"))
    if first and int(first.group(1)) != 0:
        log.warning("the acquisition started %s pings into the scene's track (it took "
                    "longer than the %.0f s lead to start): the first targets may be "
                    "missing", first.group(1), lead_s)
    folder = tiles / run_folder_name(DEMO_RUN)
    manifest = json.loads((folder / "manifest.json").read_text())
    run_products = [folder / n for n in (CONTACTS_CSV, CONTACTS_GEOJSON, MOSAIC_PNG, MOSAIC_H5,
                                         MOSAIC_TIF, CONTACTS_GPKG)
                    if (folder / n).exists()]
    return (sorted(runs.glob(f"{DEMO_RUN}_*.h5")) + [folder / n for n in manifest["files"]]
            + run_products)


def _run_chain(procs: dict[str, subprocess.Popen], scene_path: Path, hw_path: Path,
               proc_path: Path, runs: Path, tiles: Path, logs: Path, devices: Path,
               endpoints: Path, n_pings: int, worker_timeout_s: float, force: bool,
               lead_s: float) -> None:
    """Start the three processes (into ``procs``) and wait for the worker to finish the
    run; the caller stops them."""
    # the daemon compiles the navigation filters before its sonar pings (seconds in a
    # fresh environment: 13 s there once ate the whole lead and the first target); here,
    # before the device's clock runs, into numba's cache that the daemon then loads
    from svss_daq.nav.kalman import warm_up
    t0 = time.monotonic()
    warm_up()
    log.info("navigation filters ready (%.1f s)", time.monotonic() - t0)
    with open(logs / "sim-device.log", "wb") as err:
        procs["sim-device"] = _start(
            _svss("sim-device", "--scene", str(scene_path), "--hardware", str(hw_path),
                  "--devices-out", str(devices), "--lead", str(lead_s)),
            stdout=subprocess.DEVNULL, stderr=err)
    _wait_for_file(devices, procs["sim-device"], "svss sim-device",
                   logs / "sim-device.log")
    log.info("simulated device up (logs/sim-device.log); starting the acquisition")
    with open(logs / "acquire.log", "wb") as err:
        procs["acquire"] = _start(
            _svss("acquire", "--config", str(config_path("acquire.toml")), "--hardware",
                  str(hw_path), "--devices", str(devices), "--out", str(runs),
                  "--run-id", DEMO_RUN, "--pings",
                  str(n_pings), "--ephemeral-ports", "--endpoints-out", str(endpoints),
                  "--wait-subscribers", "1"),
            stdout=subprocess.DEVNULL, stderr=err)
    _wait_for_file(endpoints, procs["acquire"], "svss acquire", logs / "acquire.log")
    ep = json.loads(endpoints.read_text())
    log.info("acquisition bound %s; starting the worker", ep)
    procs["worker"] = _start(
        _svss("worker", "--connect", ep["publisher"], "--service", ep["service"],
              "--out", str(tiles), "--hardware", str(hw_path), "--processing",
              str(proc_path), "--runs", "1", "--idle-timeout", str(worker_timeout_s))
        + (["--force"] if force else []), stdout=subprocess.DEVNULL)
    rc = procs["worker"].wait(timeout=STARTUP_S + lead_s + worker_timeout_s)
    if rc != 0:
        raise DemoError(f"the worker process failed with exit code {rc}")
    # the run is over (the worker saw its end); the daemon may still be keeping its
    # catch-up service up for late workers: stop it
    stop_process(procs["acquire"], STOP_S["acquire"])
    rc = procs["acquire"].returncode
    if rc not in (0, 130):                  # 130: stopped while closing, all flushed
        raise DemoError(f"svss acquire failed with exit code {rc}; see "
                        f"{logs / 'acquire.log'}")
