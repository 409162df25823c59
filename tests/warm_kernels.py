"""Numba's on-disk cache filled once, before the test processes start (issue 50).

On a cold cache (a fresh clone: CI) each test process, and each daemon, worker and
simulated device the end-to-end tests start, compiled the kernels it needed itself: the
simulator's point-scene kernels, the navigation filter and the live worker's imaging
kernel were compiled up to four times over, the daemons' copies while a test waited on
them. The xdist controller (``tests/conftest.py``) runs this module's groups as parallel
processes before the workers start; later processes load the kernels from the cache. On
a warm cache each group only loads them (a few seconds).

``python -m tests.warm_kernels GROUP`` compiles one group (``sim``, ``imaging``);
failures are reported, never fatal: a kernel not warmed is compiled where it is used."""

from __future__ import annotations

import dataclasses
import sys


def sim() -> None:
    """The simulated device's point-scene kernels (float64; the pings of
    ``svss simulate`` and the end-to-end tests' devices), and the navigation filter that
    every daemon warms before its sonar starts."""
    from sim_device.environment_source import EnvironmentSource
    from sim_device.scene import PointTarget, load_scene
    from svss_daq.config import HardwareConfig, config_path, load_with_text
    from svss_daq.nav.kalman import warm_up

    warm_up()
    hardware = load_with_text(HardwareConfig, config_path("hardware.toml"))
    sc = load_scene(config_path("scenes/seabed_sand.toml"))
    sc = dataclasses.replace(
        sc, points=(PointTarget(along_m=0.0, cross_m=0.0, depth_m=0.5,
                                   target_strength_db=-20.0),), targets=(),
        surface=None,
        scattering=dataclasses.replace(sc.scattering, interface=False, volume=False,
                                       specular=False))
    EnvironmentSource(hardware, sc).pressure(0)


def imaging() -> None:
    """The imaging kernels of the shipped processing settings, as the live worker
    (``warm_up`` at its start) and ``svss process`` run them."""
    from svss_daq.config import HardwareConfig, ProcessingConfig, config_path, load_with_text
    from svss_proc.imaging.imager import PingAccumulator, imaging_method

    hardware = load_with_text(HardwareConfig, config_path("hardware.toml"))
    for name in ("processing.toml", "processing-demo.toml"):
        proc = load_with_text(ProcessingConfig, config_path(name)).value
        for live in (True, False):
            PingAccumulator(hardware, proc, method=imaging_method(proc, live=live)).warm_up()


GROUPS = {"sim": sim, "imaging": imaging}


def main(argv: list[str]) -> int:
    for name in argv:
        try:
            GROUPS[name]()
        except Exception as exc:  # noqa: BLE001 - a warm-up never fails the suite
            print(f"tests.warm_kernels {name}: not warmed ({type(exc).__name__}: {exc})",
                  file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
