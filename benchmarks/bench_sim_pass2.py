#!/usr/bin/env python
"""Where the simulator's pass 2 spends its time: the receive legs, the echoes' phases and
weights, and their deposit into the baseband buffer.

Pass 2 (``sim_device.synthesis_fast.accumulate_fast_kernel``) computes, per scatterer, the
receive legs to every channel, then each echo's phase and Lagrange weights, then adds the
echo's four taps into the thread's buffer. To split its time, this benchmark builds two
scratch copies of ``sim_device/synthesis_fast.py`` in a temporary folder (nothing in the
project changes):

* ``no_deposit``: the four-tap add replaced by a comparison (the echoes are still formed);
* ``legs_only``: the echo loop removed (the receive legs only).

Each variant and the project's own kernel run in a process of their own on the same
pings of the seed sand scene (``--pings`` from ping 100, one untimed ping first: numba
compiles or loads), alternated ``--rounds`` times; the median pass-2 time per ping of each
is reported, and the stages before it (generation, transmit legs) and after it (the
passband FFTs, the coherent paths) from the project's own run. The variants' echoes are
wrong by construction: they time, they do not simulate.

    python benchmarks/bench_sim_pass2.py --pings 10 --rounds 2 --out benchmarks/results/bench_sim_pass2.json
"""

from __future__ import annotations

import argparse
import json
import logging
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_isa import machine_isa  # noqa: E402

log = logging.getLogger("bench_sim_pass2")

_DEPOSIT = """                            _add_taps(buf, ch, 2 * e_i[ch] - 2, re, im, e_w[ch, 0],
                                      e_w[ch, 1], e_w[ch, 2], e_w[ch, 3])
                            n_add += 1"""
_ECHO_LOOP = "                    for a in range(nt):\n                        if not allowed[a, b] or zk > zmax[a, b]:"
_AFTER = "        counts[blk] = n_add"

#: run in a child process: argv = variant folder (or ""), variant name, first ping, pings
_CHILD = r"""
import importlib, json, sys, time
import numpy as np
folder, name, first, n = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
import sim_device.environment_source as es
if folder:
    sys.path.insert(0, folder)
    es.accumulate_fast = importlib.import_module(name).accumulate_fast
from sim_device.scene import load_scene
from svss_daq.config import HardwareConfig, config_path, load_with_text
hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
src = es.EnvironmentSource(hw, load_scene(config_path("scenes/seed_cylinder_sand.toml")))
src.pressure(first - 1)
rows = []
for i in range(first, first + n):
    g = src.frame(i)
    src.last_stats = {}
    t0 = time.perf_counter()
    src.scattered(i, g)
    t1 = time.perf_counter()
    src.specular(i, g)
    t2 = time.perf_counter()
    s = dict(src.last_stats)
    rows.append({"pass2_s": s["receive_s"], "generate_s": s["generate_s"],
                 "transmit_s": s["transmit_s"],
                 "passband_s": s["scattered_s"] - s["generate_s"] - s["transmit_s"]
                 - s["receive_s"], "specular_s": t2 - t1, "echoes": s["echoes"]})
print(json.dumps(rows))
"""


def variants(folder: Path) -> dict[str, Path]:
    """The scratch copies of ``sim_device/synthesis_fast.py`` in ``folder``, by name."""
    src = (ROOT / "sim_device" / "synthesis_fast.py").read_text()
    # its relative imports made absolute: the copies live outside the package
    src = re.sub(r"^from \.(\w)", r"from sim_device.\1", src, flags=re.MULTILINE)
    for part in (_DEPOSIT, _ECHO_LOOP, _AFTER):
        if part not in src:
            raise SystemExit("sim_device/synthesis_fast.py: the text "
                             f"{part.splitlines()[0]!r} this benchmark edits is gone; "
                             "update bench_sim_pass2.py")
    no_deposit = src.replace(_DEPOSIT, "                            n_add += 1 if re + im > 1e300 else 0")
    i0, i1 = no_deposit.index(_ECHO_LOOP), no_deposit.index(_AFTER)
    legs_only = (no_deposit[:i0] + "                    n_add += 1 if wk[8, 0] > 1e300 else 0\n"
                 + no_deposit[i1:])
    out = {}
    for name, text in (("no_deposit", no_deposit), ("legs_only", legs_only)):
        p = folder / f"synth_{name}.py"
        p.write_text(text)
        out[name] = p
    return out


def run_one(folder: str, module: str, first: int, n: int) -> list[dict]:
    res = subprocess.run([sys.executable, "-c", _CHILD, folder, module, str(first), str(n)],
                         capture_output=True, text=True, cwd=ROOT, check=False)
    if res.returncode:
        raise SystemExit(f"{module or 'project'}: rc {res.returncode}\n{res.stderr[-2000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pings", type=int, default=10)
    ap.add_argument("--first", type=int, default=100)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    with tempfile.TemporaryDirectory(prefix="svss_pass2_") as tmp:
        paths = variants(Path(tmp))
        runs: dict[str, list[dict]] = {"project": [], "no_deposit": [], "legs_only": []}
        for r in range(args.rounds):
            for name in runs:
                folder, module = ("", "") if name == "project" else (tmp, paths[name].stem)
                rows = run_one(folder, module, args.first, args.pings)
                runs[name].extend(rows)
                log.info("round %d %-10s pass 2 %.3f s/ping (median)", r + 1, name,
                         np.median([x["pass2_s"] for x in rows]))
    med = {k: float(np.median([x["pass2_s"] for x in v])) for k, v in runs.items()}
    own = runs["project"]
    other = {k: float(np.median([x[k] for x in own]))
             for k in ("generate_s", "transmit_s", "passband_s", "specular_s")}
    echoes = float(np.median([x["echoes"] for x in own]))
    split = {"receive_legs_s": med["legs_only"],
             "echo_phase_and_weights_s": med["no_deposit"] - med["legs_only"],
             "deposit_s": med["project"] - med["no_deposit"]}
    result = {"command": "python benchmarks/bench_sim_pass2.py " + " ".join(argv or sys.argv[1:]),
              "machine": machine_isa(), "pings": args.pings, "rounds": args.rounds,
              "echoes_per_ping": echoes, "pass2_s_per_ping": med, "split_s_per_ping": split,
              "other_stages_s_per_ping": other,
              "per_ping_s": med["project"] + sum(other.values())}
    for k, v in split.items():
        log.info("%-26s %.3f s/ping (%.0f %% of pass 2)", k, v, 100 * v / med["project"])
    for k, v in other.items():
        log.info("%-26s %.3f s/ping", k, v)
    log.info("per ping %.3f s, %.1f M echoes", result["per_ping_s"], echoes / 1e6)
    if args.out:
        args.out.write_text(json.dumps(result, indent=1) + "\n")
        log.info("saved %s", args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
