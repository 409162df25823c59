"""The imaging kernel built for other instruction sets on this machine, side by side:
voxel-channel updates per second of the same kernel calls compiled for this machine
(AVX-512 where it has it), for an AVX2-only target (numba's CPU name and features,
``window_gather.AVX2_TARGET``: what a Haswell-to-Zen-3 boat computer runs) with the AVX2
window gather, and for that target with the lane-by-lane loads (how such a machine ran
before the AVX2 gather), saved as JSON.

    python benchmarks/bench_isa.py --out benchmarks/results/bench_isa.json [--pings 20] [--reps 3]

Workload: bench_threads.py's (``--pings`` consecutive pings of the reference tile, the
default processing, float32), recorded once here and replayed, kernel only, in one
subprocess per (variant, repetition), the variants interleaved, each with its own numba
cache folder (the cache does not know the gather path); best of ``--reps``, at 1 thread
and at every core. Every variant must give the same image, bit for bit (the gather's
result never depends on its path): the run fails otherwise. The JSON records this
machine's instruction set and the path each variant compiled.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import pickle
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from svss_proc.imaging.window_gather import AVX2_TARGET, PATH_VARIABLE  # noqa: E402

log = logging.getLogger("bench_isa")

VARIANTS = {
    "this machine": {},
    "AVX2 target, AVX2 gather": dict(AVX2_TARGET),
    "AVX2 target, lane loads": {**AVX2_TARGET, PATH_VARIABLE: "loads"},
}

CHILD = """
import hashlib, json, pickle, sys, time
import numba, numpy as np
from svss_proc.imaging.cpu_kernel import _make_kernel
from svss_proc.imaging.window_gather import PATH
with open(sys.argv[1], "rb") as fh:
    calls = pickle.load(fh)
key = calls[0][4]
kernel = _make_kernel(*key, spread=True)
dtype = calls[0][0].planes.re.dtype
images = {c[3]: (np.zeros(c[3], dtype), np.zeros(c[3], dtype)) for c in calls}
kernel(*images[calls[0][3]], calls[0][0], calls[0][1], calls[0][2])       # compile
out = {"path": PATH, "rates": {}}
for threads in sorted({1, numba.config.NUMBA_NUM_THREADS}):
    numba.set_num_threads(threads)
    for im in images.values():
        im[0][:] = 0
        im[1][:] = 0
    t0 = time.perf_counter()
    n = sum(int(kernel(*images[c[3]], c[0], c[1], c[2])) for c in calls)
    out["rates"][threads] = {"updates": n, "seconds": time.perf_counter() - t0}
h = hashlib.sha256()
for shape in sorted(images):
    h.update(images[shape][0].tobytes())
    h.update(images[shape][1].tobytes())
out["image_sha256"] = h.hexdigest()
print("RESULT " + json.dumps(out))
"""


def machine_isa() -> dict:
    import platform
    flags = set()
    model = platform.processor()
    try:
        text = Path("/proc/cpuinfo").read_text()
        for line in text.splitlines():
            if line.startswith("flags"):
                flags = set(line.split(":", 1)[1].split())
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
    except OSError:
        pass
    return {"cpu": model, "cores": os.cpu_count(),
            "isa": [f for f in ("avx512f", "avx512bw", "avx512vl", "avx2", "fma", "avx",
                                "sse4_2") if f in flags]}


def record(pings: int) -> list:
    from benchmarks.bench_imaging import scene_for
    from benchmarks.bench_threads import record_calls
    from sim_device.environment_source import EnvironmentSource
    from svss_daq.config import (HardwareConfig, ProcessingConfig, config_path, load,
                                 load_with_text)
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    proc = load(ProcessingConfig, config_path("processing.toml"))
    src = EnvironmentSource(hw, scene_for(340))
    calls = record_calls(hw, proc, [src.ping(i) for i in range(90, 150 + pings)])
    return calls[-pings:]


def run_child(job: Path, env: dict, cache: Path) -> dict:
    full = {**os.environ, **env, "NUMBA_CACHE_DIR": str(cache),
            "PYTHONPATH": os.pathsep.join([str(ROOT)] + [p for p in [
                os.environ.get("PYTHONPATH")] if p])}
    res = subprocess.run([sys.executable, "-c", CHILD, str(job)], cwd=ROOT, env=full,
                         capture_output=True, text=True, timeout=1800)
    lines = [ln for ln in res.stdout.splitlines() if ln.startswith("RESULT ")]
    if res.returncode != 0 or not lines:
        raise RuntimeError(f"variant {env}: exit {res.returncode}\n{res.stderr[-3000:]}")
    return json.loads(lines[-1][len("RESULT "):])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="bench_isa.json")
    ap.add_argument("--pings", type=int, default=20)
    ap.add_argument("--reps", type=int, default=3)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    logging.getLogger("numba").setLevel(logging.WARNING)
    calls = record(args.pings)
    result = {"command": " ".join([os.path.basename(sys.executable)] + sys.argv),
              "machine": machine_isa(), "pings": len(calls), "variants": {}}
    best: dict = {}
    with tempfile.TemporaryDirectory(prefix="bench_isa_") as tmp:
        job = Path(tmp) / "calls.pkl"
        with open(job, "wb") as fh:
            pickle.dump(calls, fh)
        for rep in range(args.reps):
            order = list(VARIANTS) if rep % 2 == 0 else list(reversed(VARIANTS))
            for name in order:
                r = run_child(job, VARIANTS[name], Path(tmp) / f"cache{list(VARIANTS).index(name)}")
                log.info("rep %d %-26s path %-6s %s", rep, name, r["path"],
                         {t: f"{v['updates'] / v['seconds']:.3e}/s"
                          for t, v in r["rates"].items()})
                entry = best.setdefault(name, {"path": r["path"], "env": VARIANTS[name],
                                               "image_sha256": r["image_sha256"],
                                               "rates": {}})
                if r["image_sha256"] != entry["image_sha256"] or r["path"] != entry["path"]:
                    raise RuntimeError(f"{name}: another image or path between repetitions")
                for t, v in r["rates"].items():
                    b = entry["rates"].get(t)
                    if b is None or v["seconds"] < b["seconds"]:
                        entry["rates"][t] = {**v, "updates_per_s": v["updates"] / v["seconds"]}
    digests = {v["image_sha256"] for v in best.values()}
    result["images_identical"] = len(digests) == 1
    base = best["this machine"]["rates"]
    for name, entry in best.items():
        entry["over_this_machine"] = {t: base[t]["seconds"] / v["seconds"]
                                      for t, v in entry["rates"].items()}
    result["variants"] = best
    with open(args.out, "w") as fh:
        json.dump(result, fh, indent=2)
    print(f"{result['machine']['cpu']} ({', '.join(result['machine']['isa'])}), "
          f"{len(calls)} pings, images identical across variants: "
          f"{result['images_identical']}")
    threads = sorted(base, key=int)
    print(f"{'variant':28s} {'path':7s} " + " ".join(f"{t + ' thr':>22s}" for t in threads))
    for name, entry in best.items():
        cells = [f"{entry['rates'][t]['updates_per_s']:.3e} ({entry['over_this_machine'][t]:.2f}x)"
                 for t in threads]
        print(f"{name:28s} {entry['path']:7s} " + " ".join(f"{c:>22s}" for c in cells))
    print(f"saved {args.out}")
    if not result["images_identical"]:
        log.error("the variants' images differ: the gather's result depends on its path")
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
