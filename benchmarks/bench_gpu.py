"""GPU imaging benchmark: the reference tile on the GPU (numba-cuda), kernel-only and end
to end, and the CPU/GPU image agreement, saved as JSON.

    python benchmarks/bench_gpu.py --out benchmarks/results/bench_gpu.json [--repeat 3]
    NUMBA_ENABLE_CUDASIM=1 python benchmarks/bench_gpu.py --quick --out /tmp/bench_gpu.json
    python benchmarks/bench_gpu.py --ptx-only          # needs numba-cuda and NVVM, no GPU

Reference tile: bench_imaging.py's (750 x 100 x 100 voxels at 2 cm, 80 channels, the
demo's points, default processing but ``imaging.device = "cuda"``), pings 90-339.

1. End to end: ``TileImager`` with the device set to cuda (conditioning, tap planes,
   geometry, uploads, kernel; the update counts kept on the device and read once per
   tile), best of ``--repeat`` passes; rate = voxel-channel updates / seconds; and the
   same with a wait for every kernel and its count (how it ran before), as a ratio.
2. Kernel only: the kernel calls of one pass recorded (kernel arguments on the host) and
   replayed with their uploads, then the launches alone with everything already on the
   device (one synchronisation at the end).
3. Agreement: the full tile's image from the GPU in float32 and in float64 against the
   CPU kernel in float64: the largest difference over the tile's peak and the number of
   voxels off by more than 1 % of the peak.
4. PTX: the float32 kernel compiled for sm_90 (no GPU needed): counts of float64
   instructions (0 expected) and of the main float32 ones.

``--quick``: 1 m x 0.4 m x 0.4 m tiles of 10 cm voxels, 3 pings near the first point and
a receive window of 384 samples from 2 ms, for checking that the script works (under the
CUDA simulator: its rates mean nothing).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import os
import platform
import re
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.bench_imaging import scene_for  # noqa: E402
from sim_device.environment_source import EnvironmentSource  # noqa: E402
from svss_daq.config import (HardwareConfig, Loaded, ProcessingConfig,  # noqa: E402
                             config_path, load, load_with_text)
from svss_proc.imaging.imager import TileImager  # noqa: E402
from svss_proc.imaging.kernel_args import STRAIGHT  # noqa: E402

log = logging.getLogger("bench_gpu")
SIMULATOR = os.environ.get("NUMBA_ENABLE_CUDASIM", "0") == "1"


def settings(proc: ProcessingConfig, device: str, precision: str) -> ProcessingConfig:
    return dataclasses.replace(proc, imaging=dataclasses.replace(
        proc.imaging, device=device, precision=precision))


def stages(proc: ProcessingConfig, conditioning: str, coverage: str) -> ProcessingConfig:
    """The GPU's conditioning and coverage where given ('device' or 'host')."""
    return dataclasses.replace(proc, imaging=dataclasses.replace(
        proc.imaging, gpu_conditioning=conditioning, gpu_coverage=coverage))


#: where the GPU's conditioning and coverage run, compared side by side
STAGES = (("device", "device"), ("host", "device"), ("device", "host"), ("host", "host"))


def stage_rates(hw, proc, pings, repeat, ref_tile) -> dict:
    """The end-to-end pass (best of ``repeat``) with the conditioning and the coverage on
    the device or the host (:data:`STAGES`), side by side in one run, as ratios to both
    on the host; each one's image and coverage against the first's."""
    out, first = {}, None
    for cond, cov in STAGES:
        sproc = stages(proc, cond, cov)
        image(hw, sproc, pings[:2])                        # compile outside the timing
        runs = [image(hw, sproc, pings) for _ in range(repeat)]
        tile, n, _, _ = runs[0]
        el = min(r[2] for r in runs)
        row = {"seconds": el, "updates": n, "updates_per_s": n / el,
               **agreement(tile.image, ref_tile)}
        if first is None:
            first = tile
        row["coverage_equal_first"] = bool(
            np.array_equal(tile.coverage.pings, first.coverage.pings)
            and np.array_equal(tile.coverage.channels, first.coverage.channels))
        out[f"conditioning_{cond}_coverage_{cov}"] = row
        log.info("conditioning on the %s, coverage on the %s: %s", cond, cov, row)
    base = out["conditioning_host_coverage_host"]["seconds"]
    for row in out.values():
        row["speed_over_both_on_host"] = base / row["seconds"]
    return out


def image(hw, proc, pings, record=False, wait_each_ping=False):
    """Image the pings; return the fullest tile (host), the updates, the seconds and
    (``record``) the kernel calls of that tile. ``wait_each_ping``: the GPU kernel's
    front door called without a device counter, so that each call waits for its kernel
    and reads its count back (as before the counts stayed on the device)."""
    imager = TileImager(hw, proc)
    calls = []
    run = imager.accumulator.kernel
    if record:
        def recording(*args, **kw):
            calls.append((args, {k: v for k, v in kw.items() if k != "count"}))
            return run(*args, **kw)
        imager.accumulator.kernel = recording
    elif wait_each_ping:
        waited = [0]

        def waiting(*args, count=None, **kw):
            waited[0] += run(*args, **kw)
        imager.accumulator.kernel = waiting
    t0 = time.perf_counter()
    tiles = []
    for p in pings:
        tiles += imager.add(p)
    tiles += imager.finish()
    n = imager.updates                      # (on the GPU: waits for the last kernels)
    el = time.perf_counter() - t0
    if wait_each_ping:
        return None, waited[0], el, calls
    tile = max(tiles, key=lambda t: t.updates)
    return tile, n, el, calls


def per_launch_rates(hw, proc, pings, calls, counts, repeat) -> dict:
    """Pings per launch side by side in one run (float32): the end-to-end pass through
    the imager (best of ``repeat``), and the recorded kernel calls replayed through the
    batcher (packing, uploads and launches, no conditioning or coverage), per count."""
    from numba import cuda

    from svss_proc.imaging import gpu_kernel as G
    from svss_proc.imaging.gpu_batch import PingBatcher
    shape, dtype = calls[0][0][0].re.shape, calls[0][0][0].re.dtype
    re, im = G.device_zeros(shape, dtype), G.device_zeros(shape, dtype)
    out = {}
    for k in counts:
        kproc = dataclasses.replace(proc, imaging=dataclasses.replace(
            proc.imaging, gpu_pings_per_launch=k))
        image(hw, kproc, pings[:2])                        # compile outside the timing
        runs = [image(hw, kproc, pings) for _ in range(repeat)]
        el = min(r[2] for r in runs)
        n = runs[0][1]
        batcher = PingBatcher(k)
        best = None
        for _ in range(repeat):
            count = G.device_counter()
            cuda.synchronize()
            t0 = time.perf_counter()
            for a, kw in calls:
                batcher.run_ping(a[0]._replace(re=re, im=im), *a[1:], count=count, **kw)
            batcher.flush()
            m = int(count.copy_to_host()[0])
            t = time.perf_counter() - t0
            best = t if best is None else min(best, t)
        out[str(k)] = {"end_to_end_seconds": el, "end_to_end_updates_per_s": n / el,
                       "replay_seconds": best, "replay_updates_per_s": m / best,
                       "replay_updates_equal": m == n}
        log.info("%d pings per launch: %s", k, out[str(k)])
    base = out[str(counts[0])]
    for k in counts:
        r = out[str(k)]
        r["end_to_end_speed_over_first"] = base["end_to_end_seconds"] / r["end_to_end_seconds"]
        r["replay_speed_over_first"] = base["replay_seconds"] / r["replay_seconds"]
    return out


def profile_pass(hw, proc, pings, top=25) -> list[dict]:
    """One end-to-end pass under cProfile: where the seconds of a ping go (conditioning,
    argument packing, uploads, launches, read-back), the functions with the most
    cumulative time."""
    import cProfile
    import pstats
    prof = cProfile.Profile()
    prof.enable()
    image(hw, proc, pings)
    prof.disable()
    st = pstats.Stats(prof)
    rows = []
    for (path, line, name), (cc, nc, tt, ct, _) in st.stats.items():
        rows.append({"function": f"{Path(path).name}:{line}:{name}", "calls": nc,
                     "tottime_s": round(tt, 4), "cumtime_s": round(ct, 4)})
    rows.sort(key=lambda r: -r["cumtime_s"])
    return rows[:top]


def kernel_only(calls, repeat):
    """Replay recorded GPU kernel calls: with their per-ping uploads (run_ping_gpu), and
    the launches alone with all arguments resident (one synchronisation at the end)."""
    from numba import cuda

    from svss_proc.imaging import gpu_kernel as G
    from svss_proc.imaging.kernel_args import kernel_args
    shape, dtype = calls[0][0][0].re.shape, calls[0][0][0].re.dtype
    re, im = G.device_zeros(shape, dtype), G.device_zeros(shape, dtype)
    out = {}
    best = None
    for _ in range(repeat):
        cuda.synchronize()
        t0 = time.perf_counter()
        n = sum(G.run_ping_gpu(a[0]._replace(re=re, im=im), *a[1:], **kw)
                for a, kw in calls)
        cuda.synchronize()
        el = time.perf_counter() - t0
        best = el if best is None else min(best, el)
    out["with_uploads"] = {"updates": int(n), "seconds": best, "updates_per_s": n / best}
    # everything resident: each call's arguments uploaded once, outside the timing
    launches = []
    for a, kw in calls:
        out_slice, kd, array, delays = a
        ia0, ia1 = out_slice.ia0, out_slice.ia1
        args = kernel_args(kd, array, out_slice.axes, delays)
        gating = kw.get("gating", True)
        ic0, ic1 = G.cross_range(args, gating)
        dev = G.KernelArgs(G.TapPlanes(cuda.to_device(args.planes.re),
                                       cuda.to_device(args.planes.im), *args.planes[2:]),
                           G.VoxelGeometry(*(cuda.to_device(v) if isinstance(v, np.ndarray)
                                             else v for v in args.geometry)),
                           G.TravelTimes(*(cuda.to_device(v) if isinstance(v, np.ndarray)
                                           else v for v in args.delays)),
                           G.ConeGate(*(cuda.to_device(v) if isinstance(v, np.ndarray)
                                        else v for v in args.gate)))
        kernel = G.kernel_for(kd.interp, delays.code, gating, kd.halvings)
        nvox = (ia1 - ia0) * (ic1 - ic0) * len(out_slice.axes.depth)
        launches.append((kernel, -(-nvox // G.THREADS), dev, ia0, ia1, ic0, ic1))
    count = cuda.to_device(np.zeros(1, np.int64))
    best = None
    for _ in range(repeat):
        count.copy_to_device(np.zeros(1, np.int64))
        cuda.synchronize()
        t0 = time.perf_counter()
        for kernel, blocks, dev, ia0, ia1, ic0, ic1 in launches:
            if blocks > 0:
                kernel[blocks, G.THREADS](re, im, dev, ia0, ia1, ic0, ic1, count)
        cuda.synchronize()
        el = time.perf_counter() - t0
        best = el if best is None else min(best, el)
    n = int(count.copy_to_host()[0])
    out["resident"] = {"updates": n, "seconds": best, "updates_per_s": n / best}
    return out


def ptx_counts(proc_pings, hw, proc) -> dict:
    """The float32 kernel of the default setting compiled to PTX for sm_90: instruction
    counts (float64 ones and the main float32 ones)."""
    import numba
    from numba import cuda

    from svss_proc.imaging import gpu_kernel as G
    from svss_proc.imaging.kernel_args import kernel_args
    tile, _, _, calls = image(hw, settings(proc, "cpu", "float32"), proc_pings[:2],
                              record=True)
    a, kw = calls[-1]
    out_slice, kd, array, delays = a
    args = kernel_args(kd, array, out_slice.axes, delays)
    f3 = numba.float32[:, :, ::1]
    sig = (f3, f3, numba.typeof(args), numba.int64, numba.int64, numba.int64, numba.int64,
           numba.int64[::1])

    def counts(kernel):
        ptx, _ = cuda.compile_ptx(kernel.py_func, sig, cc=(9, 0))
        ops = Counter(re.findall(r"^\s+([a-z]+(?:\.[a-z0-9]+)*)", ptx, re.M))
        return {"float64_ops": {k: v for k, v in ops.items() if "f64" in k},
                "float32_ops": {k: v for k, v in ops.items()
                                if k.split(".")[0] in ("fma", "mul", "add", "sub", "sqrt")
                                and "f32" in k},
                "lines": ptx.count("\n")}
    # the default setting: float64 where meant (the refraction table's row in offset,
    # cone decisions at an edge); straight rays ungated: float32 alone
    out = counts(G.kernel_for(kd.interp, delays.code, kw.get("gating", True),
                              kd.halvings))
    out["straight_ungated"] = counts(G.kernel_for(kd.interp, STRAIGHT, False, kd.halvings))
    return out


def agreement(img, ref) -> dict:
    peak = float(np.abs(ref).max())
    d = np.abs(img.astype(np.complex128) - ref) / peak
    return {"max_error_over_peak": float(d.max()),
            "voxels_off_by_1pct_of_peak": int(np.count_nonzero(d > 0.01))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="bench_gpu.json")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="tiny problem (works under "
                    "NUMBA_ENABLE_CUDASIM=1; its rates mean nothing there)")
    ap.add_argument("--profile", action="store_true",
                    help="also profile one float32 end-to-end pass (cProfile, top functions)")
    ap.add_argument("--per-launch", default="1,4,16,64",
                    help="pings per GPU launch compared side by side (float32), comma list")
    ap.add_argument("--ptx-only", action="store_true",
                    help="only compile the float32 kernel to PTX and count instructions")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    logging.getLogger("numba").setLevel(logging.WARNING)   # no dealloc lines
    if SIMULATOR:
        log.warning("NUMBA_ENABLE_CUDASIM=1: the CUDA simulator runs the kernel in Python; "
                    "its rates say NOTHING about a GPU (this run checks that the script "
                    "works and that the images agree)")
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    proc = load(ProcessingConfig, config_path("processing.toml"))
    result = {"command": " ".join([os.path.basename(sys.executable)] + sys.argv),
              "simulator": SIMULATOR,
              "machine": {"cpu": platform.processor() or platform.machine(),
                          "cores": os.cpu_count()}}
    if not SIMULATOR:
        try:
            from numba import cuda
            dev = cuda.get_current_device()
            result["machine"]["gpu"] = dev.name.decode() if isinstance(dev.name, bytes) \
                else str(dev.name)
        except Exception as exc:                       # noqa: BLE001 - reported
            result["machine"]["gpu"] = f"none ({exc.__class__.__name__})"
    if args.quick:        # the tile's echoes in a shorter window (the simulator's time)
        hw = Loaded(dataclasses.replace(hw.value, digitiser=dataclasses.replace(
            hw.value.digitiser, window_start_s=0.002, window_samples=384)), hw.text,
            hw.source)
    src = EnvironmentSource(hw, scene_for(340))
    if args.quick:
        proc = dataclasses.replace(proc, tile=dataclasses.replace(
            proc.tile, length_m=1.0, width_m=0.4, depth_m=0.4, top_m=0.1, voxel_m=0.1))
        pings = [src.ping(i) for i in range(134, 137)]
    else:
        pings = [src.ping(i) for i in range(90, 340)]
    result["pings"] = len(pings)
    if args.ptx_only or not SIMULATOR:
        try:
            result["ptx_float32"] = ptx_counts(pings, hw, proc)
            log.info("PTX float32 kernel: %s", result["ptx_float32"])
        except Exception as exc:                       # noqa: BLE001 - reported
            result["ptx_float32"] = {"error": f"{exc.__class__.__name__}: {exc}"[:500]}
            log.warning("PTX compile failed: %s", result["ptx_float32"]["error"])
        if args.ptx_only:
            with open(args.out, "w") as fh:
                json.dump(result, fh, indent=2)
            print(json.dumps(result["ptx_float32"], indent=1))
            return 0
    ref_tile, n_ref, el_cpu, _ = image(hw, settings(proc, "cpu", "float64"), pings)
    ref = ref_tile.image.astype(np.complex128)
    cpu32, n_cpu, el_cpu32, _ = image(hw, settings(proc, "cpu", "float32"), pings)
    result["cpu_float32"] = {"updates": n_cpu, "seconds": el_cpu32,
                             "updates_per_s": n_cpu / el_cpu32,
                             **agreement(cpu32.image, ref)}
    result["tile"] = {"index": ref_tile.grid.index, "shape": list(ref_tile.grid.shape),
                      "updates": ref_tile.updates}
    for precision in ("float32", "float64"):
        gproc = settings(proc, "cuda", precision)
        image(hw, gproc, pings[:1])                    # compile outside the timing
        passes = [image(hw, gproc, pings) for _ in range(args.repeat if not SIMULATOR
                                                         else 1)]
        tile, n, _, _ = passes[0]
        # the kernel calls of a pass with the planes made on the host, for the replays
        calls = image(hw, stages(gproc, "host", "host"), pings, record=True)[3]
        el = min(p[2] for p in passes)
        row = {"updates": n, "seconds": el, "seconds_all_passes": [p[2] for p in passes],
               "end_to_end_updates_per_s": n / el, **agreement(tile.image, ref),
               "updates_equal_cpu": n == n_ref}
        # the same passes with a wait for each kernel and its count (the way before the
        # counts stayed on the device), side by side in this run
        waits = [image(hw, gproc, pings, wait_each_ping=True)
                 for _ in range(args.repeat if not SIMULATOR else 1)]
        el_wait = min(w[2] for w in waits)
        row["waiting_for_each_kernel"] = {
            "updates": waits[0][1], "seconds": el_wait, "updates_per_s": waits[0][1] / el_wait,
            "deferred_over_waiting_speed": el_wait / el}
        # every tile has the same shape: the calls replay into one pair of planes
        row.update(kernel_only(calls, args.repeat if not SIMULATOR else 1))
        if precision == "float32":
            row["stages"] = stage_rates(hw, gproc, pings, args.repeat if not SIMULATOR
                                        else 1, ref)
        if precision == "float32" and args.per_launch:
            row["pings_per_launch"] = per_launch_rates(
                hw, gproc, pings, calls,
                [int(k) for k in args.per_launch.split(",")],
                args.repeat if not SIMULATOR else 1)
        if args.profile and precision == "float32":
            row["profile_one_pass"] = profile_pass(hw, gproc, pings)
            for r in row["profile_one_pass"][:15]:
                log.info("profile %8.3f s cum %8.3f s own %7d calls  %s", r["cumtime_s"],
                         r["tottime_s"], r["calls"], r["function"])
        result[f"cuda_{precision}"] = row
        log.info("cuda %s: %s", precision, row)
    with open(args.out, "w") as fh:
        json.dump(result, fh, indent=2)
    note = "  (CUDA SIMULATOR: rates mean nothing)" if SIMULATOR else ""
    print(f"tile {result['tile']['shape']} index {result['tile']['index']}, "
          f"{n_ref:.3e} updates in all{note}")
    c = result["cpu_float32"]
    print(f"  cpu float32: {c['updates_per_s']:.3e} updates/s end to end, max error "
          f"{c['max_error_over_peak']:.2e} of peak, {c['voxels_off_by_1pct_of_peak']} "
          f"voxels off by 1 %")
    for precision in ("float32", "float64"):
        r = result[f"cuda_{precision}"]
        k = r.get("resident", {}).get("updates_per_s", float("nan"))
        print(f"  cuda {precision}: {r['end_to_end_updates_per_s']:.3e} updates/s end to "
              f"end, kernel alone {k:.3e}, max error {r['max_error_over_peak']:.2e} of "
              f"peak, {r['voxels_off_by_1pct_of_peak']} voxels off by 1 %, updates equal "
              f"CPU: {r['updates_equal_cpu']}{note}")
        for k, v in r.get("pings_per_launch", {}).items():
            print(f"    {k:>3} pings per launch: end to end {v['end_to_end_updates_per_s']:.3e} "
                  f"updates/s ({v['end_to_end_speed_over_first']:.2f}x), kernel calls "
                  f"replayed {v['replay_updates_per_s']:.3e} ({v['replay_speed_over_first']:.2f}x)")
        for k, v in r.get("stages", {}).items():
            print(f"    {k}: {v['updates_per_s']:.3e} updates/s "
                  f"({v['speed_over_both_on_host']:.2f}x both on the host), max error "
                  f"{v['max_error_over_peak']:.2e} of peak, coverage equal: "
                  f"{v['coverage_equal_first']}")
        w = r["waiting_for_each_kernel"]
        print(f"    waiting for each kernel and its count: {w['updates_per_s']:.3e} "
              f"updates/s (counts on the device: {w['deferred_over_waiting_speed']:.2f}x)")
    print(f"saved {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
