"""Imaging options: time per tile against image error.

Every row images the same pings into the same sub-tile with one option changed from
the default processing (``config/processing.toml``); the reference is the most
faithful setting (cubic interpolation, float64, exact Fermat delays at the top
sediment's speed, 4x upsampling, the default voxel, all channels). Errors against it:

* ``rel_rms_db``: 20 log10 ||I - I_ref|| / ||I_ref|| of the complex image (rows on a
  coarser voxel grid: of the magnitude, against the reference magnitude interpolated
  to their voxel centres);
* ``peak_db``: the brightest voxel's level re the reference's (channel subsets are
  scaled by all/used channels, as a coherent sum is);
* ``peak_shift_m``: distance between the brightest voxels.

Time: the sub-tile's imaging seconds (kernels compiled beforehand), with the pings'
conditioning timed apart, extrapolated to a full tile of the processing configuration
(imaging x its volume ratio, conditioning x the pings of a tile); ``cpu_s``: the CPU
seconds of all threads over the same imaging (steadier on a shared machine). Over a
refracting seabed the options are measured a second time about table delays
("with table delays"), where the straight rays' error no longer hides them.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from svss_daq.config import HardwareConfig, Loaded, ProcessingConfig
from svss_proc.imaging.imager import TileImager

from .workloads import Workload, extrapolation

log = logging.getLogger(__name__)


def make_imager(hw: Loaded[HardwareConfig], proc: ProcessingConfig,
                channels: np.ndarray | None) -> TileImager:
    """A tile imager that sums only ``channels`` (None: all)."""
    return TileImager(hw, proc, channels=channels)


def channel_subsets(hw: HardwareConfig) -> dict[str, np.ndarray | None]:
    """all; every other element (twice the pitch, half the channels); the aft section."""
    n = hw.digitiser.n_channels
    aft = hw.receive_array.sections[0]
    return {"all": None, "every other": np.arange(0, n, 2),
            f"{aft.name.split(' (')[0]} only": np.arange(aft.rows * aft.cols)}


def only_tile(imager: TileImager, index: int, span: int = 1000) -> TileImager:
    """Restrict ``imager`` to tile ``index``: it skips tiles it has written, so the
    neighbours are marked written (the pings' other tiles would cost time for nothing)."""
    imager.schedule.mark_done(k for k in range(index - span, index + span + 1)
                              if k != index)
    return imager


def image(hw, proc, pings, index: int, channels=None):
    """(complex image of tile ``index`` (float64 planes), grid, imaging seconds,
    conditioning seconds, updates, imaging CPU seconds). Kernels are compiled beforehand
    by one untimed ping."""
    only_tile(make_imager(hw, proc, channels), index).add(pings[len(pings) // 2])
    imager = only_tile(make_imager(hw, proc, channels), index)
    t_cond = 0.0
    for p in pings:                       # conditioning alone, for the extrapolation
        t0 = time.perf_counter()
        imager.accumulator.condition(p)
        t_cond += time.perf_counter() - t0
    t0 = time.perf_counter()
    c0 = time.process_time()
    tiles = []
    for p in pings:
        tiles += imager.add(p)
    tiles += imager.finish()
    el = time.perf_counter() - t0
    cpu = time.process_time() - c0                 # CPU seconds, all threads
    tile = next((t for t in tiles if t.grid.index == index), None)
    if tile is None:
        raise RuntimeError(f"trade: the pings did not reach sub-tile {index}; got "
                           f"{[t.grid.index for t in tiles]}")
    img = tile.re.astype(np.float64) + 1j * tile.im.astype(np.float64)
    return img, tile.grid, el, t_cond, imager.updates, cpu


def _peak(img, grid):
    i = np.unravel_index(int(np.argmax(np.abs(img))), img.shape)
    return float(np.abs(img[i])), np.array([grid.along[i[0]], grid.cross[i[1]],
                                            grid.depth[i[2]]])


def errors(img, grid, ref, ref_grid, scale: float = 1.0) -> dict:
    """Errors of ``img`` (scaled by ``scale``) against the reference image."""
    img = img * scale
    if img.shape == ref.shape:
        diff = np.linalg.norm(img - ref) / np.linalg.norm(ref)
        basis = "complex"
    else:
        pts = np.stack(np.meshgrid(grid.along, grid.cross, grid.depth, indexing="ij"), -1)
        interp = RegularGridInterpolator((ref_grid.along, ref_grid.cross, ref_grid.depth),
                                         np.abs(ref), bounds_error=False, fill_value=None)
        r = interp(pts.reshape(-1, 3)).reshape(img.shape)
        diff = np.linalg.norm(np.abs(img) - r) / np.linalg.norm(r)
        basis = "magnitude, resampled"
    p, pos = _peak(img, grid)
    p_ref, pos_ref = _peak(ref, ref_grid)
    return {"rel_rms_db": 20 * math.log10(max(diff, 1e-300)) if diff > 0 else -math.inf,
            "rel_rms": float(diff), "error_basis": basis,
            "peak_db": 20 * math.log10(p / p_ref), "peak_shift_m": float(
                np.linalg.norm(pos - pos_ref))}


def variants(proc: ProcessingConfig, hw: HardwareConfig, c_sed: float, quick: bool,
             cuda: bool) -> tuple[dict, list[tuple[str, str, dict]]]:
    """The reference setting and the rows (option, value, setting): one option changed
    from the default each, plus a few combined fast settings."""
    im = proc.imaging
    default = {"interpolation": im.interpolation, "precision": im.precision,
               "delays": im.delays, "voxel_m": proc.tile.voxel_m, "channels": "all",
               "upsample": proc.conditioning.upsample, "device": im.device,
               "method": im.method}
    ref = dict(default, interpolation="cubic", precision="float64", delays="exact",
               upsample=4, device="cpu", method="exact")
    rows = [("reference", "highest fidelity", ref), ("default", "processing.toml", default)]
    for interp in ("nearest", "linear", "cubic"):
        rows.append(("interpolation", interp, dict(default, interpolation=interp)))
    for prec in ("float32", "float64"):
        rows.append(("precision", prec, dict(default, precision=prec)))
    for d in ("straight", "table", "exact"):
        rows.append(("delays", d, dict(default, delays=d)))
    v0 = proc.tile.voxel_m
    for k in ((3,) if quick else (2, 3)):
        rows.append(("voxel_m", f"{v0 * k:g}", dict(default, voxel_m=v0 * k)))
    for name in list(channel_subsets(hw))[1:]:
        rows.append(("channels", name, dict(default, channels=name)))
    rows.append(("upsample", "4", dict(default, upsample=4)))
    # the live worker's method (docs/imaging.md: the live method), at the configured
    # lattice and one twice as coarse in area
    for m in ("exact", "factorised"):
        rows.append(("method", m, dict(default, method=m)))
    coarser = tuple(1.4 * h for h in im.factorised_step_m)
    rows.append(("method", "factorised, lattice {:.3g} x {:.3g} m".format(*coarser),
                 dict(default, method="factorised", factorised_step_m=coarser)))
    rows.append(("combined", "nearest, float32, 2x voxel",
                 dict(default, interpolation="nearest", precision="float32",
                      voxel_m=2 * v0 if not quick else 3 * v0)))
    rows.append(("combined", "cubic, float32, table", dict(default, interpolation="cubic",
                                                            precision="float32",
                                                            delays="table")))
    if cuda:
        rows.append(("device", "cuda", dict(default, device="cuda")))
    if abs(c_sed - im.water_sound_speed_m_s) > 1e-6 * c_sed and default["delays"] == "straight":
        # a refracting seabed: straight rays' error hides every other option's, so the
        # options are measured again about the refracted (table) delays
        base = dict(default, delays="table")
        for interp in ("nearest", "cubic"):
            rows.append(("with table delays", f"interpolation {interp}",
                         dict(base, interpolation=interp)))
        rows.append(("with table delays", "precision float64", dict(base, precision="float64")))
        rows.append(("with table delays", f"voxel_m {2 * v0:g}", dict(base, voxel_m=2 * v0)))
        for name in list(channel_subsets(hw))[1:]:
            rows.append(("with table delays", f"channels {name}", dict(base, channels=name)))
        rows.append(("with table delays", "upsample 4", dict(base, upsample=4)))
    # the same setting twice measures once: drop duplicates of the default
    seen, out = set(), []
    for opt, val, s in rows:
        key = tuple(sorted(s.items()))
        if opt not in ("reference", "default") and (key in seen):
            continue
        seen.add(key)
        out.append((opt, val, s))
    return ref, out


def configure(proc: ProcessingConfig, s: dict, workload: Workload,
              c_sed: float) -> ProcessingConfig:
    tile = dataclasses.replace(workload.tile, voxel_m=s["voxel_m"])
    im = dataclasses.replace(proc.imaging, interpolation=s["interpolation"],
                             precision=s["precision"], delays=s["delays"],
                             sediment_sound_speed_m_s=c_sed, device=s["device"],
                             method=s["method"], factorised_step_m=s.get(
                                 "factorised_step_m", proc.imaging.factorised_step_m))
    cond = dataclasses.replace(proc.conditioning, upsample=s["upsample"])
    return dataclasses.replace(proc, tile=tile, imaging=im, conditioning=cond)


def run(hw: Loaded[HardwareConfig], proc: ProcessingConfig, workload: Workload, pings,
        c_sed: float, quick: bool, cuda: bool) -> list[dict]:
    """Measure every imaging row on ``pings`` (the workload's)."""
    _, rows = variants(proc, hw.value, c_sed, quick, cuda)
    subsets = channel_subsets(hw.value)
    n_all = hw.value.digitiser.n_channels
    full = proc.tile
    spacing = workload.scene.track.speed_m_s * hw.value.sequencer.ping_interval_s
    out = []
    ref_img = ref_grid = default_img = None
    for opt, val, s in rows:
        p = configure(proc, s, workload, c_sed)
        ch = subsets[s["channels"]]
        img, grid, el, t_cond, upd, cpu = image(hw, p, pings, workload.tile_index, ch)
        if opt == "reference":
            ref_img, ref_grid = img, grid
        if opt == "default":
            default_img = img
        n_ch = n_all if ch is None else len(ch)
        err = errors(img, grid, ref_img, ref_grid, scale=n_all / n_ch)
        if default_img is not None and img.shape == default_img.shape:
            # against the default (the exact method's image): what a method alone costs
            err["vs_default_db"] = errors(img, grid, default_img, grid,
                                          scale=n_all / n_ch)["rel_rms_db"]
        ratio = extrapolation(p.tile, full)
        # the pings of a full tile: its length plus the workload's reach on both sides
        tile_pings = full.length_m / spacing + (len(pings) * workload.stride
                                                - workload.tile.length_m / spacing)
        tile_s = max(el - t_cond, 0.0) * ratio + t_cond / len(pings) * tile_pings
        out.append({"area": "imaging", "option": opt, "value": val, "setting": s,
                    "is_reference": opt == "reference", "is_default": opt == "default",
                    "time_s": el, "conditioning_s": t_cond, "tile_s": tile_s,
                    "cpu_s": cpu, "updates": int(upd), "error": err["rel_rms"],
                    "error_name": "relative RMS image error", "metrics": err})
        log.info("imaging %s=%s: %.3f s (%.1f s per tile), error %.1f dB", opt, val, el,
                 tile_s, err["rel_rms_db"])
    return out

