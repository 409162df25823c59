"""CPU kernel scaling: voxel-channel updates per second against numba's thread count,
for the spread order of along-track slices (issue 16) and the contiguous order before it,
measured side by side in one run.

    python benchmarks/bench_threads.py --out benchmarks/results/bench_threads.json \
        [--pings 30] [--reps 3]

Workload: ``--pings`` consecutive pings of the reference tile (bench_imaging.py's demo
scene: 750 x 100 x 100 voxels at 2 cm, 80 channels, default processing) from ping 150,
placed by the real imager; the kernel calls are recorded once and then replayed, kernel
only, for every (thread count, order) pair, interleaved, the best of ``--reps`` passes
kept. Thread counts 1..N, N = numba's NUMBA_NUM_THREADS (the machine's cores).

It also measures the work of every along-track slice of one mid-tile ping (updates per
slice, from one-slice kernel calls) and from it the load balance numba's static split
would give on T threads, T = 1..16: mean over the most loaded thread's work (1 = no
thread idles). That part needs no cores; the timing part says only what this machine's
cores say.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import sys
import time
from pathlib import Path

import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.bench_imaging import scene_for  # noqa: E402
from sim_device.environment_source import EnvironmentSource  # noqa: E402
from svss_daq.config import (HardwareConfig, ProcessingConfig, config_path, load,  # noqa: E402
                             load_with_text)
from svss_proc.imaging.cpu_kernel import _make_kernel, spread_step  # noqa: E402
from svss_proc.imaging.imager import TileImager  # noqa: E402
from svss_proc.imaging.kernel_args import kernel_args  # noqa: E402

log = logging.getLogger("bench_threads")


def record_calls(hw, proc, pings):
    """The kernel calls the imager makes for ``pings``: (kernel args, ia0, ia1, shape,
    kernel key) each."""
    imager = TileImager(hw, proc)
    calls = []

    def recording(out, kd, array, delays, *, gating=True):
        args = kernel_args(kd, array, out.axes, delays)
        calls.append((args, out.ia0, out.ia1, out.re.shape,
                      (kd.interp, delays.code, bool(gating), kd.halvings)))
        return 0
    imager.accumulator.kernel = recording
    for p in pings:
        imager.add(p)
    return calls


def replay(kernel, calls, images):
    t0 = time.perf_counter()
    n = 0
    for args, ia0, ia1, shape, _ in calls:
        re, im = images[shape]
        n += kernel(re, im, args, ia0, ia1)
    return n, time.perf_counter() - t0


def slice_work(kernel, call, images):
    """Updates of each along-track slice of one call (one-slice kernel calls)."""
    args, ia0, ia1, shape, _ = call
    re, im = images[shape]
    return np.array([kernel(re, im, args, k, k + 1) for k in range(ia0, ia1)], dtype=float)


def balance(work, threads: int, spread: bool) -> float:
    """Mean over the most loaded thread's work under numba's static split into
    ``threads`` contiguous blocks of loop iterations."""
    n = work.size
    order = (np.arange(n) * (spread_step(n) if spread else 1)) % n
    edges = np.linspace(0, n, threads + 1).round().astype(int)
    loads = [work[order[a:b]].sum() for a, b in zip(edges[:-1], edges[1:])]
    return float(work.sum() / threads / max(loads))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="bench_threads.json")
    ap.add_argument("--pings", type=int, default=30)
    ap.add_argument("--reps", type=int, default=3)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    logging.getLogger("numba").setLevel(logging.WARNING)   # no dealloc lines
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    proc = load(ProcessingConfig, config_path("processing.toml"))
    src = EnvironmentSource(hw, scene_for(340))
    pings = [src.ping(i) for i in range(90, 150 + args.pings)]
    calls = record_calls(hw, proc, pings)
    # the first 60 pings only fix the tile frame as in bench_imaging; time the rest
    calls = calls[-args.pings:] if len(calls) > args.pings else calls
    keys = {c[4] for c in calls}
    assert len(keys) == 1, keys
    key = keys.pop()
    kernels = {"contiguous": _make_kernel(*key, spread=False),
               "spread": _make_kernel(*key, spread=True)}
    dtype = calls[0][0].planes.re.dtype
    images = {c[3]: (np.zeros(c[3], dtype), np.zeros(c[3], dtype)) for c in calls}
    for k in kernels.values():                              # compile
        replay(k, calls[:1], images)
    n_max = numba.config.NUMBA_NUM_THREADS
    result = {"command": " ".join([os.path.basename(sys.executable)] + sys.argv),
              "machine": {"cpu": platform.processor() or platform.machine(),
                          "cores": os.cpu_count(), "numba_threads": n_max,
                          "threading_layer": numba.threading_layer()},
              "pings": len(calls), "setting": {"precision": str(dtype),
                                               "interp_mode_gating_halvings": list(key)},
              "rates": []}
    best = {}
    try:
        for rep in range(args.reps):
            for t in range(1, n_max + 1):
                numba.set_num_threads(t)
                for name in (("contiguous", "spread") if rep % 2 == 0
                             else ("spread", "contiguous")):
                    n, el = replay(kernels[name], calls, images)
                    b = best.get((t, name))
                    if b is None or el < b[1]:
                        best[(t, name)] = (n, el)
                    log.info("rep %d threads %d %-10s %.3e updates/s", rep, t, name, n / el)
    finally:
        numba.set_num_threads(n_max)
    for t in range(1, n_max + 1):
        row = {"threads": t}
        for name in ("contiguous", "spread"):
            n, el = best[(t, name)]
            row[name] = {"updates": int(n), "seconds": el, "updates_per_s": n / el,
                         "speedup_vs_1_thread": best[(1, name)][1] / el}
        row["spread_over_contiguous"] = best[(t, "contiguous")][1] / best[(t, "spread")][1]
        result["rates"].append(row)
    mid = calls[len(calls) // 2]
    work = slice_work(kernels["spread"], mid, images)
    result["slice_work"] = {"slices": int(work.size), "updates": work.tolist(),
                            "balance": [{"threads": t,
                                         "contiguous": balance(work, t, False),
                                         "spread": balance(work, t, True)}
                                        for t in (1, 2, 4, 8, 12, 16)]}
    with open(args.out, "w") as fh:
        json.dump(result, fh, indent=2)
    print(f"{'threads':>7s} {'contiguous':>12s} {'spread':>12s} {'ratio':>6s}")
    for row in result["rates"]:
        print(f"{row['threads']:7d} {row['contiguous']['updates_per_s']:12.3e} "
              f"{row['spread']['updates_per_s']:12.3e} {row['spread_over_contiguous']:6.2f}")
    print(f"load balance of one mid-tile ping ({work.size} slices), mean/max thread work:")
    for b in result["slice_work"]["balance"]:
        print(f"  {b['threads']:2d} threads: contiguous {b['contiguous']:.3f}, "
              f"spread {b['spread']:.3f}")
    print(f"saved {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
