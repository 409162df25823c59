"""The host's share of the GPU path, measured without a GPU: one pass of the reference
tile through the imager doing every host step the GPU path does (with the conditioning
and the coverage on the device), the device's work left out; the ceiling that host time
puts on the end-to-end rate, and where it goes.

    python benchmarks/bench_gpu_host.py [--repeat 3] [--out bench_gpu_host.json]

Per ping the GPU path's host work is: the ping gate and pose checks, the schedule's step,
the placed array and its refraction table (cached per cm of height), the output axis
from the header, the codes copied into page-locked staging (here: into a host array of
the same size), and per slice the kernel arguments and their cross-track range
(``kernel_args``, ``cross_range``), the two geometry rows packed for the batch
(``pack_row``) and the coverage's arguments and placed row (``coverage_args``,
``placed_row``). Left out: numba's launch overhead (about 2 launches a ping and one a
16-ping batch), the CUDA calls (asynchronous copies, events) and anything the GPU does.
The tiles' volumes are uninitialised host arrays (the GPU zeroes them on the device).
The update count is the CPU imager's on the same pings. Side by side, interleaved, best
of ``--repeat``: both stages on the device, the conditioning on the host (the CPU
conditioner and tap planes, copied into a staging array) and both on the host (with the
CPU's coverage count), as ratios.
"""

from __future__ import annotations

import argparse
import cProfile
import dataclasses
import json
import logging
import os
import pstats
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.bench_imaging import scene_for  # noqa: E402
from benchmarks.bench_isa import machine_isa  # noqa: E402
from sim_device.environment_source import EnvironmentSource  # noqa: E402
from svss_daq.config import (HardwareConfig, ProcessingConfig, config_path, load,  # noqa: E402
                             load_with_text)
from svss_proc.imaging.coverage import CoverageArgs, count_cpu  # noqa: E402
from svss_proc.imaging.gpu_batch import pack_row, row_length  # noqa: E402
from svss_proc.imaging.gpu_coverage import placed_row  # noqa: E402
from svss_proc.imaging.gpu_kernel import cross_range  # noqa: E402
from svss_proc.imaging.imager import TileImager  # noqa: E402
from svss_proc.imaging.kernel_args import (INTERP, KernelData, TapPlanes,  # noqa: E402
                                           kernel_args, phase_halvings, prepare,
                                           tap_theta)

log = logging.getLogger("bench_gpu_host")


#: where the GPU path's conditioning and coverage run, compared side by side
VARIANTS = (("device", "device"), ("host", "device"), ("host", "host"))


def host_only_imager(hw, proc, conditioning="device", coverage="device") -> TileImager:
    """A CPU-configured imager whose kernel, coverage count and conditioning do the GPU
    path's host work only (module docstring); ``conditioning``, ``coverage`` 'host':
    those stages as the GPU path runs them on the host (the CPU conditioner and tap
    planes, copied into staging; the CPU's coverage count)."""
    imager = TileImager(hw, proc)
    acc = imager.accumulator
    conditioner = acc._conditioner
    axis0 = conditioner.output_axis()
    code = INTERP[proc.imaging.interpolation]
    theta = tap_theta(conditioner.fc, axis0.step_s)
    planes = np.empty((2, 2, acc.geometry.receivers.shape[0], axis0.n), dtype=acc.dtype)
    staging = np.empty((acc.geometry.receivers.shape[0], conditioner.n_in), dtype=np.int32)
    rows: dict = {}
    ft = np.dtype(acc.dtype).type
    host_planes = np.empty_like(planes)

    def kernel_data(ping, conditioned=None):
        if conditioning == "host":
            kd = prepare(acc.condition(ping), proc.imaging.interpolation, acc.dtype)
            host_planes[0, :kd.planes.re.shape[0]] = kd.planes.re   # the staging copy
            host_planes[1, :kd.planes.im.shape[0]] = kd.planes.im
            return kd, conditioner.output_axis(ping.sample_axis), False
        staging[:, :ping.samples.shape[1]] = ping.samples        # the staging copy
        axis = conditioner.output_axis(conditioner.checked_axis(ping.sample_axis))
        kd = KernelData(TapPlanes(planes[0], planes[1], ft(axis.start_s),
                                  ft(1.0 / axis.step_s), ft(theta)), code,
                        phase_halvings(theta))
        return kd, axis, False

    def kernel(out, kd, array, delays, *, gating=True, count=None):
        args = kernel_args(kd, array, out.axes, delays)
        cross_range(args, gating)
        g = args.geometry
        n = row_length(g.ax.size, g.cy.size, g.dz.size, g.rx_dx.size)
        if rows.get("n") != n:
            rows.update(n=n, k=np.empty(n, dtype=acc.dtype), f=np.empty(n))
        pack_row(rows["k"], args.geometry, args.planes)
        pack_row(rows["f"], args.gate, None)
        return 0

    def counter(pings, channels, a: CoverageArgs, ia0, ia1):
        placed_row(a)

    acc.kernel = kernel
    acc.kernel_data = kernel_data
    acc._coverage_counter = counter if coverage == "device" else count_cpu
    zeros = {"device": lambda shape, dtype: np.empty(shape, dtype=dtype),
             "host": np.zeros}[coverage]     # (the host's coverage counts from zero)
    acc._zeros = zeros
    return imager


def one_pass(hw, proc, pings, profile=False, variant=VARIANTS[0]):
    imager = host_only_imager(hw, proc, *variant)
    prof = cProfile.Profile() if profile else None
    t0 = time.perf_counter()
    if prof:
        prof.enable()
    for p in pings:
        imager.add(p)
    imager.finish()
    if prof:
        prof.disable()
    return time.perf_counter() - t0, prof


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="bench_gpu_host.json")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    proc = load(ProcessingConfig, config_path("processing.toml"))
    proc = dataclasses.replace(proc, imaging=dataclasses.replace(
        proc.imaging, device="cpu", method="exact"))
    src = EnvironmentSource(hw, scene_for(340))
    pings = [src.ping(i) for i in range(90, 340)]
    times: dict = {v: [] for v in VARIANTS}
    for v in VARIANTS:
        one_pass(hw, proc, pings[:3], variant=v)         # compile outside the timing
    for _ in range(args.repeat):                         # interleaved
        for v in VARIANTS:
            times[v].append(one_pass(hw, proc, pings, variant=v)[0])
    _, prof = one_pass(hw, proc, pings, profile=True)
    st = pstats.Stats(prof)
    top = sorted(({"function": f"{Path(p).name}:{ln}:{nm}", "calls": nc,
                   "cumtime_s": round(ct, 4), "tottime_s": round(tt, 4)}
                  for (p, ln, nm), (cc, nc, tt, ct, _) in st.stats.items()),
                 key=lambda r: -r["cumtime_s"])[:25]
    log.info("the CPU imager for the update count")
    imager = TileImager(hw, proc)
    for p in pings:
        imager.add(p)
    imager.finish()
    updates = imager.updates
    best = min(times[VARIANTS[0]])
    load_avg = os.getloadavg()
    variants = {}
    for v in VARIANTS:
        b = min(times[v])
        variants[f"conditioning_{v[0]}_coverage_{v[1]}"] = {
            "host_seconds": times[v], "host_seconds_best": b,
            "host_ms_per_ping": 1e3 * b / len(pings), "ceiling_updates_per_s": updates / b,
            "host_seconds_over_both_on_device": b / best}
    result = {
        "command": " ".join([os.path.basename(sys.executable)] + sys.argv),
        "machine": {**machine_isa(), "load_after": load_avg},
        "pings": len(pings), "updates": updates, "variants": variants,
        "host_seconds_best": best, "host_ms_per_ping": 1e3 * best / len(pings),
        "ceiling_updates_per_s": updates / best, "profile_top": top}
    with open(args.out, "w") as fh:
        json.dump(result, fh, indent=2)
    print(f"{len(pings)} pings, {updates:.3e} updates: the GPU path's host work "
          f"{best:.3f} s a pass ({1e3 * best / len(pings):.2f} ms a ping), ceiling "
          f"{updates / best:.3e} updates/s end to end")
    for k, v in variants.items():
        print(f"  {k}: {v['host_seconds_best']:.3f} s a pass "
              f"({v['host_seconds_over_both_on_device']:.2f}x), ceiling "
              f"{v['ceiling_updates_per_s']:.3e} updates/s")
    print("where the host time goes, both stages on the device:")
    for r in top[:12]:
        print(f"  {r['cumtime_s']:8.3f} s cum {r['tottime_s']:8.3f} s own {r['calls']:6d}  "
              f"{r['function']}")
    print(f"saved {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
