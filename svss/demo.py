"""The demo: the whole chain on a built-in scene.

The simulated device synthesises pings; the acquisition loop records them to
``run.h5`` and publishes them over ZeroMQ; a worker in another process subscribes,
images them and writes tiles and quicklooks.
"""

from __future__ import annotations

import json
import logging
import subprocess
import sys
from pathlib import Path

from sim_device.environment import water_sound_speed
from sim_device.environment_source import EnvironmentSource
from sim_device.scene import load_scene
from svss_daq.acquisition import acquire
from svss_daq.config import DaqConfig, HardwareConfig, config_path, load, load_with_text
from svss_daq.publisher import PingPublisher
from svss_daq.rawfile import RawRunWriter
from svss_proc.worker import prepare_output_dir

log = logging.getLogger(__name__)

DEMO_SCENE = "scenes/demo.toml"
DEMO_PROCESSING = "processing-demo.toml"


def run_demo(out: Path, scene: str | None = None, hardware: str | None = None,
             processing: str | None = None, worker_timeout_s: float = 600.0,
             force: bool = False) -> list[Path]:
    """Run the demo into ``out``; return every file written (raw run first). An earlier
    run's outputs there are refused unless ``force``."""
    out.mkdir(parents=True, exist_ok=True)
    hw_path = Path(hardware or config_path("hardware.toml")).resolve()
    proc_path = Path(processing or config_path(DEMO_PROCESSING)).resolve()
    hw = load_with_text(HardwareConfig, hw_path)
    sc = load_scene(scene or config_path(DEMO_SCENE))
    daq = load(DaqConfig, config_path("daq.toml"))
    source = EnvironmentSource(hw, sc)
    raw = out / "run.h5"
    tiles = out / "tiles"
    if raw.exists() and not force:
        raise FileExistsError(f"{raw} exists (an earlier demo); pass --force to replace "
                              "the demo's outputs")
    prepare_output_dir(tiles, force)
    with PingPublisher("tcp://127.0.0.1:*", daq.publisher.send_hwm) as pub:
        cmd = [sys.executable, "-m", "svss", "worker", "--connect", pub.endpoint,
               "--out", str(tiles), "--hardware", str(hw_path), "--processing",
               str(proc_path), "--idle-timeout", str(worker_timeout_s), "--runs", "1"] + (
                   ["--force"] if force else [])
        log.info("starting worker: %s", " ".join(cmd))
        worker = subprocess.Popen(cmd, stdout=subprocess.DEVNULL)
        try:
            pub.wait_for_subscribers(timeout_s=120.0)
            with RawRunWriter(raw, hw, overwrite=force,
                              flush_every_pings=daq.recorder.flush_every_pings,
                              flush_interval_s=daq.recorder.flush_interval_s,
                              environment={"sound_speed_indicative":
                                           water_sound_speed(sc)},
                              run_attrs={"scene_name": sc.scene.name}) as rec:
                acquire(iter(source), rec, pub, sc.scene.name, total=source.n_pings)
            log.info("all %d pings recorded and published; waiting for the worker",
                     source.n_pings)
            rc = worker.wait(timeout=worker_timeout_s)
        finally:
            if worker.poll() is None:
                worker.kill()
                worker.wait()
    if rc != 0:
        raise RuntimeError(f"the worker process failed with exit code {rc}")
    manifest = json.loads((tiles / "manifest.json").read_text())
    return [raw] + [tiles / name for name in manifest["files"]]
