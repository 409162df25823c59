"""``svss inspect FILE``: a summary of a tile file or a raw-run file.

:func:`summarise` returns a JSON-serialisable dictionary (``kind`` is ``"tile"`` or
``"raw"``); :func:`format_summary` renders it as text.
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import numpy as np

from svss_daq import rawfile
from svss_daq.decibels import amplitude_to_db
from svss_daq.progress import Progress
from svss_daq.nav.renavigate import records_problem
from svss_proc import tiles
from svss_proc.products.circumstances import circumstances_text

log = logging.getLogger(__name__)


def file_kind(path: str | Path) -> str:
    """``"tile"`` or ``"raw"`` from the file's ``svss_format`` attribute."""
    fmt = rawfile.svss_format(path)
    if fmt == tiles.TILE_FORMAT:
        return "tile"
    if fmt == rawfile.FORMAT:
        return "raw"
    raise ValueError(f"{path}: svss_format is {fmt!r}; expected {tiles.TILE_FORMAT!r} or "
                     f"{rawfile.FORMAT!r}")


def summarise(path: str | Path) -> dict:
    """Summary of a tile or raw-run file (not of a tile still being written: see
    :func:`svss_proc.tiles.is_temporary`)."""
    if tiles.is_temporary(path):
        raise tiles.TileFileError(f"{path}: a temporary file of a tile being written (or "
                                  "left by a failed write); not read")
    return summarise_tile(path) if file_kind(path) == "tile" else summarise_raw(path)


def verify(path: str | Path) -> tuple[bool | None, list[str]]:
    """Read a tile or raw-run file whole against its checksums: (True: sound, False:
    damaged, None: written without checksums, cannot be verified; lines saying so, one
    per damaged ping or dataset)."""
    path = Path(path)
    if file_kind(path) == "tile":
        try:
            damaged = tiles.verify_tile(path)
        except tiles.TileFileError as exc:
            if "without checksums" in str(exc):
                return None, [str(exc)]
            raise
        what = "tile"
    else:
        with rawfile.RawRunReader(path) as r:
            if not r.verifiable:
                return None, [f"{path}: recorded without checksums (before they were "
                              "written): it cannot be verified"]
            progress = Progress(f"verifying {path.name}", len(r), log)
            damaged = r.verify(lambda n: progress.update(n - progress.done))
            what = f"{len(r)} pings"
    if damaged:
        return False, damaged
    return True, [f"{path}: {what} verified against their checksums: no damage"]


def _plain(v):
    if isinstance(v, bytes):
        return v.decode(errors="replace")
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    return v


def _db(x: float) -> float | None:
    """The level of an amplitude in dB, None where it has none (zero, not finite)."""
    v = float(amplitude_to_db(x))
    return v if math.isfinite(v) else None


def _axis(values: np.ndarray) -> dict:
    step = float(values[1] - values[0]) if values.size > 1 else None
    return {"n": int(values.size), "first_m": float(values[0]), "last_m": float(values[-1]),
            "step_m": step}


def summarise_tile(path: str | Path) -> dict:
    """Identity, grid, pings, image level, products and detections of a tile file."""
    path = Path(path)
    t = tiles.read_tile(path)
    attrs = {k: _plain(v) for k, v in t["attrs"].items()}
    axes = {d: t[d] for d in tiles.DIMS}
    pings = t["ping_sequence"]
    mag = t["magnitude"]
    bg_attrs = {k: _plain(v) for k, v in t.get("background_attrs", {}).items()}
    bg_med = None
    if "background" in t:
        b = t["background"]
        b = b[np.isfinite(b) & (b > 0)]
        bg_med = _db(float(np.median(b))) if b.size else None
    det = t["detections"]
    peak_idx = np.unravel_index(int(np.argmax(mag)), mag.shape) if mag.size else None
    nonzero = mag[mag > 0]
    out = {
        "kind": "tile", "file": str(path),
        "format_version": attrs.get("svss_format_version"),
        "tile_index": attrs.get("tile_index"),
        "shape": list(mag.shape),
        "axes": {d: _axis(v) for d, v in axes.items()},
        "line": {"origin_north_m": attrs.get("line_origin_north_m"),
                 "origin_east_m": attrs.get("line_origin_east_m"),
                 "heading_deg": math.degrees(attrs.get("line_heading_rad", float("nan"))),
                 "interface_down_m": attrs.get("interface_down_m")},
        "pings": {"n": int(pings.size),
                  "first": int(pings.min()) if pings.size else None,
                  "last": int(pings.max()) if pings.size else None},
        # what happened among its pings (None: a tile written before it was kept)
        "circumstances": {k: attrs.get(k) for k in ("pings_missing", "poses_dead_reckoned",
                                                    "poses_held")},
        "voxel_channel_updates": attrs.get("voxel_channel_updates"),
        "image": {
            "imaged_fraction": float(nonzero.size / mag.size) if mag.size else 0.0,
            "peak_db_re_upa": _db(float(mag.max())) if mag.size else None,
            "peak_at_m": [float(axes[d][i]) for d, i in zip(tiles.DIMS, peak_idx)]
            if peak_idx is not None else None,
            "median_db_re_upa": _db(float(np.median(nonzero))) if nonzero.size else None,
        },
        "products": t["products"],
        "background": ({"method": bg_attrs.get("background_method"),
                        "kernel_voxels": bg_attrs.get("background_kernel_voxels"),
                        "kernel_m": bg_attrs.get("background_kernel_m"),
                        "boundary": bg_attrs.get("background_boundary"),
                        "max_error_db": bg_attrs.get("background_max_error_db"),
                        "median_db_re_upa": bg_med} if "background" in t else None),
        "detections": [{k: _plain(row[k]) for k in det.dtype.names} for row in det],
        "provenance": {k: attrs.get(k) for k in ("software_name", "software_version",
                                                 "creation_time_utc", "hardware_config_id",
                                                 "processing_config_id")},
        "seabed": t.get("seabed"),
    }
    if "products_timing_s" in attrs:
        try:
            timing = json.loads(attrs["products_timing_s"])
            out["products_timing_s"] = {str(k): float(v) for k, v in timing.items()}
        except (TypeError, ValueError, AttributeError):
            raise tiles.TileFileError(
                f"{path}: root attribute 'products_timing_s' is "
                f"{attrs['products_timing_s']!r}; expected a JSON object of seconds per "
                "stage") from None
    return out


def summarise_raw(path: str | Path) -> dict:
    """Pings, timing, navigation, samples and provenance of a raw-run file."""
    path = Path(path)
    with rawfile.RawRunReader(path) as run:
        n = len(run)
        hw = run.hardware
        per_ping = run.ping_table()
        times, seq, proj = (per_ping[k] for k in ("ping_time", "ping_sequence",
                                                  "transmit_projector"))
        nav = run.nav_table()
        gaps = int(np.count_nonzero(np.diff(seq) != 1)) if n > 1 else 0
        channels, samples = run.shape
        out = {
            "kind": "raw", "file": str(path), "clean": run.clean,
            "checksums": run.verifiable,
            "format_version": _plain(run.attrs.get("svss_format_version")),
            "run_attrs": {k: _plain(v) for k, v in run.attrs.items()
                          if k not in rawfile.WRITER_ATTRS},
            "hardware": {"name": hw.value.name, "config_id": hw.id,
                         "channels": int(channels), "samples_per_ping": int(samples),
                         "sample_rate_hz": run.sample_rate_hz},
            "pings": {"n": n, "first_sequence": int(seq[0]) if n else None,
                      "last_sequence": int(seq[-1]) if n else None,
                      "sequence_gaps": gaps,
                      "projectors": {str(int(p)): int(c) for p, c in
                                     zip(*np.unique(proj, return_counts=True))}},
            "time": {"first_utc_ns": int(times[0]) if n else None,
                     "duration_s": float((times[-1] - times[0]) * 1e-9) if n else 0.0,
                     "median_interval_s": float(np.median(np.diff(times)) * 1e-9)
                     if n > 1 else None},
            "navigation": _nav_summary(nav, n),
            "environment": {k: _plain(v) for k, v in run.environment.items()},
            "nmea_sentences": len(run.nmea()),
            "pd0_ensembles": run.n_pd0, "ping_clock_events": len(run.ping_clock()),
            # why svss process cannot re-navigate the run (None: it can)
            "renavigation_problem": records_problem(run),
        }
        if n:
            s = run.ping(0).samples
            full = 2 ** (hw.value.digitiser.bits - 1)
            out["first_ping_samples"] = {
                "rms_counts": float(np.sqrt(np.mean(s.astype(np.float64) ** 2))),
                "peak_counts": int(np.abs(s).max()),
                "peak_fraction_of_full_scale": float(np.abs(s).max() / full)}
        if run.provenance:
            out["provenance"] = {k: _plain(v) for k, v in run.provenance.items()}
    return out


def _nav_summary(nav: dict, n: int) -> dict:
    if n == 0:
        return {}
    north, east = nav["north_m"], nav["east_m"]
    track = float(np.sum(np.hypot(np.diff(north), np.diff(east)))) if n > 1 else 0.0
    dt = (nav["time1"][-1] - nav["time1"][0]) * 1e-9
    return {"start_ne_m": [float(north[0]), float(east[0])],
            "end_ne_m": [float(north[-1]), float(east[-1])],
            "track_length_m": track,
            "mean_speed_m_s": track / dt if dt > 0 else None,
            "heading_deg": [float(np.degrees(nav["heading_rad"].min())),
                            float(np.degrees(nav["heading_rad"].max()))],
            "altitude_m": [float(nav["altitude_m"].min()), float(nav["altitude_m"].max())],
            "quality_flags": sorted({int(q) for q in np.unique(nav["quality"])})}


def format_summary(s: dict) -> str:
    """Human-readable text of a :func:`summarise` dictionary."""
    return _format_tile(s) if s["kind"] == "tile" else _format_raw(s)


def _f(v, fmt: str = ".2f", none: str = "-") -> str:
    return none if v is None else format(v, fmt)


def _circumstances(counts: dict) -> str:
    """"; gap 8 pings; dead-reckoned 22 poses" of a tile's pings ("" when none, or not
    known)."""
    said = circumstances_text({k: int(v) for k, v in counts.items() if v is not None})
    return f"; {said}" if said else ""


def _format_tile(s: dict) -> str:
    ax, ln, im = s["axes"], s["line"], s["image"]
    lines = [f"{s['file']}: SVSS tile {s['tile_index']} (format version "
             f"{s['format_version']})",
             f"  grid       {' x '.join(map(str, s['shape']))} voxels (along x cross x depth)"]
    for d in tiles.DIMS:
        a = ax[d]
        lines.append(f"  {d:<10} {a['first_m']:.3f} .. {a['last_m']:.3f} m, step "
                     f"{_f(a['step_m'], '.3f')} m ({a['n']} voxel centres)")
    lines += [
        f"  line       origin N {_f(ln['origin_north_m'])} E {_f(ln['origin_east_m'])} m, "
        f"heading {_f(ln['heading_deg'], '.1f')} deg, interface at "
        f"{_f(ln['interface_down_m'])} m down",
        f"  pings      {s['pings']['n']} (sequence {s['pings']['first']} .. "
        f"{s['pings']['last']}), {_f(s['voxel_channel_updates'], '.3g')} voxel-channel "
        "updates" + _circumstances(s.get("circumstances") or {}),
        f"  image      peak {_f(im['peak_db_re_upa'], '.1f')} dB re 1 uPa at "
        f"{_fmt_pos(im['peak_at_m'])}, median {_f(im['median_db_re_upa'], '.1f')} dB, "
        f"{100 * im['imaged_fraction']:.1f} % of voxels imaged",
        f"  products   {', '.join(s['products']) or 'none'}",
    ]
    b = s["background"]
    if b:
        lines.append(f"  background {b['method']} median, kernel "
                     f"{'x'.join(map(str, b['kernel_voxels']))} voxels "
                     f"({'x'.join(f'{k:g}' for k in b['kernel_m'])} m), {b['boundary']} "
                     f"boundary, max error {_f(b['max_error_db'], 'g')} dB; median "
                     f"{_f(b['median_db_re_upa'], '.1f')} dB re 1 uPa")
    if "products_timing_s" in s:
        lines.append("  timing     " + ", ".join(f"{k} {v:.2f} s"
                                                 for k, v in s["products_timing_s"].items()))
    sb = s.get("seabed")
    if sb:
        lines.append("  sediment   " + seabed_line(sb))
    det = s["detections"]
    lines.append(f"  detections {len(det)}")
    if det:
        lines.append("     #   along_m  cross_m  depth_m  excess_dB  peak_dB  extent_m "
                     "(a x c x d)")
        for i, d in enumerate(det[:20]):
            lines.append(f"    {i:2d} {d['along_m']:9.3f} {d['cross_m']:8.3f} "
                         f"{d['depth_m']:8.3f} {d['excess_db']:10.1f} {d['peak_db']:8.1f}  "
                         f"{d['extent_along_m']:.2f} x {d['extent_cross_m']:.2f} x "
                         f"{d['extent_depth_m']:.2f}")
        if len(det) > 20:
            lines.append(f"    ... {len(det) - 20} more")
    p = s["provenance"]
    lines.append(f"  provenance {p['software_name']} {p['software_version']}, created "
                 f"{p['creation_time_utc']}, hardware config {p['hardware_config_id']}, "
                 f"processing config {p['processing_config_id']}")
    return "\n".join(lines)


def seabed_line(sb: dict) -> str:
    """One line for the sediment speed (and the interface's slope, where it was
    estimated) a tile or run was imaged with (its ``seabed``)."""
    text = _speed_line(sb)
    slope = sb.get("interface_slope_deg")
    if slope is not None and None not in slope:
        sig = sb.get("interface_slope_sigma_deg") or [None, None]
        text += "; interface sloping " + ", ".join(
            f"{_f(v, '+.2f')}" + (f" +/- {_f(e, '.2f')}" if e is not None else "")
            + f" deg {name}" for v, e, name in zip(slope, sig, ("along", "across")))
    if sb.get("interface_relief") is not None:
        rms, sig = sb.get("interface_relief_rms_m"), sb.get("interface_relief_sigma_m")
        if sb["interface_relief"]:
            lo, hi = sb.get("interface_relief_range_m") or [None, None]
            text += (f"; interface relief {_f(100 * rms if rms is not None else None, '.1f')}"
                     f" cm rms ({_f(lo, '+.3f')} to {_f(hi, '+.3f')} m) on "
                     f"{sb.get('interface_relief_nodes')} nodes")
        else:
            text += (f"; no interface relief beyond its uncertainty "
                     f"({_f(100 * sig if sig is not None else None, '.2f')} cm a node)")
    tiles = sb.get("tiles") or []
    if len(tiles) > 1:
        text += ("; per tile " + ", ".join(
            f"{t['tile']}: {_f(t['speed_m_s'], '.0f')} +/- {_f(t['sigma_m_s'], '.0f')}"
            for t in tiles) + (" (they disagree: two sediments?)"
                               if sb.get("tiles_disagree") else ""))
    return text


def _speed_line(sb: dict) -> str:
    c = sb.get("sediment_sound_speed_m_s")
    if sb.get("status") == "estimated":
        text = (f"{_f(c, '.0f')} +/- {_f(sb.get('sigma_m_s'), '.0f')} m/s estimated from "
                f"{len(sb.get('responses') or [])} buried response(s)")
        if sb.get("disagrees"):
            text += f"; configured {_f(sb.get('configured_m_s'), '.0f')} m/s disagrees"
        return text
    if sb.get("status") == "unconstrained":
        return (f"{_f(c, '.0f')} m/s configured: not constrained by the echoes "
                f"({sb.get('reason')})")
    return f"{_f(c, '.0f')} m/s as configured"


def _fmt_pos(p) -> str:
    return "-" if p is None else "(" + ", ".join(f"{v:.3f}" for v in p) + ") m"


def _format_raw(s: dict) -> str:
    hw, pg, t, nav = s["hardware"], s["pings"], s["time"], s["navigation"]
    lines = [f"{s['file']}: SVSS raw run (format version {s['format_version']})"
             + ("" if s["clean"] else " -- NOT closed by its writer, read to last flush"),
             "  checksums  " + ("Fletcher-32 on every ping's samples (svss inspect --verify "
                               "reads them all)" if s.get("checksums") else
                               "none: recorded before checksums, cannot be verified"),
             "  run        " + (", ".join(f"{k} = {v}" for k, v in s["run_attrs"].items())
                                 or "-"),
             f"  hardware   {hw['name']} (config {hw['config_id']}): {hw['channels']} "
             f"channels x {hw['samples_per_ping']} samples at {hw['sample_rate_hz']:g} Hz",
             f"  pings      {pg['n']} (sequence {pg['first_sequence']} .. "
             f"{pg['last_sequence']}, {pg['sequence_gaps']} gap(s)); projectors "
             + ", ".join(f"{k}: {v}" for k, v in pg["projectors"].items()),
             f"  time       {t['duration_s']:.2f} s, median interval "
             f"{_f(t['median_interval_s'], '.3f')} s"]
    if nav:
        lines += [f"  navigation N {nav['start_ne_m'][0]:.2f} E {nav['start_ne_m'][1]:.2f} m"
                  f" -> N {nav['end_ne_m'][0]:.2f} E {nav['end_ne_m'][1]:.2f} m, "
                  f"{nav['track_length_m']:.2f} m at {_f(nav['mean_speed_m_s'])} m/s, "
                  f"heading {nav['heading_deg'][0]:.1f}..{nav['heading_deg'][1]:.1f} deg, "
                  f"altitude {nav['altitude_m'][0]:.2f}..{nav['altitude_m'][1]:.2f} m, "
                  f"quality flags {nav['quality_flags']}"]
    if "first_ping_samples" in s:
        fp = s["first_ping_samples"]
        lines.append(f"  samples    first ping: rms {fp['rms_counts']:.1f} counts, peak "
                     f"{fp['peak_counts']} ({100 * fp['peak_fraction_of_full_scale']:.2f} % "
                     "of full scale)")
    lines.append("  environment " + (", ".join(f"{k} = {v}" for k, v in
                                                s["environment"].items()) or "-"))
    lines.append(f"  NMEA       {s['nmea_sentences']} sentence(s)")
    lines.append(f"  PD0        {s['pd0_ensembles']} ensemble(s), "
                 f"{s['ping_clock_events']} ping-clock event(s); re-navigation: "
                 f"{s['renavigation_problem'] or 'possible'}")
    if "provenance" in s:
        lines.append("  provenance " + ", ".join(f"{k} = {v}"
                                                for k, v in s["provenance"].items()))
    return "\n".join(lines)
