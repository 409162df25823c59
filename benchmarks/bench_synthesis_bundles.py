#!/usr/bin/env python
"""The synthesis kernels alone, through their front doors, on inputs captured once from
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
``PYTHONPATH=<its worktree>`` (benchmarks/results/bench_synthesis_bundles.json). The
front doors take the bundles of ``sim_device.synthesis_args`` since issue 50
(``transmit_legs(pts, samp, img, medium, beam, out, fast)``, pass 2 one ``Pass2``): a
tree before it takes this script as it was before that change (positional arguments).
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
        def tl(pts, samp, img, medium, beam, out, fast=False):
            cap["t"] = (pts, samp, img, medium, beam, out)
            return orig_t(pts, samp, img, medium, beam, out, fast)
        def af(p2, n_buf, *rest):
            cap["f"] = (p2, n_buf)
            return orig_f(p2, n_buf, *rest)
        def afs(p2, n_buf, *rest):
            cap["f"] = (p2, n_buf)
            return orig_s(p2, n_buf, *rest)
        es.transmit_legs, es.accumulate_fast, es.accumulate_fast_serial = tl, af, afs
        src.scattered(100 if kind != "water" else 40)
        es.transmit_legs, es.accumulate_fast = orig_t, orig_f
        es.accumulate_fast_serial = orig_s
        p2, n_buf = cap["f"]
        print(kind, "pass 1 scatterers", cap["t"][0].x.size, "pass 2", p2.pts.x.size,
              "n_buf", n_buf, "img", p2.paths.img.shape)
        with open(out / f"{kind}.pkl", "wb") as fh:
            pickle.dump(cap, fh)


def load(kind):
    with open(DIR / f"{kind}.pkl", "rb") as fh:
        return pickle.load(fh)


def rows(bundle, idx):
    """``bundle`` (Points or TransmitLegs) with the scatterers ``idx`` only."""
    return type(bundle)(*(a[idx] for a in bundle))


def sub(f, n, seed=0):
    """The captured pass 2 (Pass2, n_buf) cut to ``n`` scatterers."""
    p2, n_buf = f
    ns = p2.pts.x.size
    if ns <= n:
        return p2, n_buf
    idx = np.sort(np.random.default_rng(seed).choice(ns, n, replace=False))
    return p2._replace(pts=rows(p2.pts, idx), legs_t=rows(p2.legs_t, idx)), n_buf


def ref_buf(p2, n_buf):
    return np.zeros((p2.paths.img.shape[0], n_buf), dtype=np.complex128)


def compare(out):
    res = {}
    for kind in ("water", "sand", "exact"):
        cap = load(kind)
        pts, samp, img, medium, beam, legs = cap["t"]
        if kind != "water":   # pass 1 on 40000 scatterers
            idx = np.arange(min(40000, pts.x.size))
            pts, samp, legs = rows(pts, idx), samp[idx], rows(legs, idx)
        legs = type(legs)(*(np.empty_like(a) for a in legs))
        S.transmit_legs(pts, samp, img, medium, beam, legs, True)
        res[f"{kind}_p1_tau"], res[f"{kind}_p1_amp"] = legs
        p2, n_buf = sub(cap["f"], 20000 if kind == "sand" else 4000)
        buf = ref_buf(p2, n_buf)
        res[f"{kind}_ref_n"] = S.accumulate(p2, buf); res[f"{kind}_ref"] = buf
        b, n = S.accumulate_fast(p2, n_buf, 2 * numba.get_num_threads())
        res[f"{kind}_fast"] = b; res[f"{kind}_fast_n"] = n
        b, n = S.accumulate_fast_serial(p2, n_buf)
        res[f"{kind}_ser"] = b; res[f"{kind}_ser_n"] = n
        print(kind, "echoes ref", res[f"{kind}_ref_n"].sum(), "fast",
              res[f"{kind}_fast_n"].sum(), flush=True)
    np.savez(out, **res)


def bench(label, reps=5):
    p2, n_buf = sub(load("sand")["f"], 20000)
    numba.set_num_threads(2)
    S.accumulate_fast_serial(p2, n_buf)
    S.accumulate(p2, ref_buf(p2, n_buf))
    ts, tr = [], []
    for _ in range(reps):
        c0 = time.process_time()
        _, n = S.accumulate_fast_serial(p2, n_buf)
        ts.append(time.process_time() - c0)
    for _ in range(reps):
        buf = ref_buf(p2, n_buf)
        c0 = time.process_time()
        S.accumulate(p2, buf)
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
