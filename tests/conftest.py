"""Shared fixtures: the project's configuration and small helpers."""

from __future__ import annotations

import json
import os
import resource
import sys
import time
from pathlib import Path

import pytest

from svss_daq.config import HardwareConfig, ProcessingConfig, config_path, load_with_text

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = ROOT.parent / "shared" / "data"


#: the project's packages, compiled to bytecode once at the start of a session
PACKAGES = ("svss", "svss_daq", "svss_proc", "sim_device")


def pytest_configure(config):
    """Bytecode for the session's processes, even where the environment says
    PYTHONDONTWRITEBYTECODE (this project's machines do): without it each of the some
    130 real daemons, workers and devices the end-to-end tests start compiled the
    project's modules from source (0.6 CPU s each on the 2-core Zen 3), and each test
    process rewrote and compiled the test modules afresh (20 CPU s of collection). The
    first process (the xdist controller, or the only one) compiles the packages; the
    caches are __pycache__ folders, ignored by git."""
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
    sys.dont_write_bytecode = False
    if not hasattr(config, "workerinput"):
        import compileall
        for pkg in PACKAGES:
            compileall.compile_dir(str(ROOT / pkg), quiet=1)
        if (getattr(config.option, "numprocesses", None) or 0) and not config.option.collectonly:
            _warm_kernels()


def _warm_kernels():
    """Numba's cache filled before the test processes start (:mod:`tests.warm_kernels`),
    its groups in parallel: on a cold cache (a fresh clone, CI) the kernels that several
    test processes and the end-to-end tests' daemons and devices use are compiled once,
    not once in each; on a warm cache the groups only load them."""
    import subprocess
    procs = [subprocess.Popen([sys.executable, "-m", "tests.warm_kernels", group], cwd=ROOT)
             for group in ("sim", "imaging")]
    for p in procs:
        p.wait()


def pytest_xdist_auto_num_workers(config):
    """``-n auto``: half as many test processes again as CPUs (3 on 2 cores). A third of
    the suite's wall time is its end-to-end tests waiting on real processes, sockets and
    timers (issue 27: 235 s of 1433 s of test time on the 2-core Zen 3); a third process
    computes meanwhile (12.4 min with 2 processes, 11.2 with 3, same code)."""
    return max(1, (3 * (os.cpu_count() or 1) + 1) // 2)


@pytest.fixture(scope="session")
def hardware():
    return load_with_text(HardwareConfig, config_path("hardware.toml"))


@pytest.fixture(scope="session")
def demo_processing():
    return load_with_text(ProcessingConfig, config_path("processing-demo.toml"))


# SVSS_TEST_CPU_LOG=FILE: one JSON line per test with its wall time and the CPU time it
# took, this process's (numba's threads included) and its waited-for subprocesses' (the
# real daemons, workers and devices of the end-to-end tests): where the suite's time goes
# (issue 27). Off by default.
_CPU_LOG = os.environ.get("SVSS_TEST_CPU_LOG")

if _CPU_LOG:
    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(item, nextitem):
        def cpu():
            s = resource.getrusage(resource.RUSAGE_SELF)
            c = resource.getrusage(resource.RUSAGE_CHILDREN)
            return s.ru_utime + s.ru_stime, c.ru_utime + c.ru_stime
        (s0, c0), t0 = cpu(), time.perf_counter()
        yield
        (s1, c1), t1 = cpu(), time.perf_counter()
        line = {"test": item.nodeid, "wall_s": round(t1 - t0, 3),
                "cpu_self_s": round(s1 - s0, 3), "cpu_children_s": round(c1 - c0, 3)}
        with open(_CPU_LOG, "a") as f:
            f.write(json.dumps(line) + "\n")
