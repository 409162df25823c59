#!/usr/bin/env python
"""The products of one tile, stage by stage, as the worker makes them: the chain
(background, normalisation, compression and MIPs, detection), the products PNG and the
tile file (``svss_proc.products.chain.save_tile`` with a stage clock), on a real tile.

The tile comes from a folder of tiles that ``svss process`` wrote (its image, coverage
and track; ``--index`` picks it, default 1) with its neighbours' planes across the seams
(tiles ``index - 1`` and ``index + 1`` when present), as in the worker. Its products are
made ``--repeat`` times and the fastest of each stage is kept.

``--baseline DIR`` runs the same measurement with the source tree ``DIR`` (for example
a ``git worktree`` of the commit before a change) in a child process, alternating with
this tree's, ``--repeat`` times each, so that old and new share the same minutes of a
noisy machine; the ratios are printed. Every figure comes with the load average and the
instruction set (``bench_isa.machine_isa``).

    svss process RUN.h5 --out TILES          # once, e.g. bench_live's cached sand line
    python benchmarks/bench_products.py --tiles TILES [--index 1] [--repeat 3]
        [--baseline /tmp/base] --out benchmarks/results/bench_products.json
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

log = logging.getLogger("bench_products")

#: the stages reported, in the worker's stage clock names
STAGES = ("products.background", "products.normalisation",
          "products.compression_and_mips", "products.detection", "products.features",
          "products.chain",
          "products.quicklook_png", "products.tile_file", "products")


def _tile_from_file(path: Path):
    """A :class:`~svss_proc.tiles.Tile` rebuilt from a tile file: image, coverage
    (the projector height from the file; no aperture span), pings and track."""
    import numpy as np

    from svss_proc.imaging.coverage import Coverage
    from svss_proc.imaging.grid import TileGrid
    from svss_proc.tiles import Tile, read_tile, tile_line

    t = read_tile(path)
    a = t["attrs"]
    grid = TileGrid(int(a["tile_index"]), t["along"], t["cross"], t["depth"])
    image = t["image"]
    tile = Tile(grid, tile_line(a), np.ascontiguousarray(image.real),
                np.ascontiguousarray(image.imag), pings=[int(s) for s in t["ping_sequence"]],
                updates=int(a.get("voxel_channel_updates", 0)),
                run_id=str(a.get("run_id", "")))
    if "ping_time" in t:
        tile.track = list(zip(t["ping_time"].tolist(), t["ping_north_m"].tolist(),
                              t["ping_east_m"].tolist()))
    if "coverage_pings" in t:
        n = len(tile.pings)
        tile.coverage = Coverage(t["coverage_pings"], t["coverage_channels"],
                                 int(a.get("coverage_n_channels", 0)), np.zeros((0, 3)),
                                 float(a.get("projector_height_m", float("nan"))) * n, n)
    return tile, t


def measure(tiles: Path, index: int, repeat: int) -> dict:
    """The stage times (CPU and wall, s; the fastest of ``repeat``) of tile ``index``'s
    products with this interpreter's ``svss_proc``."""
    import numpy as np

    from svss_daq.config import HardwareConfig, ProcessingConfig, config_path, load_with_text
    from svss_proc.live_clock import StageClock
    from svss_proc.products import chain
    from svss_proc.tiles import tile_file_paths

    hardware = load_with_text(HardwareConfig, config_path("hardware.toml"))
    processing = load_with_text(ProcessingConfig, config_path("processing.toml"))
    pcfg = processing.value.products
    planes = chain.kernel_voxels(pcfg.background.kernel_m,
                                 processing.value.tile.voxel_m)[0] // 2
    tile, _ = _tile_from_file(tile_file_paths(tiles, index)[0])
    prev_path, next_path = (tile_file_paths(tiles, index + d)[0] for d in (-1, 1))
    before = after = None
    if prev_path.exists():
        prev, t = _tile_from_file(prev_path)
        d = t["detections"]
        before = chain.Before(index - 1, tile.line, np.abs(prev.image[-planes:]),
                              prev.coverage.channels[-planes:].copy(),
                              np.stack([d["along_m"], d["cross_m"], d["depth_m"]], axis=1),
                              np.asarray(d["peak_db"], dtype=np.float64))
    if next_path.exists():
        nxt, _ = _tile_from_file(next_path)
        after = (np.abs(nxt.image[:planes]), nxt.coverage.channels[:planes].copy())
    best: dict[str, dict] = {}
    with tempfile.TemporaryDirectory(prefix="bench_products_") as tmp:
        # once to compile (or load the numba caches), then timed
        for rep in range(repeat + 1):
            tile.__dict__.pop("image", None)         # rebuilt as in the worker
            tile.after = after
            seams = chain.Seams()
            seams.last = before
            clock = StageClock()
            with clock.stage("products"):
                files = chain.save_tile(tile, Path(tmp) / f"r{rep}", hardware, processing,
                                        seams, clock=clock)
            size = {p.suffix: p.stat().st_size for p in files}
            if rep == 0:
                continue
            for k, v in clock.totals().items():
                b = best.setdefault(k, {"cpu_s": v["cpu_s"], "wall_s": v["wall_s"]})
                b["wall_s"] = min(b["wall_s"], v["wall_s"])
                if v["cpu_s"] is not None:
                    b["cpu_s"] = min(b["cpu_s"], v["cpu_s"])
    return {"stages": best, "bytes": size, "tile": str(tile_file_paths(tiles, index)[0]),
            "seam_planes": [0 if before is None else planes, 0 if after is None else planes],
            "numba_threads": __import__("numba").get_num_threads()}


def _child(tree: Path, args) -> dict:
    """:func:`measure` in a child process with ``tree``'s ``svss_proc`` and config (this
    file from this tree: ``benchmarks`` is a namespace package)."""
    code = ("import json, pathlib, sys; sys.path[:0] = sys.argv[1:3]; "
            "from benchmarks.bench_products import measure; "
            "print('RESULT' + json.dumps(measure(pathlib.Path(sys.argv[3]), "
            "int(sys.argv[4]), 1)))")
    out = subprocess.run([sys.executable, "-c", code, str(tree), str(ROOT), str(args.tiles),
                          str(args.index)], cwd=tree, env={**os.environ, "PYTHONPATH": str(tree)},
                         capture_output=True, text=True)
    if out.returncode:
        raise RuntimeError(f"{tree}: the measurement failed: {out.stderr[-3000:]}")
    line = [s for s in out.stdout.splitlines() if s.startswith("RESULT")][-1]
    return json.loads(line[len("RESULT"):])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tiles", required=True, type=Path, help="folder of tile files")
    ap.add_argument("--index", type=int, default=1, help="the tile measured")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--baseline", type=Path, default=None,
                    help="a source tree to compare with (e.g. a git worktree)")
    ap.add_argument("--out", default="bench_products.json")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    sys.path.insert(0, str(ROOT))
    from benchmarks.bench_isa import machine_isa

    res = {"command": " ".join(["python", os.path.relpath(sys.argv[0], ROOT)] + sys.argv[1:]),
           "machine": machine_isa(), "load_before": os.getloadavg(), "trees": {}}
    trees = {"new": ROOT} | ({"baseline": args.baseline.resolve()} if args.baseline else {})
    runs: dict[str, list] = {k: [] for k in trees}
    for rep in range(args.repeat):
        for name, tree in trees.items():
            r = _child(tree, args)
            r["load"] = os.getloadavg()[0]
            runs[name].append(r)
            log.info("%s, repeat %d: products %.2f s (load %.2f)", name, rep,
                     r["stages"]["products"]["wall_s"], r["load"])
    for name, rs in runs.items():
        best = {}
        for r in rs:
            for k, v in r["stages"].items():
                b = best.setdefault(k, dict(v))
                b["wall_s"] = min(b["wall_s"], v["wall_s"])
                if v["cpu_s"] is not None and b["cpu_s"] is not None:
                    b["cpu_s"] = min(b["cpu_s"], v["cpu_s"])
        res["trees"][name] = {"tree": str(trees[name]), "best": best, "runs": rs,
                              "bytes": rs[-1]["bytes"]}
    res["load_after"] = os.getloadavg()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(res, indent=1))
    print(report(res))
    print(f"saved {args.out}")
    return 0


def report(res: dict) -> str:
    m = res["machine"]
    names = list(res["trees"])
    lines = [f"{m['cpu']} ({', '.join(m['isa'])}), {m['cores']} cores; load "
             f"{res['load_before'][0]:.2f} before, {res['load_after'][0]:.2f} after; "
             f"fastest of {len(res['trees'][names[0]]['runs'])} runs each, alternated"]
    head = f"  {'stage':32s}" + "".join(f"{n + ' CPU s':>17s}{n + ' wall s':>17s}"
                                         for n in names)
    if "baseline" in names:
        head += f"{'wall new/old':>14s}"
    lines.append(head)
    for s in STAGES:
        row = f"  {s:32s}"
        for n in names:
            v = res["trees"][n]["best"].get(s)
            cpu = "" if v is None or v["cpu_s"] is None else f"{v['cpu_s']:.3f}"
            wall = "" if v is None else f"{v['wall_s']:.3f}"
            row += f"{cpu:>17s}{wall:>17s}"
        if "baseline" in names:
            a = res["trees"]["new"]["best"].get(s)
            b = res["trees"]["baseline"]["best"].get(s)
            if a and b and b["wall_s"] > 0:
                row += f"{a['wall_s'] / b['wall_s']:>14.2f}"
        lines.append(row)
    for n in names:
        lines.append(f"  {n}: files {res['trees'][n]['bytes']} bytes")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
