#!/usr/bin/env python
"""The synthesis kernels alone, through their positional front doors (which main before
and after the bundled kernels both have), on inputs captured once from
``EnvironmentSource.scattered`` (issue 28; docs/simulator.md, "Bundled kernels and speed").

    python benchmarks/bench_synthesis_bundles.py capture DIR
        pass-1 and pass-2 inputs of one ping each: water (the demo's points), sand
        (ping 100), sand with precision = "exact", into DIR/{water,sand,exact}.pkl
    python benchmarks/bench_synthesis_bundles.py compare DIR OUT.npz
        pass 1 (40,000 scatterers), reference, fast parallel and fast serial of each case
        (20,000 sand scatterers, 4,000 of the others) into OUT.npz; two trees' files are
        compared with ``np.array_equal`` (bitwise)
    python benchmarks/bench_synthesis_bundles.py bench DIR LABEL [REPS]
        process seconds, best of REPS (5), of the fast serial kernel and of the reference
        at 2 threads on 20,000 in-view sand scatterers (80 channels)

Run one tree against another by alternating processes, the other tree with
``PYTHONPATH=<its worktree>`` (benchmarks/results/bench_synthesis_bundles.json).
"""
import dataclasses
import os
import pickle
import sys
import time
from pathlib import Path

import numba
import numpy as np

if "PYTHONPATH" not in os.environ:      # else: the tree PYTHONPATH names
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sim_device import environment_source as es  # noqa: E402
from sim_device import synthesis as S  # noqa: E402
from sim_device.scene import load_scene  # noqa: E402
from svss_daq.config import HardwareConfig, config_path, load_with_text  # noqa: E402

DIR = Path(".")


def capture(out: Path):
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    def scene(kind):
        sand = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
        if kind == "water":
            demo = load_scene(config_path("scenes/demo.toml"))
            sc = dataclasses.replace(sand.scattering, interface=False, volume=False,
                                     specular=False)
            return dataclasses.replace(demo, scattering=sc)
        sc = dataclasses.replace(sand, targets=())
        if kind == "exact":
            sc = dataclasses.replace(sc, scattering=dataclasses.replace(
                sc.scattering, precision="exact"))
        return sc

    for kind in ("water", "sand", "exact"):
        src = es.EnvironmentSource(hw, scene(kind))
        cap = {}
        orig_t, orig_f = es.transmit_legs, es.accumulate_fast
        orig_s = es.accumulate_fast_serial
        def tl(*a):
            cap["t"] = [np.copy(x) if isinstance(x, np.ndarray) else x for x in a]
            return orig_t(*a)
        def af(*a):
            cap["f"] = list(a)
            return orig_f(*a)
        def afs(*a):
            cap["f"] = list(a)
            return orig_s(*a)
        es.transmit_legs, es.accumulate_fast, es.accumulate_fast_serial = tl, af, afs
        src.scattered(100 if kind != "water" else 40)
        es.transmit_legs, es.accumulate_fast = orig_t, orig_f
        es.accumulate_fast_serial = orig_s
        f = cap["f"]
        print(kind, "pass 1 scatterers", cap["t"][0].size, "pass 2", f[0].size, "n_buf",
              f[27], "img", f[6].shape)
        with open(out / f"{kind}.pkl", "wb") as fh:
            pickle.dump(cap, fh)


def load(kind):
    with open(DIR / f"{kind}.pkl", "rb") as fh:
        return pickle.load(fh)

def sub(f, n, seed=0):
    ns = f[0].size
    if ns <= n:
        return list(f)
    idx = np.sort(np.random.default_rng(seed).choice(ns, n, replace=False))
    return [a[idx] for a in f[:6]] + list(f[6:])

def fast_args(f):
    # f: 27 positional + n_buf, n_blocks, zmax
    return f[:27], f[27], f[29]

def ref_buf(f):
    return np.zeros((f[6].shape[0], f[27]), dtype=np.complex128)

def compare(out):
    res = {}
    for kind in ("water", "sand", "exact"):
        cap = load(kind)
        t = [np.copy(x) if isinstance(x, np.ndarray) else x for x in cap["t"]]
        if kind != "water":   # pass 1 on 40000 scatterers
            n = 40000
            ns = cap["t"][0].size
            t = [a[:n] if isinstance(a, np.ndarray) and a.ndim >= 1 and a.shape[0] == ns
                 else a for a in t]
        S.transmit_legs(*t)
        res[f"{kind}_p1_tau"] = t[-2]; res[f"{kind}_p1_amp"] = t[-1]
        f = sub(cap["f"], 20000 if kind == "sand" else 4000)
        a27, n_buf, zmax = fast_args(f)
        buf = ref_buf(f)
        res[f"{kind}_ref_n"] = S.accumulate(*a27, buf); res[f"{kind}_ref"] = buf
        b, n = S.accumulate_fast(*a27, n_buf, 2 * numba.get_num_threads(), zmax)
        res[f"{kind}_fast"] = b; res[f"{kind}_fast_n"] = n
        b, n = S.accumulate_fast_serial(*a27, n_buf, 1, zmax)
        res[f"{kind}_ser"] = b; res[f"{kind}_ser_n"] = n
        print(kind, "echoes ref", res[f"{kind}_ref_n"].sum(), "fast",
              res[f"{kind}_fast_n"].sum(), flush=True)
    np.savez(out, **res)

def bench(label, reps=5):
    f = sub(load("sand")["f"], 20000)
    a27, n_buf, zmax = fast_args(f)
    numba.set_num_threads(2)
    S.accumulate_fast_serial(*a27, n_buf, 1, zmax)
    S.accumulate(*a27, ref_buf(f))
    ts, tr = [], []
    for _ in range(reps):
        c0 = time.process_time()
        _, n = S.accumulate_fast_serial(*a27, n_buf, 1, zmax)
        ts.append(time.process_time() - c0)
    for _ in range(reps):
        buf = ref_buf(f)
        c0 = time.process_time()
        S.accumulate(*a27, buf)
        tr.append(time.process_time() - c0)
    print(f"{label}: fast serial {min(ts):.4f} s ({min(ts) / n.sum() * 1e9:.1f} ns/echo, "
          f"{n.sum()} echoes); reference {min(tr):.4f} s", flush=True)

if __name__ == "__main__":
    cmd = sys.argv[1]
    DIR = Path(sys.argv[2])
    if cmd == "capture":
        DIR.mkdir(parents=True, exist_ok=True)
        capture(DIR)
    elif cmd == "compare":
        compare(sys.argv[3])
    else:
        bench(sys.argv[3], int(sys.argv[4]) if len(sys.argv) > 4 else 5)
