"""The demo: the whole boat-side chain on a built-in scene, in separate processes.

``svss sim-device`` serves the simulated sonar and navigation on their real protocols;
``svss acquire`` drives them, records every ping (``runs/``) and publishes it; ``svss
worker`` subscribes (catching up from the recording if it misses a ping), images the
pings and writes tiles and quicklooks (``tiles/<run id>/``). Each process logs to
``logs/``; the worker's progress is shown.
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
from svss_proc.products.run_products import (CONTACTS_CSV, CONTACTS_GEOJSON, MOSAIC_H5,
                                           MOSAIC_PNG)
from svss_proc.worker import prepare_output_dir, run_folder_name

log = logging.getLogger(__name__)

DEMO_SCENE = "scenes/demo.toml"
DEMO_PROCESSING = "processing-demo.toml"
DEMO_RUN = "demo"
#: simulated seconds the device's clock runs before the track starts: the daemon and the
#: worker start meanwhile, and the sequencer's first ping is then the track's first
DEMO_LEAD_S = 12.0
STARTUP_S = 120.0


def _svss(*args: str) -> list[str]:
    return [sys.executable, "-m", "svss", *args]


def _wait_for_file(path: Path, proc: subprocess.Popen, what: str, log_path: Path,
                   timeout_s: float = STARTUP_S) -> None:
    deadline = time.monotonic() + timeout_s
    while not path.exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            tail = log_path.read_text(errors="replace")[-2000:] if log_path.exists() else ""
            raise RuntimeError(f"{what} did not start (exit code {proc.poll()}); its log "
                               f"{log_path} ends:\n{tail}")
        time.sleep(0.05)


def stop_process(proc: subprocess.Popen | None, timeout_s: float = 20.0) -> None:
    """SIGTERM a child process and wait for it (SIGKILL after ``timeout_s``)."""
    if proc is None or proc.poll() is not None:
        return
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


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
    try:
        with open(logs / "sim-device.log", "wb") as err:
            procs["sim-device"] = subprocess.Popen(
                _svss("sim-device", "--scene", str(scene_path), "--hardware", str(hw_path),
                      "--devices-out", str(devices), "--lead", str(lead_s)),
                stdout=subprocess.DEVNULL, stderr=err)
        _wait_for_file(devices, procs["sim-device"], "svss sim-device",
                       logs / "sim-device.log")
        log.info("simulated device up (logs/sim-device.log); starting the acquisition")
        with open(logs / "acquire.log", "wb") as err:
            procs["acquire"] = subprocess.Popen(
                _svss("acquire", "--config", str(config_path("acquire.toml")), "--hardware",
                      str(hw_path), "--devices", str(devices), "--out", str(runs),
                      "--run-id", DEMO_RUN, "--pings",
                      str(n_pings), "--ephemeral-ports", "--endpoints-out", str(endpoints),
                      "--wait-subscribers", "1"),
                stdout=subprocess.DEVNULL, stderr=err)
        _wait_for_file(endpoints, procs["acquire"], "svss acquire", logs / "acquire.log")
        ep = json.loads(endpoints.read_text())
        log.info("acquisition bound %s; starting the worker", ep)
        procs["worker"] = subprocess.Popen(
            _svss("worker", "--connect", ep["publisher"], "--service", ep["service"],
                  "--out", str(tiles), "--hardware", str(hw_path), "--processing",
                  str(proc_path), "--runs", "1", "--idle-timeout", str(worker_timeout_s))
            + (["--force"] if force else []), stdout=subprocess.DEVNULL)
        rc = procs["worker"].wait(timeout=STARTUP_S + lead_s + worker_timeout_s)
        if rc != 0:
            raise RuntimeError(f"the worker process failed with exit code {rc}")
        # the run is over (the worker saw its end); the daemon may still be keeping its
        # catch-up service up for late workers: stop it
        stop_process(procs["acquire"])
        rc = procs["acquire"].returncode
        if rc not in (0, 130):                  # 130: stopped while closing, all flushed
            raise RuntimeError(f"svss acquire failed with exit code {rc}; see "
                               f"{logs / 'acquire.log'}")
    finally:
        for name in ("worker", "acquire", "sim-device"):
            stop_process(procs.get(name))
    first = re.search(r"first ping is track ping (\d+)",
                      (logs / "sim-device.log").read_text(errors="replace"))
    if first and int(first.group(1)) != 0:
        log.warning("the acquisition started %s pings into the scene's track (it took "
                    "longer than the %.0f s lead to start): the first targets may be "
                    "missing", first.group(1), lead_s)
    folder = tiles / run_folder_name(DEMO_RUN)
    manifest = json.loads((folder / "manifest.json").read_text())
    run_products = [folder / n for n in (CONTACTS_CSV, CONTACTS_GEOJSON, MOSAIC_PNG, MOSAIC_H5)
                    if (folder / n).exists()]
    return (sorted(runs.glob(f"{DEMO_RUN}_*.h5")) + [folder / n for n in manifest["files"]]
            + run_products)
