#!/usr/bin/env python
"""Benchmark target echo synthesis (``sim_device.targets.echo``) in the simulated pings.

1. Cost per ping of each target type, proud and buried, in the Sayers-like field's
   silt over stiff clay (seabed scattering off: the target contribution alone), on a
   ping with the target 0.3 m ahead of the projector, and on a ping where no beam sees
   it.
2. Series truncation tolerance x frequency sampling (the cylinder form table's step over
   projected frequency; 0 = the series summed at every frequency of the band) against
   the echo's error and the time per ping: error = RMS of the difference of the
   synthesised pressure over the RMS of the reference (tol 1e-13, step 0), in dB. The
   one-off table build per target is reported apart from the per-ping time.

Usage::

    python benchmarks/bench_target_echoes.py --out benchmarks/results/bench_target_echoes.json [--quick]
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

from sim_device.environment_source import EnvironmentSource  # noqa: E402
from sim_device.scene import TargetConfig, TargetModelConfig, load_scene  # noqa: E402
from svss_daq.config import HardwareConfig, config_path, load_with_text  # noqa: E402

log = logging.getLogger("bench_target_echoes")

KINDS = {
    "sphere (shot put, cast iron)": dict(kind="sphere", material="cast_iron", radius_m=0.051),
    "cylinder 30.5 cm (aluminium)": dict(kind="cylinder", material="aluminium",
                                         radius_m=0.076, length_m=0.305,
                                         axis_heading_deg=90.0, axis_tilt_deg=0.0),
    "cylinder 61 cm (aluminium)": dict(kind="cylinder", material="aluminium",
                                       radius_m=0.076, length_m=0.61,
                                       axis_heading_deg=45.0, axis_tilt_deg=0.0),
    "rock (granite disc, 15 cm)": dict(kind="disc", material="granite", radius_m=0.15,
                                       axis_heading_deg=0.0, axis_tilt_deg=10.0),
}


def quiet_field():
    sc = load_scene(config_path("scenes/sayers_field.toml"))
    return dataclasses.replace(
        sc, surface=None, points=(), targets=(),
        scattering=dataclasses.replace(sc.scattering, interface=False, volume=False,
                                       specular=False),
        noise=dataclasses.replace(sc.noise, electronic_rms_counts=0.0, sea_state=None))


def make_target(spec: dict, along: float, depth: float) -> TargetConfig:
    fields = {f.name: None for f in dataclasses.fields(TargetConfig)}
    fields.update(along_m=along, cross_m=0.0, depth_m=depth, **spec)
    return TargetConfig(**fields)


def source_with(hw, base, tgt, tol=1e-8, step=5.0):
    sc = dataclasses.replace(base, targets=(tgt,), target_model=TargetModelConfig(
        truncation_tol=tol, freq_step_hz=step, bistatic="kell"))
    return EnvironmentSource(hw, sc)


def time_target(src, i: int, repeat: int) -> tuple[float, np.ndarray]:
    """Best time (s) of the target contribution on ping i, and its pressure."""
    g = src.frame(i)
    echo = src.contributions[0]
    out = echo(src, i, g)                   # first call: tables, caches
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = echo(src, i, g)
        best = min(best, time.perf_counter() - t0)
    return best, out


def cost_table(hw, base, repeat: int) -> list[dict]:
    rows = []
    tx0 = EnvironmentSource(hw, base).frame(100).tx
    for name, spec in KINDS.items():
        for state, depth in (("proud", -spec["radius_m"]), ("buried 0.2 m", 0.2)):
            src = source_with(hw, base, make_target(spec, tx0[0] + 0.3, depth))
            t_in, _ = time_target(src, 100, repeat)
            paths = src.last_stats.get("target_paths", 0)
            t_out, p_out = time_target(src, 0, repeat)         # 10 m away: unseen
            rows.append({"target": name, "state": state, "s_per_ping_in_view": t_in,
                         "echo_paths": int(paths), "s_per_ping_unseen": t_out,
                         "unseen_pressure_is_zero": bool(not np.any(p_out))})
            log.info("%s %s: %.4f s/ping (%d paths), unseen %.2e s", name, state, t_in,
                     paths, t_out)
    return rows


def trade_table(hw, base, tols, steps, repeat: int) -> list[dict]:
    rows = []
    tx0 = EnvironmentSource(hw, base).frame(100).tx
    for name in ("cylinder 61 cm (aluminium)", "sphere (shot put, cast iron)"):
        spec = KINDS[name]
        tgt = make_target(spec, tx0[0] + 0.3, 0.2)
        ref_src = source_with(hw, base, tgt, tol=1e-13, step=0.0)
        _, ref = time_target(ref_src, 100, 1)
        ref_rms = float(np.sqrt(np.mean(ref ** 2)))
        for tol in tols:
            for step in (steps if spec["kind"] == "cylinder" else [0.0]):
                src = source_with(hw, base, tgt, tol=tol, step=step)
                t0 = time.perf_counter()
                src.contributions[0](src, 100, src.frame(100))
                first = time.perf_counter() - t0
                t, out = time_target(src, 100, repeat if step > 0 else 1)
                err = float(np.sqrt(np.mean((out - ref) ** 2))) / ref_rms
                rows.append({"target": name, "truncation_tol": tol, "freq_step_hz": step,
                             "s_per_ping": t, "first_ping_s (table build)": first,
                             "error_db": 20 * np.log10(max(err, 1e-300))})
                log.info("%s tol %.0e step %g: %.4f s/ping, first %.3f s, error %.1f dB",
                         name, tol, step, t, first, rows[-1]["error_db"])
    return rows


def _print(title: str, rows: list[dict]) -> None:
    print(f"\n{title}")
    if not rows:
        return
    keys = list(rows[0])
    print(" | ".join(keys))
    for r in rows:
        print(" | ".join(f"{r[k]:.4g}" if isinstance(r[k], float) else str(r[k])
                         for k in keys))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="JSON file for the figures")
    ap.add_argument("--quick", action="store_true", help="fewer repeats and options")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    base = quiet_field()
    repeat = 2 if args.quick else 5
    tols = [1e-4, 1e-8] if args.quick else [1e-4, 1e-6, 1e-8, 1e-12]
    steps = [0.0, 25.0, 200.0] if args.quick else [0.0, 5.0, 25.0, 100.0, 400.0]
    result = {
        "command": "python " + " ".join([os.path.relpath(__file__)] + (argv or sys.argv[1:])),
        "machine": {"cpu": platform.machine(), "cores": os.cpu_count()},
        "cost_per_ping": cost_table(hw, base, repeat),
        "truncation_and_sampling": trade_table(hw, base, tols, steps, repeat),
    }
    _print("Cost per ping (target contribution only)", result["cost_per_ping"])
    _print("Truncation tolerance x frequency sampling (error re tol 1e-13, exact series)",
           result["truncation_and_sampling"])
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
