#!/usr/bin/env python
"""What the recordings' checksums cost: HDF5's Fletcher-32 on every ping's samples (one
chunk per ping) and on every tile volume, side by side with and without it in one run,
against the time a ping takes to record (the ping interval) and to image (measured here
on a default tile with the shipped processing).

    python benchmarks/bench_checksums.py --out benchmarks/results/bench_checksums.json
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_isa import machine_isa  # noqa: E402
from svss_daq.config import HardwareConfig, config_path, load_with_text  # noqa: E402


def _samples_file(path: Path, pings: np.ndarray, fletcher32: bool) -> tuple[float, float]:
    """(write, read) seconds per ping of ``pings`` as the raw run stores them."""
    n = pings.shape[0]
    t0 = time.perf_counter()
    with h5py.File(path, "w") as f:
        ds = f.create_dataset("backscatter_r", shape=(0,) + pings.shape[1:],
                              maxshape=(None,) + pings.shape[1:], dtype="<i4",
                              chunks=(1,) + pings.shape[1:], fletcher32=fletcher32)
        for i in range(n):
            ds.resize(i + 1, axis=0)
            ds[i] = pings[i]
        f.flush()
    write = (time.perf_counter() - t0) / n
    t0 = time.perf_counter()
    with h5py.File(path, "r") as f:
        ds = f["backscatter_r"]
        for i in range(n):
            ds[i]
    return write, (time.perf_counter() - t0) / n


def _volume_file(path: Path, image: np.ndarray, fletcher32: bool) -> tuple[float, float]:
    """(write, read) seconds of a tile's complex image as the tiles store it."""
    from svss_proc.tiles import _plain
    opts = _plain(image.shape, image.itemsize)
    if not fletcher32:
        opts.pop("fletcher32", None)
    t0 = time.perf_counter()
    with h5py.File(path, "w") as f:
        f.create_dataset("image", data=image, **opts)
    write = time.perf_counter() - t0
    t0 = time.perf_counter()
    with h5py.File(path, "r") as f:
        f["image"][()]
    return write, time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pings", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", default="bench_checksums.json")
    args = ap.parse_args(argv)
    hw = load_with_text(HardwareConfig, config_path("hardware.toml")).value
    dig = hw.digitiser
    rng = np.random.default_rng(5)
    pings = rng.integers(-2 ** 20, 2 ** 20, size=(args.pings, dig.n_channels,
                                                 dig.window_samples), dtype=np.int32)
    from svss_daq.config import ProcessingConfig, load
    from svss_proc.imaging.grid import tile_grid
    shape = tile_grid(load(ProcessingConfig, config_path("processing.toml")).tile, 0).shape
    image = (rng.normal(size=shape) + 1j * rng.normal(size=shape)).astype(np.complex64)
    res = {}
    with tempfile.TemporaryDirectory() as d:
        for name, fn, data in (("ping samples", _samples_file, pings),
                               ("tile image", _volume_file, image)):
            runs = {flag: [fn(Path(d) / f"{flag}.h5", data, flag)
                           for _ in range(args.repeat)] for flag in (False, True)}
            row = {}
            for k, what in ((0, "write_s"), (1, "read_s")):
                plain = statistics.median(r[k] for r in runs[False])
                summed = statistics.median(r[k] for r in runs[True])
                row[what] = {"plain": plain, "fletcher32": summed,
                             "added": summed - plain, "ratio": summed / plain}
            res[name] = row
    interval = hw.sequencer.ping_interval_s
    per_ping = res["ping samples"]
    added_record = max(per_ping["write_s"]["added"], 0.0)
    added_read = max(per_ping["read_s"]["added"], 0.0)
    doc = {"command": " ".join(["python", *sys.argv]), "machine": machine_isa(),
           "date": time.strftime("%Y-%m-%d"), "pings": args.pings,
           "ping_bytes": int(pings[0].nbytes), "tile_image_bytes": int(image.nbytes),
           "results": res, "ping_interval_s": interval,
           "record_fraction_of_interval": added_record / interval,
           "read_added_s_per_ping": added_read}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=1))
    for name, row in res.items():
        for what, v in row.items():
            print(f"{name:<13} {what:<8} plain {1e3 * v['plain']:8.3f} ms, Fletcher-32 "
                  f"{1e3 * v['fletcher32']:8.3f} ms ({v['ratio']:.3f}x, "
                  f"+{1e3 * v['added']:.3f} ms)")
    print(f"recording: +{1e3 * added_record:.3f} ms a ping, "
          f"{100 * added_record / interval:.2f} % of the {interval} s ping interval")
    return 0


if __name__ == "__main__":
    sys.exit(main())
