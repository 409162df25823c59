#!/usr/bin/env python
"""Benchmark pass 2 of the point-scatterer synthesis on the GPU against the CPU fast path
(``[scattering] device = "cuda"`` against ``"cpu"``, :mod:`sim_device.synthesis_gpu`).

Per ping of the seed's sand scene (the scene file's fidelity, 80 channels, no targets,
pings from ``--first``): the scattered pressure (``EnvironmentSource.scattered``) on the
CPU and with pass 2 on the GPU, best and median of ``--pings`` pings after one untimed
ping each (numba compiles or loads the kernels): total seconds, pass 2 seconds
(``receive_s``) and, on the GPU, its parts (uploads, kernel, read-back); ns per echo of
pass 2; CPU seconds of the process per ping; and the agreement of the two pressures on
the first timed ping (||p_gpu - p_cpu|| / ||p_cpu||, float32 rounding expected: < 1e-5).

Usage::

    python benchmarks/bench_gpu_synthesis.py --out benchmarks/results/bench_gpu_synthesis.json
                                              [--pings 5] [--first 100] [--quick]

Where numba finds no GPU it says so, times the CPU alone and writes that. ``--quick``: the
demo's points in water (a few echoes), for checking the script under the CUDA simulator
(``NUMBA_ENABLE_CUDASIM=1``; its times mean nothing). On the GPU machine see
``../shared/tools/gpu-wheels.sh``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sim_device.environment_source import EnvironmentSource
from sim_device.scene import load_scene
from sim_device.synthesis_gpu import cuda_available
from svss_daq.config import HardwareConfig, config_path, load_with_text

log = logging.getLogger("bench_gpu_synthesis")


def scene(quick: bool, device: str):
    """The sand scene (or, quick, the demo's points with an inactive seabed model)."""
    if quick:
        demo = load_scene(config_path("scenes/demo.toml"))
        sand = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
        sc = dataclasses.replace(sand.scattering, interface=False, volume=False,
                                 specular=False, device=device)
        return dataclasses.replace(demo, scattering=sc)
    sc = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
    return dataclasses.replace(sc, targets=(), scattering=dataclasses.replace(
        sc.scattering, device=device))


def time_source(src: EnvironmentSource, pings: list[int]):
    """Per-ping statistics of ``src.scattered`` (one untimed ping first) and the first
    timed ping's pressure."""
    src.scattered(pings[0] - 1)
    rows, first = [], None
    for i in pings:
        c0, t0 = time.process_time(), time.perf_counter()
        p = src.scattered(i)
        row = dict(src.last_stats, wall_s=time.perf_counter() - t0,
                   cpu_s=time.process_time() - c0)
        if src.gpu is not None:
            row.update(src.gpu.last_times)
        rows.append(row)
        if first is None:
            first = p
    return rows, first


def summary(rows: list[dict]) -> dict:
    out = {}
    for key in ("wall_s", "cpu_s", "receive_s", "transmit_s", "generate_s", "upload_s",
                "kernel_s", "download_s"):
        if key in rows[0]:
            v = np.array([r[key] for r in rows])
            out[key] = {"best": float(v.min()), "median": float(np.median(v))}
    echoes = int(np.median([r["echoes"] for r in rows]))
    out["echoes"] = echoes
    out["in_view"] = int(np.median([r["in_view"] for r in rows]))
    out["pass2_ns_per_echo"] = out["receive_s"]["best"] / max(echoes, 1) * 1e9
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=None, help="JSON results")
    ap.add_argument("--pings", type=int, default=5)
    ap.add_argument("--first", type=int, default=100)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("numba").setLevel(logging.WARNING)   # no dealloc lines
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    first = 40 if args.quick else args.first
    pings = list(range(first, first + args.pings))
    simulated = os.environ.get("NUMBA_ENABLE_CUDASIM") == "1"
    result = {"machine": platform.node(), "cpu_count": os.cpu_count(),
              "scene": "demo points (quick)" if args.quick else "seed_cylinder_sand",
              "pings": pings, "cuda_simulator": simulated}
    cpu_rows, p_cpu = time_source(EnvironmentSource(hw, scene(args.quick, "cpu")), pings)
    result["cpu"] = summary(cpu_rows)
    if not cuda_available():
        print("no CUDA GPU available to numba (numba-cuda, an NVIDIA GPU and its driver "
              "are needed): CPU figures only")
        result["gpu"] = None
    else:
        from numba import cuda
        name = "CUDA simulator" if simulated else cuda.get_current_device().name
        name = name.decode() if isinstance(name, bytes) else str(name)
        result["gpu_device"] = name
        gpu_rows, p_gpu = time_source(EnvironmentSource(hw, scene(args.quick, "cuda")),
                                      pings)
        result["gpu"] = summary(gpu_rows)
        result["agreement"] = float(np.linalg.norm(p_gpu - p_cpu) / np.linalg.norm(p_cpu))
    c, g = result["cpu"], result["gpu"]
    print(f"{result['scene']}: {c['in_view']} scatterers in view, {c['echoes']} echoes "
          f"per ping, pings {pings[0]}..{pings[-1]}")
    print(f"{'path':6} {'ping s':>8} {'pass 2 s':>9} {'ns/echo':>8} {'cpu s':>7} "
          f"{'upload':>7} {'kernel':>7} {'back':>7}")
    for label, r in (("cpu", c), ("gpu", g)):
        if r is None:
            continue
        parts = "".join(f" {r[k]['best']:7.3f}" if k in r else f" {'':7}"
                        for k in ("upload_s", "kernel_s", "download_s"))
        print(f"{label:6} {r['wall_s']['best']:8.3f} {r['receive_s']['best']:9.3f} "
              f"{r['pass2_ns_per_echo']:8.2f} {r['cpu_s']['best']:7.2f}{parts}")
    if g is not None:
        print(f"pass 2 speed-up {c['receive_s']['best'] / g['receive_s']['best']:.1f}x, "
              f"agreement {result['agreement']:.2e}")
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1))
        log.info("wrote %s", args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
