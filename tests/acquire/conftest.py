"""``svss sim-device`` and ``svss acquire`` as real processes: pseudo-terminals, loopback
TCP and ZeroMQ, raw-run files on disk."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.sim_devices.conftest import SimDeviceProcess, stop_process

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "config"
DEMO = CONFIG / "scenes" / "demo.toml"
STARTUP_S = 60.0


def acquire_toml(tmp: Path, **sections) -> Path:
    """An acquisition TOML in ``tmp`` naming the project's configurations; ``sections``
    override keys, e.g. ``rotation={"max_file_mib": 2}``."""
    tables = {
        "run": {"hardware": str(CONFIG / "hardware.toml"),
                "devices": str(CONFIG / "devices.toml"), "daq": str(CONFIG / "daq.toml"),
                "out_dir": str(tmp / "runs"), "name": "test"},
        "rotation": {"max_file_mib": 2048.0, "max_file_s": 600.0},
        "status": {"endpoint": "tcp://127.0.0.1:*", "interval_s": 0.2,
                   "rate_window_s": 5.0},
        "disk": {"min_free_mib": 0.0},
        "pairing": {"transmit_wait_s": 0.3, "start_timeout_s": 20.0, "drain_s": 1.0},
        "navigation": {"history_s": 60.0, "wait_s": 0.5},
        "catch_up": {"linger_s": 15.0, "max_linger_s": 120.0}}
    for k, v in sections.items():
        tables.setdefault(k, {}).update(v)
    lines = []
    for name, table in tables.items():
        lines.append(f"[{name}]")
        lines += [f"{k} = {json.dumps(v)}" for k, v in table.items()]
    path = tmp / "acquire.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def local_setup(tmp: Path, *, links: bool = False, recorder: dict | None = None,
                **sections):
    """The acquisition setup of :func:`acquire_toml` (``sections`` as there) for a
    daemon's parts run in the test's process: without the DVL and GPS links unless
    ``links`` (the project's devices.toml otherwise), daq.toml's ``[recorder]`` keys
    replaced by ``recorder``."""
    from svss_daq.acquire_config import load_acquire
    text = (CONFIG / "devices.toml").read_text()
    if not links:
        keep, skip = [], False
        for line in text.splitlines():
            if line.startswith("["):
                skip = line.strip() in ("[dvl]", "[gps]")
            if not skip:
                keep.append(line)
        text = "\n".join(keep) + "\n"
    devices = tmp / "local-devices.toml"
    devices.write_text(text)
    daq = CONFIG / "daq.toml"
    if recorder:
        lines = daq.read_text().splitlines()
        at = lines.index("[recorder]")
        for k, v in recorder.items():
            i = next(j for j in range(at, len(lines)) if lines[j].startswith(f"{k} ="))
            lines[i] = f"{k} = {json.dumps(v)}"
        daq = tmp / "local-daq.toml"
        daq.write_text("\n".join(lines) + "\n")
    sections.setdefault("run", {})["daq"] = str(daq)
    return load_acquire(acquire_toml(tmp, **sections), devices=devices)


class AcquireProcess:
    """``svss acquire`` as a subprocess against a simulated device; :attr:`endpoints` is
    what it bound (publisher, service, status) and its run id."""

    def __init__(self, tmp: Path, devices: Path, *extra: str, run_id: str = "run1",
                 config: Path | None = None, preexec_fn=None, wait: bool = True,
                 ephemeral: bool = True):
        self.tmp = tmp
        self.ep_file = tmp / f"{run_id}.endpoints.json"
        self.log = tmp / f"{run_id}.acquire.log"
        self.out = tmp / "runs"
        self.run_id = run_id
        cmd = [sys.executable, "-m", "svss", "acquire", "--config",
               str(config or acquire_toml(tmp)), "--devices", str(devices), "--out",
               str(self.out), "--run-id", run_id,
               *(["--ephemeral-ports"] if ephemeral else []), "--endpoints-out",
               str(self.ep_file), *extra]
        with open(self.log, "wb") as err:
            self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, cwd=ROOT,
                                         preexec_fn=preexec_fn)
        self.endpoints: dict = {}
        if wait:
            self.wait_started()

    def wait_started(self) -> dict:
        deadline = time.monotonic() + STARTUP_S
        while not self.ep_file.exists():
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.stop()
                raise RuntimeError(f"svss acquire did not start (rc {self.proc.returncode})"
                                   f":\n{self.logs()[-3000:]}")
            time.sleep(0.05)
        self.endpoints = json.loads(self.ep_file.read_text())
        return self.endpoints

    def logs(self) -> str:
        return self.log.read_text(errors="replace")

    def wait(self, timeout_s: float = 120.0) -> int:
        try:
            self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.stop()
            raise AssertionError(f"svss acquire still running after {timeout_s} s:\n"
                                 + self.logs()[-3000:]) from None
        return self.proc.returncode

    def stop(self, sig: int = signal.SIGTERM, timeout_s: float = 20.0) -> int:
        return stop_process(self.proc, sig, timeout_s)

    def files(self) -> list[Path]:
        return sorted(self.out.glob(f"{self.run_id}_*.h5"))


@pytest.fixture
def rig(tmp_path):
    """Start simulated devices and acquisition daemons; stop them all at the end."""
    started: list = []

    class Rig:
        tmp = tmp_path

        def device(self, *extra: str, name: str = "dev") -> SimDeviceProcess:
            d = tmp_path / name
            d.mkdir()
            # synthesis in the device's process (the demo scene costs < 40 ms a ping):
            # no worker processes to start while the first pings are due
            sim = d / "sim-device.toml"
            sim.write_text((CONFIG / "sim-device.toml").read_text().replace(
                "inline_max_load = 0.5", "inline_max_load = 1.0"))
            p = SimDeviceProcess(d, "--sim-config", str(sim), *extra)
            started.append(p)
            return p

        def acquire(self, dev: SimDeviceProcess, *extra: str, **kw) -> AcquireProcess:
            a = AcquireProcess(tmp_path, dev.out, *extra, **kw)
            started.append(a)
            return a

    yield Rig()
    for p in reversed(started):
        p.stop()


def limit_file_size(limit_bytes: int):
    """A ``preexec_fn``: files the child writes stop at ``limit_bytes`` (EFBIG, as a
    full disk)."""
    def apply():
        import resource
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))
        os.setsid()
    return apply
