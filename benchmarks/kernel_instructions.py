"""The exact imaging kernel against the machine's bound (issue 49): instructions per
voxel-channel update of its hot loops, counted in the generated assembly of the native
and the AVX2-only build, the rate those counts allow at an assumed sustained IPC on this
machine's cores, and the measured rate of the same build in the same run; plus kernel
variants that remove work per update, timed side by side with the shipped kernel.

    python benchmarks/kernel_instructions.py --out benchmarks/results/kernel_instructions.json \
        [--pings 10] [--reps 5] [--ipc 4] [--builds native,avx2] [--dynamic-count PINGS]

Workload: bench_isa.py's (consecutive pings of the reference tile, the default
processing: float32, table delays, linear interpolation, gating on), recorded once and
replayed, kernel only (``cpu_kernel._make_kernel``, the specialisation ``run_ping``
uses), in one subprocess per build: ``native`` (numba's host target: AVX-512 here where
the CPU has it) and ``avx2`` (``window_gather.AVX2_TARGET``: numba's CPU name and
features forced to an AVX2-only Haswell, as bench_isa.py does), each with its own numba
cache folder.

Counting. The child takes ``inspect_asm()`` of the compiled specialisation; this script
splits it into functions and finds the innermost loops (a backward jump to a label, no
other backward jump inside). The per-update work of the kernel is three branch-free
depth passes, run per (voxel column, channel) over the cone's depth interval padded to
16-lane vectors: the delay pass (the one loop that converts float sample positions to
integer indices, ``vcvttps2dq``), the window gather (the loop with the register permutes
``vpermt2ps``/``vpermd``; its lane-by-lane fallback lies outside the counted range) and
interpolation/phase/sum (the loop with the phase polynomial's FMAs, no square root, no
conversion, no permute). Where the vectoriser emitted a pass twice (one vector and an
unrolled pair), the body with the most lanes per iteration is counted; the lanes per
iteration come from the loop's induction step (elements where the counter is an index
scaled by 4, bytes otherwise). Instructions per lane are per iteration / lanes; per
update they are multiplied by lanes computed / updates counted (padded lanes and voxels
outside a receiver's cone are computed but weigh 0), measured with a copy of the kernel
that counts every lane. Per (column, channel) pair overhead (table row, loop set-up) and
the projector pass per column are not in the count.

Bound: clock (``/proc/cpuinfo``, ``cpu MHz``: the nominal one a VM reports) x ``--ipc``
instructions per cycle / instructions per update, per core, x threads. Measured:
updates/s of the same build in the same child at 1 thread and at all cores (numba's
thread count), median of ``--reps`` passes, each against the bound of as many cores.

Variants (``VARIANTS``): the shipped ``cpu_kernel.py`` source with text substitutions,
compiled in the same child (no cache) and timed interleaved with the shipped kernel; the
JSON gives each one's median time ratio (shipped / variant, > 1: faster), its image's
largest difference from the shipped image relative to the image peak, and its counted
instructions per lane.

Cross-check (``--dynamic-count PINGS``): the instructions the AVX2 build executes per
update over whole kernel calls, counted by valgrind (cachegrind) as the difference
between replaying PINGS pings and none; the hot loops' share of it says how much of the
executed work the static count covers.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import pickle
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from svss_proc.imaging.window_gather import AVX2_TARGET  # noqa: E402

log = logging.getLogger("kernel_instructions")

BUILDS = {"native": {}, "avx2": dict(AVX2_TARGET)}

# The phase factor exp(j theta (w - s)) with one polynomial term fewer: |theta (w - s)|
# <= |theta| / 2 = 1.38 rad for the default setting (27.5 kHz, 62.5 kHz samples, no
# halvings), under MAX_HALF_ANGLE = 1.4. Near-minimax polynomials on |x| <= 1.4 (Lawson
# iterations on Chebyshev nodes, float64) of degree 8 (cos) and 9 (sin): errors 1.7e-8
# and 1.3e-9 in float64, 1.0e-7 and 1.1e-7 evaluated in float32, against 1.9e-7 and
# 1.2e-7 for the shipped Taylor series to x^10 and x^11.
_CIS_SHORT = '''

@nb.njit(inline="always")
def _cis_minimax(x, halvings, one):
    """(cos x, sin x) for |x| <= 1.4 rad, near-minimax to x^8 and x^9 (trial)."""
    x2 = x * x
    c = one + x2 * (cast_like(one, -0.4999997275399227) + x2 * (
        cast_like(one, 0.04166531160243962) + x2 * (
            cast_like(one, -0.0013867912039832095) + x2 * cast_like(one, 2.351684242284169e-05))))
    s = x * (one + x2 * (cast_like(one, -0.1666666282063911) + x2 * (
        cast_like(one, 0.008333173557609786) + x2 * (
            cast_like(one, -0.00019819237735575442) + x2 * cast_like(one, 2.6313789655454983e-06)))))
    return c, s


# ----'''

_SPLICE = "\n\n# ----"
_PHASE_CALL = "cr, ci = _cis(theta * (w - shift), halvings, one)"
_COUNT = "n_ch += one if g != zero else zero"

#: name -> (old, new) text substitutions on cpu_kernel.py ("lanes" is not a kernel
#: variant: it counts every computed lane instead of every update)
VARIANTS = {
    "lanes": [(_COUNT, "n_ch += one")],
    "pairs": [("n_upd += np.int64(n_ch)", "n_upd += 1")],
    "phase minimax, one term fewer": [
        (_SPLICE, _CIS_SHORT), (_PHASE_CALL, _PHASE_CALL.replace("_cis(", "_cis_minimax("))],
}
#: variants that count instead of image (not timed)
COUNTERS = ("lanes", "pairs")

CHILD = r"""
import json, pickle, statistics, sys, time, types
from pathlib import Path
import numba, numpy as np
import svss_proc.imaging.cpu_kernel as ck
from svss_proc.imaging.window_gather import PATH

calls = pickle.load(open(sys.argv[1], "rb"))
variants = json.loads(Path(sys.argv[2]).read_text())
reps = int(sys.argv[3])
key = calls[0][4]
src0 = Path(ck.__file__).read_text()


def variant(name, subs):
    src = src0
    for old, new in subs:
        if src.count(old) != 1:
            raise RuntimeError(f"{name}: {old!r} found {src.count(old)} times")
        src = src.replace(old, new)
    mod = types.ModuleType("svss_proc.imaging._cpu_kernel_variant")
    mod.__package__ = "svss_proc.imaging"
    exec(compile(src.replace("cache=True", "cache=False"), f"<{name}>", "exec"),
         mod.__dict__)
    return mod._make_kernel(*key, spread=True)


kernels = {"shipped": ck._make_kernel(*key, spread=True)}
for name, subs in variants.items():
    kernels[name] = variant(name, subs)
dtype = calls[0][0].planes.re.dtype
shapes = sorted({c[3] for c in calls})


def replay(kernel):
    images = {s: (np.zeros(s, dtype), np.zeros(s, dtype)) for s in shapes}
    t0 = time.perf_counter()
    n = 0
    for args, ia0, ia1, shape, _ in calls:
        n += int(kernel(*images[shape], args, ia0, ia1))
    return n, time.perf_counter() - t0, images


t0 = time.perf_counter()
for k in kernels.values():
    k(*[np.zeros(calls[0][3], dtype)] * 2, calls[0][0], calls[0][1], calls[0][1] + 1)
compile_s = time.perf_counter() - t0
out = {"path": PATH, "key": list(key), "compile_s": compile_s,
       "asm": {n: k.inspect_asm(k.signatures[0]) for n, k in kernels.items()},
       "updates": {}, "seconds": {}, "image": {}}
ref = None
for name, k in kernels.items():
    n, _, images = replay(k)
    out["updates"][name] = n
    if ref is None:
        ref = images
        peak = max(float(np.abs(a[0] + 1j * a[1]).max()) for a in images.values())
    d = max(float(np.abs((images[s][0] - ref[s][0]) + 1j * (images[s][1] - ref[s][1])).max())
            for s in shapes)
    out["image"][name] = {"max_diff_over_peak": d / peak,
                          "identical": all(np.array_equal(images[s][0], ref[s][0]) and
                                           np.array_equal(images[s][1], ref[s][1])
                                           for s in shapes)}
timed = [n for n in kernels if n not in ("lanes", "pairs")]
for threads in sorted({1, numba.config.NUMBA_NUM_THREADS}):
    numba.set_num_threads(threads)
    sec = {n: [] for n in timed}
    for rep in range(reps):
        for name in (timed if rep % 2 == 0 else timed[::-1]):
            sec[name].append(replay(kernels[name])[1])
    out["seconds"][threads] = sec
print("RESULT " + json.dumps(out))
"""

DYN_CHILD = r"""
import pickle, sys
import numpy as np
import svss_proc.imaging.cpu_kernel as ck
calls = pickle.load(open(sys.argv[1], "rb"))
kernel = ck._make_kernel(*calls[0][4], spread=True)
dtype = calls[0][0].planes.re.dtype
images = {c[3]: (np.zeros(c[3], dtype), np.zeros(c[3], dtype)) for c in calls}
c = calls[0]
kernel(*images[c[3]], c[0], c[1], c[1] + 1)          # load from the cache, first call
print("UPDATES", sum(int(kernel(*images[c[3]], c[0], c[1], c[2]))
                     for c in calls[:int(sys.argv[2])]))
"""


def dynamic_count(build: str, job: Path, cache: Path, pings: int) -> dict:
    """Instructions executed per update, whole kernel calls (1 thread), from valgrind's
    cachegrind: the difference between replaying ``pings`` pings and none, each after
    the same first call (valgrind hides AVX-512: AVX2 build only)."""
    env = {**os.environ, **BUILDS[build], "NUMBA_CACHE_DIR": str(cache),
           "NUMBA_NUM_THREADS": "1",
           "PYTHONPATH": os.pathsep.join([str(ROOT)] + [p for p in [
               os.environ.get("PYTHONPATH")] if p])}
    out = {}
    for n in (0, pings):
        res = subprocess.run(["valgrind", "--tool=cachegrind", "--cache-sim=no",
                              "--cachegrind-out-file=/dev/null", sys.executable, "-c",
                              DYN_CHILD, str(job), str(n)], cwd=ROOT, env=env,
                             capture_output=True, text=True, timeout=7200)
        refs = re.search(r"I\s+refs:\s+([\d,]+)", res.stderr)
        upd = re.search(r"UPDATES (\d+)", res.stdout)
        if res.returncode != 0 or not refs or not upd:
            raise RuntimeError(f"valgrind: exit {res.returncode}\n{res.stderr[-2000:]}")
        out[n] = (int(refs.group(1).replace(",", "")), int(upd.group(1)))
    d_ins, d_upd = out[pings][0] - out[0][0], out[pings][1] - out[0][1]
    return {"pings": pings, "instructions": d_ins, "updates": d_upd,
            "instructions_per_update": d_ins / d_upd}


# ------------------------------------------------------------------- assembly analysis

_VEC_ARITH = re.compile(r"^v(add|sub|mul|div|fmadd|fmsub|fnmadd|fnmsub|min|max|sqrt|rsqrt|"
                        r"rcp|cvt|round|hadd)\w*$")
_VEC_LOGIC = re.compile(r"^(v(p?cmp|and|andn|or|xor|p?blend|pand|por|pxor|pmax|pmin|psub|"
                        r"padd|pcmp|ptest|movmsk|test)\w*|k\w+)$")
_PERMUTE = re.compile(r"^v(perm|shuf|unpck|insert|extract|broadcast|pbroadcast|movsh|"
                      r"movsl|pshuf|align|valign|compress|expand|pext|pinsr)\w*$")
_GATHER = re.compile(r"^v(p?gather|p?scatter)\w*$")
_MOVE = re.compile(r"^v?(mov|lddqu)\w*$")


def functions(asm: str) -> dict[str, list[str]]:
    """Instructions (comments, directives dropped; labels kept as ``L:name``) per global
    function label."""
    out: dict[str, list[str]] = {}
    cur = None
    for line in asm.splitlines():
        s = line.split("#", 1)[0].strip()
        if not s:
            continue
        if re.match(r"^[A-Za-z_][^\s:]*:$", s):
            cur = s[:-1]
            out[cur] = []
        elif cur is None:
            continue
        elif re.match(r"^\.L[\w$.]+:$", s):
            out[cur].append("L:" + s[:-1])
        elif not s.startswith("."):
            out[cur].append(s)
    return out


def innermost_loops(insns: list[str]) -> list[tuple[int, int]]:
    """(first, last) instruction positions of each loop whose back edge (a jump to a
    label at or before it) encloses no other back edge."""
    labels = {x[2:]: i for i, x in enumerate(insns) if x.startswith("L:")}
    edges = []
    for j, x in enumerate(insns):
        m = re.match(r"^j\w+\s+(\.L[\w$.]+)$", x)
        if m and m.group(1) in labels and labels[m.group(1)] < j:
            edges.append((labels[m.group(1)], j))
    return [(a, b) for a, b in edges
            if not any((a2, b2) != (a, b) and a <= a2 and b2 <= b for a2, b2 in edges)]


def classify(op: str, operands: str) -> str:
    mem = "(" in operands
    if op.startswith("j"):
        return "branch"
    if op.startswith("call"):
        return "call"
    if _GATHER.match(op):
        return "gather"
    if _MOVE.match(op) and mem and ("mm" in operands or op.startswith("v")):
        dst = operands.rsplit(",", 1)[-1]
        return "store" if "(" in dst else "load"
    if _VEC_ARITH.match(op):
        return "vector_fp"
    if _PERMUTE.match(op):
        return "permute_broadcast"
    if _VEC_LOGIC.match(op) or ("mm" in operands and op.startswith("v")):
        return "vector_logic_compare_blend"
    return "integer_address"


def analyse_loop(body: list[str], width: str) -> dict:
    insns = [x for x in body if not x.startswith("L:")]
    counts: dict[str, int] = {}
    folded = 0
    for x in insns:
        op, _, operands = x.partition("\t") if "\t" in x else x.partition(" ")
        op, operands = op.strip(), operands.strip()
        c = classify(op, operands)
        counts[c] = counts.get(c, 0) + 1
        if c not in ("load", "store", "integer_address", "branch") and "(" in operands:
            folded += 1
    text = "\n".join(insns)
    # lanes per iteration from the induction step: `add $N, %r` with %r an index scaled
    # by 4 (elements) or a base / unscaled index (bytes)
    lanes = None
    for x in insns:
        m = re.match(r"^addq\s+\$(\d+),\s*(%\w+)$", x)
        if not m:
            continue
        n, reg = int(m.group(1)), m.group(2)
        if re.search(r",\s*" + re.escape(reg) + r",\s*4\)", text):
            lanes = n
        elif re.search(r"\(\s*" + re.escape(reg) + r"\b|,\s*" + re.escape(reg) + r"\)", text):
            lanes = lanes or n // 4
    ops = [x.split()[0] for x in insns]
    return {"instructions": len(insns), "lanes_per_iteration": lanes,
            "by_class": counts, "folded_memory_operands": folded,
            "width_register_instructions": sum(width in x for x in insns),
            "sqrt": sum(o.startswith(("vsqrt", "vrsqrt")) for o in ops),
            "fma": sum("fmadd" in o or "fmsub" in o for o in ops),
            "convert_to_int": sum(o.startswith("vcvttps2dq") for o in ops),
            "permute2": sum(o.startswith(("vpermt2ps", "vpermi2ps", "vpermd", "vpermps"))
                            for o in ops)}


def hot_loops(asm: str, width: str) -> dict:
    """The three per-update depth passes of the column kernel (module doc)."""
    found: dict[str, list] = {"delay": [], "gather": [], "phase": []}
    for fname, insns in functions(asm).items():
        for a, b in innermost_loops(insns):
            info = analyse_loop(insns[a:b + 1], width)
            if info["width_register_instructions"] < 4 or not info["lanes_per_iteration"]:
                continue
            if info["permute2"]:
                kind = "gather"
            elif info["convert_to_int"]:
                kind = "delay"
            elif info["fma"] >= 8 and not info["sqrt"]:
                kind = "phase"
            else:
                continue
            info["label"] = insns[a][2:] if insns[a].startswith("L:") else None
            info["asm"] = [x for x in insns[a:b + 1]]
            found[kind].append(info)
    out = {}
    for kind, loops in found.items():
        if not loops:
            raise RuntimeError(f"no {kind} loop found in the assembly")
        best = max(loops, key=lambda i: (i["lanes_per_iteration"], i["instructions"]))
        out[kind] = {**best, "per_lane": best["instructions"] / best["lanes_per_iteration"],
                     "versions": [{"instructions": i["instructions"],
                                   "lanes_per_iteration": i["lanes_per_iteration"]}
                                  for i in loops]}
    return out


# --------------------------------------------------------------------------- machine


def machine() -> dict:
    from benchmarks.bench_isa import machine_isa
    info = machine_isa()
    mhz = []
    text = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    for line in text.splitlines():
        if line.startswith("cpu MHz"):
            mhz.append(float(line.split(":")[1]))
        if line.startswith(("cpu family", "model\t", "model  ")):
            k, v = line.split(":", 1)
            info[k.strip().replace(" ", "_")] = int(v)
    info["clock_hz"] = (sum(mhz) / len(mhz) * 1e6) if mhz else None
    return info


def run_child(build: str, job: Path, variants: Path, reps: int, cache: Path) -> dict:
    env = {**os.environ, **BUILDS[build], "NUMBA_CACHE_DIR": str(cache),
           "PYTHONPATH": os.pathsep.join([str(ROOT)] + [p for p in [
               os.environ.get("PYTHONPATH")] if p])}
    res = subprocess.run([sys.executable, "-c", CHILD, str(job), str(variants), str(reps)],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=3600)
    lines = [ln for ln in res.stdout.splitlines() if ln.startswith("RESULT ")]
    if res.returncode != 0 or not lines:
        raise RuntimeError(f"{build}: exit {res.returncode}\n{res.stderr[-3000:]}")
    return json.loads(lines[-1][len("RESULT "):])


def median(xs):
    xs = sorted(xs)
    n = len(xs)
    return xs[n // 2] if n % 2 else 0.5 * (xs[n // 2 - 1] + xs[n // 2])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="kernel_instructions.json")
    ap.add_argument("--pings", type=int, default=10)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--ipc", type=float, default=4.0,
                    help="sustained instructions per cycle assumed for the bound")
    ap.add_argument("--builds", default="native,avx2")
    ap.add_argument("--dynamic-count", type=int, default=0, metavar="PINGS",
                    help="also count the AVX2 build's executed instructions per update "
                         "under valgrind over PINGS pings (slow: minutes a ping)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    from benchmarks.bench_isa import record
    mach = machine()
    result = {"command": " ".join([os.path.basename(sys.executable)] + sys.argv),
              "machine": mach, "load_average_before": os.getloadavg(),
              "ipc_assumed": args.ipc, "pings": args.pings, "builds": {}}
    calls = record(args.pings)
    builds = [b for b in args.builds.split(",") if b]
    with tempfile.TemporaryDirectory(prefix="kernel_instructions_") as tmp:
        job = Path(tmp) / "calls.pkl"
        job.write_bytes(pickle.dumps(calls))
        vfile = Path(tmp) / "variants.json"
        vfile.write_text(json.dumps(VARIANTS))
        for build in builds:
            log.info("build %s: compiling and timing (%d reps)", build, args.reps)
            r = run_child(build, job, vfile, args.reps, Path(tmp) / f"cache_{build}")
            width = "zmm" if r["path"] == "avx512" else "ymm"
            lanes = r["updates"]["lanes"] / r["updates"]["shipped"]
            loops = hot_loops(r["asm"]["shipped"], width)
            per_lane = sum(v["per_lane"] for v in loops.values())
            per_update = per_lane * lanes
            per_core = mach["clock_hz"] * args.ipc / per_update
            rates = {}
            for t, sec in r["seconds"].items():
                rates[t] = r["updates"]["shipped"] / median(sec["shipped"])
            t_max = str(max(int(t) for t in rates))
            bound = per_core * int(t_max)
            measured = rates[t_max]
            variants = {}
            for name in VARIANTS:
                if name in COUNTERS:
                    continue
                vl = hot_loops(r["asm"][name], width)
                variants[name] = {
                    "substitutions": VARIANTS[name],
                    "updates_equal": r["updates"][name] == r["updates"]["shipped"],
                    "image": r["image"][name],
                    "instructions_per_lane": sum(v["per_lane"] for v in vl.values()),
                    "ratio_median": {t: median(sec["shipped"]) / median(sec[name])
                                     for t, sec in r["seconds"].items()},
                    "ratio_per_rep": {t: [a / b for a, b in zip(sec["shipped"], sec[name])]
                                      for t, sec in r["seconds"].items()}}
            result["builds"][build] = {
                "env": BUILDS[build], "gather_path": r["path"], "vector_register": width,
                "kernel_key_interp_mode_gating_halvings": r["key"],
                "hot_loops": {k: {kk: vv for kk, vv in v.items()} for k, v in loops.items()},
                "instructions_per_lane": per_lane,
                "lanes_per_update": lanes,
                "column_channel_pairs": r["updates"]["pairs"],
                "lanes_per_pair": r["updates"]["lanes"] / r["updates"]["pairs"],
                "instructions_per_update": per_update,
                "updates": r["updates"]["shipped"],
                "bound_updates_per_s": {t: per_core * int(t) for t in rates},
                "measured_updates_per_s": rates,
                "fraction_of_bound": {t: v / (per_core * int(t)) for t, v in rates.items()},
                "implied_ipc": {t: v * per_update / (mach["clock_hz"] * int(t))
                                for t, v in rates.items()},
                "seconds": r["seconds"],
                "variants": variants}
            if args.dynamic_count and build == "avx2":
                dyn = dynamic_count(build, job, Path(tmp) / f"cache_{build}",
                                    args.dynamic_count)
                dyn["hot_loops_share"] = per_update / dyn["instructions_per_update"]
                result["builds"][build]["executed_valgrind"] = dyn
                log.info("%s executed (valgrind): %.2f instructions/update; the hot loops "
                         "%.0f %% of them", build, dyn["instructions_per_update"],
                         100 * dyn["hot_loops_share"])
            log.info("%s: %.2f instructions/lane (%s), x %.3f lanes/update = %.2f/update; "
                     "bound %.3e/s, measured %.3e/s at %s threads (%.1f %%)", build,
                     per_lane, ", ".join(f"{k} {v['instructions']}/{v['lanes_per_iteration']}"
                                         for k, v in loops.items()),
                     lanes, per_update, bound, measured, t_max, 100 * measured / bound)
            for name, v in variants.items():
                log.info("  %-36s ratio %s, image diff %.2e, %.2f instructions/lane", name,
                         {t: round(x, 3) for t, x in v["ratio_median"].items()},
                         v["image"]["max_diff_over_peak"], v["instructions_per_lane"])
    result["load_average_after"] = os.getloadavg()
    Path(args.out).write_text(json.dumps(result, indent=2))
    print(f"saved {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
