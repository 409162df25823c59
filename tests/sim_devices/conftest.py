"""A running ``svss sim-device`` process: real pseudo-terminals, real loopback TCP."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from svss_daq.config import DevicesConfig, load

ROOT = Path(__file__).resolve().parents[2]
DEMO = ROOT / "config" / "scenes" / "demo.toml"
STARTUP_S = 120.0             # a cold numba cache compiles the synthesis kernels first


class SimDeviceProcess:
    """``svss sim-device`` as a subprocess; :attr:`devices` is the configuration it wrote."""

    def __init__(self, tmp: Path, *extra: str) -> None:
        self.out = tmp / "devices.toml"
        self.log = tmp / "sim-device.log"
        self.stdout = tmp / "sim-device.out"
        cmd = [sys.executable, "-m", "svss", "sim-device", "--scene", str(DEMO),
               "--devices-out", str(self.out), *extra]
        with open(self.log, "wb") as err, open(self.stdout, "wb") as out:
            self.proc = subprocess.Popen(cmd, stdout=out, stderr=err, cwd=ROOT)
        deadline = time.monotonic() + STARTUP_S
        while not self.out.exists():
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.stop()
                raise RuntimeError(f"sim-device did not start (rc {self.proc.returncode}):\n"
                                   + self.log.read_text())
            time.sleep(0.05)
        self.devices: DevicesConfig = load(DevicesConfig, self.out)
        # stdout carries the same configuration, once written
        while self.stdout.read_text().count("[navigation]") < 1 and time.monotonic() < deadline:
            time.sleep(0.05)

    def logs(self) -> str:
        return self.log.read_text(errors="replace")

    def stop(self, sig: int = signal.SIGTERM, timeout_s: float = 10.0) -> int:
        return stop_process(self.proc, sig, timeout_s)


def stop_process(proc: subprocess.Popen, sig: int = signal.SIGTERM,
                 timeout_s: float = 10.0) -> int:
    """Send ``sig`` to a running ``proc``, kill it if it is not gone within
    ``timeout_s``; its exit code."""
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
    return proc.returncode


@pytest.fixture
def sim_device_factory(tmp_path):
    started: list[SimDeviceProcess] = []

    def make(*extra: str, name: str = "dev") -> SimDeviceProcess:
        d = tmp_path / name
        d.mkdir()
        p = SimDeviceProcess(d, *extra)
        started.append(p)
        return p

    yield make
    for p in started:
        p.stop()


def wait_for(pred, timeout_s: float = 5.0, step_s: float = 0.01) -> bool:
    deadline = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > deadline:
            return False
        time.sleep(step_s)
    return True


__all__ = ["SimDeviceProcess", "DEMO", "wait_for", "stop_process"]
