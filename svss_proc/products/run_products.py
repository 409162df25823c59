"""Run-level products of a folder of tiles: the run's contact list (CSV and GeoJSON, with
latitude and longitude) and a mosaic of the tiles' plan-view MIPs (PNG and HDF5); with a
survey origin, the map products in its UTM zone (:mod:`.georef`: the mosaic as a
GeoTIFF, the contacts as a GeoPackage layer).

Each contact names its run (the tiles' ``run_id``), its tile and the UTC time of the
closest pass (:func:`closest_pass` on the run's ping track, :func:`run_track`); values
are rounded to their meaningful precision (:data:`CONTACT_FIELDS`).

Contacts (docs/run_products.md). Each tile's detections are placed in the
survey frame through the tile's line, then into the run frame (the first tile's line),
and filtered across tiles, which a tile alone cannot do:

1. coverage: a contact whose peak voxel was imaged by fewer pings than
   ``min_coverage_fraction`` of the run's full coverage at its depth (the most pings any
   voxel of that depth got in any tile) is dropped (a tile at the start or end of a run
   measures its fraction against itself only);
2. one object: contacts of neighbouring tiles within ``merge_m`` (per axis) are one
   (the same object seen in two tiles), strongest peak first;
3. sidelobes: a contact ``sidelobe_db`` weaker (peak magnitude) than a stronger one
   within its sidelobe region (:func:`svss_proc.products.detect.is_sidelobe`), whichever
   tile each is in, is dropped.

Circumstances (:mod:`.circumstances`): the run's pings (every tile's, with the
navigation flags its tiles kept) placed where the array was, give the run's stretches of
missing pings, dead-reckoned and held poses; each contact counts those among the pings
that could see it (:func:`contact_circumstances`), the map draws them along the array's
track, the GeoJSON carries them as LineStrings and ``mosaic.h5`` as a table.

Latitude and longitude: survey NED to geodetic through
:func:`svss_daq.navigation.ned_to_geodetic` about the survey origin: the one given, or
else the one recovered from a ping's geodetic position recorded in a tile
(``geodetic_ref``); without either they are empty (CSV) or the feature has a null
geometry (GeoJSON). GeoJSON follows RFC 7946: WGS-84, [longitude, latitude].

The run as its tiles hold it (views, origin, track) is :mod:`.run_views`'s, the mosaic
and the map :mod:`.run_mosaic`'s; this module makes the contacts and writes every run
product (:func:`write_run_products`). Pure geometry (:func:`filter_contacts`,
:func:`survey_origin`, :func:`~.run_mosaic.mosaic_grid`) is kept apart from the file
handling.
"""

from __future__ import annotations

import csv
import json
import logging
import math
import os
from pathlib import Path

import numpy as np

from svss_daq.geometry import cone_radius
from svss_daq.navigation import ned_to_geodetic

from ..tiles import TileFileError, temporary_path
from .chain import coverage_settings, footprint_for
from .classify import (CLASS_FILL, CLASS_NAMES, FROM_IMAGE, NOT_CLASSIFIED,
                       call_with_pings, class_text)
from .contact_features import FEATURE_FILL, FEATURE_NAMES, flags_text
from .contact_spectra import NO_SPECTRA, SPECTRA_FIELDS
from .circumstances import (FALLBACK_REACH_M, KINDS, LABELS, PingTrack, Stretch,
                            circumstances_text, counts_near, is_partial)
from .detect import Footprint, is_later_echo, sidelobe_filter
from .georef import (CONTACTS_GPKG, MOSAIC_TIF, SurveyProjection, write_contacts_gpkg,
                     write_mosaic_geotiff, write_stretches_gpkg)
from .run_mosaic import (MOSAIC_H5, MOSAIC_PNG, STRETCH_RGB, TRACK_RGB, run_mosaic,
                         run_swath, tile_corners_ne, utm_mosaic, write_mosaic_h5,
                         write_mosaic_png)
from .run_views import (TileView, _configs, closest_pass, load_views, run_circumstances,
                        run_of_views, run_pings, run_track, survey_origin, utc_text)

log = logging.getLogger(__name__)

CONTACTS_CSV = "contacts.csv"
CONTACTS_GEOJSON = "contacts.geojson"

#: contact columns: (name, units, meaning, decimals written: None not a float). The
#: decimals are the meaningful precision: 1e-7 deg (1 cm) for latitude and longitude,
#: 1 mm for positions and sizes (the detections' sub-voxel peaks on 2 cm voxels),
#: 0.01 dB, 0.001 of coverage; the tiles' float32 values carry no more.
CONTACT_FIELDS = (
    ("contact", "1", "contact number in the run, strongest excess first", None),
    ("run_id", "", "the run (survey line) the contact was found in (empty: not known)",
     None),
    ("tile", "", "tile file the contact was detected in", None),
    ("time_utc", "", ("UTC time of the closest pass: when the body origin was "
                      "horizontally closest to the peak, on the run's ping track (ISO "
                      "8601, ms; empty: tiles written before their pings' track was "
                      "kept)"), None),
    ("latitude_deg", "deg", "WGS-84 latitude of the peak (empty: no geodetic origin)", 7),
    ("longitude_deg", "deg", "WGS-84 longitude of the peak", 7),
    ("depth_below_seabed_m", "m", "depth of the peak below the water-sediment interface",
     3),
    ("size_along_m", "m", "along-track extent above the threshold", 3),
    ("size_cross_m", "m", "cross-track extent above the threshold", 3),
    ("size_depth_m", "m", "depth extent above the threshold", 3),
    ("excess_db", "dB", ("signal excess: the level at the peak over the local background "
                         "(3-D median of the image magnitude), dB"), 2),
    ("threshold_db", "dB", ("the detection threshold at the peak's depth: the configured "
                            "one, or that depth layer's own from its clutter's tail "
                            "(layer_false_alarms_per_m3), dB re background"), 2),
    ("expected_false_alarms", "1", ("voxels of the peak's depth layer in its tile expected "
                                    "at the contact's level or above from that layer's "
                                    "clutter (its fitted tail; three significant digits; "
                                    "empty: no fit): the contact's local false-alarm "
                                    "estimate"), None),
    ("north_m", "m", "survey-frame north of the peak", 3),
    ("east_m", "m", "survey-frame east of the peak", 3),
    ("along_m", "m", "along-track position in the run frame (the first tile's line)", 3),
    ("cross_m", "m", "cross-track position in the run frame, starboard positive", 3),
    ("closest_pass_m", "m", ("horizontal distance from the body origin to the peak at the "
                             "closest pass"), 3),
    ("coverage_fraction", "1", ("pings that imaged the peak over the run's full coverage "
                                "at its depth"), 3),
    ("pings_missing", "1", ("missing pings (sequence gaps) among the pings that could see "
                            "the contact: placed on the track of their gap, within the "
                            "projector cone's horizontal reach of it"), None),
    ("poses_dead_reckoned", "1", ("dead-reckoned poses (no GPS fix: NAV_DEAD_RECKONED) "
                                  "among the pings that could see it"), None),
    ("poses_held", "1", "held poses (NAV_HELD) among the pings that could see it", None),
    ("circumstances", "", ("what happened around the contact in words, empty when "
                           "nothing did: e.g. 'gap 8 pings; dead-reckoned 30 poses; held "
                           "2 poses; partial coverage' (coverage_fraction under 0.75)"),
     None),
    ("tile_row", "1", "row of the tile's detection table", None),
    ("n_tiles", "1", "tiles whose detections were merged into the contact", None),
    # each contact's features, from its strongest tile detection (docs/contact_features.md)
    ("tail_extent_m", "m", ("apparent depth below the peak down to where the tail falls "
                            "to within background_within_db of the local background "
                            "(empty: cut by the tile's bottom, or not measured)"), 3),
    ("tail_decay_db_per_m", "dB/m", ("decay of the tail below the object per metre of "
                                     "apparent depth, positive decaying (empty: no tail)"),
     2),
    ("tail_decay_err_db_per_m", "dB/m", "standard error of tail_decay_db_per_m", 2),
    ("late_to_specular_db", "dB", ("late energy (the tail window below the object) over "
                                   "the object's own (its peak window), background "
                                   "subtracted (an upper bound where feature_notes say "
                                   "so)"), 2),
    ("late_to_specular_err_db", "dB", ("uncertainty of late_to_specular_db from the local "
                                       "background's fluctuation"), 2),
    ("aspect_centre_deg", "deg", ("mean look angle along-track of the contact's response "
                                  "over the aperture (in water)"), 1),
    ("aspect_width_deg", "deg", ("rms spread of that look angle: narrow for a specular "
                                 "face, the aperture's for a point"), 2),
    ("aspect_width_err_deg", "deg", "standard error of aspect_width_deg", 2),
    ("aspect_cross_width_deg", "deg", ("rms spread of the look angle across-track (the "
                                       "receive array's aperture)"), 2),
    ("aspect_cross_width_err_deg", "deg", "standard error of aspect_cross_width_deg", 2),
    ("aspect_point_fraction", "1", ("the broader look-angle spread over a point "
                                    "scatterer's: near 1 for a sphere or along a "
                                    "cylinder's axis, well below for a flat face"), 2),
    ("aspect_point_fraction_err", "1", "standard error of aspect_point_fraction", 2),
    # from the recorded pings (svss process; svss_proc.products.contact_spectra)
    ("resonance_hz", "Hz", ("frequency of the strongest resonance line inside the band "
                            "in the pings' late response at the contact (empty: none, or "
                            "not measured)"), 1),
    ("resonance_err_hz", "Hz", "standard error of resonance_hz (jackknife over the pings)",
     1),
    ("resonance_width_hz", "Hz", ("its full width at half power (decay rate / pi; "
                                  "Q = resonance_hz / resonance_width_hz)"), 1),
    ("resonance_width_err_hz", "Hz", "standard error of resonance_width_hz", 1),
    ("late_over_background_db", "dB", ("the pings' late response at the contact over the "
                                       "background's beside it (a line is reported only "
                                       "above [products.spectra] min_over_background_db)"),
     2),
    ("resonance_pings", "1", ("pings whose projector cone held the contact (0: not "
                              "measured)"), None),
    ("feature_flags", "1", ("bits: 1 tail cut by the tile's bottom, 2 no tail, 4 "
                            "late-to-specular an upper bound, 8 no reference beside it, 16 "
                            "tail too short to fit, 32 aspect not measured; -1 not "
                            "measured"), None),
    ("feature_notes", "", "feature_flags in words (empty: every feature measured)", None),
    # its class from those features (svss_proc.products.classify)
    ("class", "", ("man-made, natural or undecided (probability between the thresholds, "
                   "or a feature missing or flagged); empty: not classified"), None),
    ("p_manmade", "1", ("probability that the contact is man-made (logistic regression on "
                        "its features, [products.classify]; empty: not classified or a "
                        "feature missing)"), 3),
    ("class_from", "", ("the model that called it: 'image' (the tile's features, "
                        "[products.classify]) or 'image and pings' (with the pings' "
                        "features too, [products.classify_pings], svss process); empty: "
                        "not classified"), None),
)
_DECIMALS = {name: d for name, _, _, d in CONTACT_FIELDS}


def _rounded(name: str, value):
    """A contact column's value at its meaningful precision (NaN stays NaN)."""
    d = _DECIMALS.get(name)
    if d is None or not isinstance(value, float) or not math.isfinite(value):
        return value
    return round(value, d)


def _depth_index(depth_axis: np.ndarray, z: float) -> int:
    return int(np.clip(np.argmin(np.abs(depth_axis - z)), 0, depth_axis.size - 1))


def filter_contacts(rows: list[dict], full_pings: np.ndarray | None, depth_axis: np.ndarray,
                    min_fraction: float, merge_m, sidelobe_db: float, sidelobe_m: float,
                    footprint: Footprint | None, later_echo_m=None) -> list[dict]:
    """The run's contacts from the tiles' detections (``rows``: dicts with ``run_m``
    (along, cross, depth in the run frame), ``peak_db``, ``coverage_pings``, extents,
    ...): coverage against the run's full coverage per depth ``full_pings`` (None:
    none known), merge across tiles, sidelobes across tiles (module docstring).
    Returns the kept rows (``n_tiles`` and ``coverage_fraction`` set), strongest
    excess first."""
    kept = []
    for r in rows:
        if full_pings is not None and r["coverage_pings"] > 0:
            ref = float(full_pings[_depth_index(depth_axis, r["depth_m"])])
            r["coverage_fraction"] = r["coverage_pings"] / ref if ref > 0 else 0.0
            if r["coverage_fraction"] < min_fraction:
                continue
        else:
            r["coverage_fraction"] = float("nan")
        kept.append(r)
    kept.sort(key=lambda r: -r["peak_db"])
    merge = np.asarray(merge_m, dtype=np.float64)
    merged: list[dict] = []
    for r in kept:
        for m in merged:
            if r["tile"] != m["tile"] and np.all(np.abs(r["run_m"] - m["run_m"]) <= merge):
                m["lo"] = np.minimum(m["lo"], r["run_m"] - r["half"])
                m["hi"] = np.maximum(m["hi"], r["run_m"] + r["half"])
                m["n_tiles"] += 1
                break
        else:
            r["n_tiles"] = 1
            r["lo"], r["hi"] = r["run_m"] - r["half"], r["run_m"] + r["half"]
            merged.append(r)
    if not merged:
        return []
    keep = sidelobe_filter(np.array([m["run_m"] for m in merged]),
                           np.array([m["peak_db"] for m in merged]), sidelobe_db,
                           sidelobe_m, footprint)
    out: list[dict] = []
    for r in (m for m, k in zip(merged, keep) if k):      # strongest peak first
        for m in out:
            if is_later_echo(r["run_m"], m["run_m"], later_echo_m):
                m["lo"] = np.minimum(m["lo"], r["lo"])
                m["hi"] = np.maximum(m["hi"], r["hi"])
                break
        else:
            out.append(r)
    out.sort(key=lambda r: -r["excess_db"])
    return out


def contact_circumstances(track: PingTrack, ned, depth_m: float, coverage_fraction: float,
                          footprint: Footprint | None) -> dict:
    """A contact's circumstance columns: what happened among the pings that could see
    it (those placed on ``track`` within the projector cone's horizontal reach of the
    peak at ``depth_m``: ``(h + z) tan(half-angle)`` of ``footprint``, else
    :data:`.circumstances.FALLBACK_REACH_M`) and its ``circumstances`` text (with
    "partial coverage" where ``coverage_fraction`` is under
    :data:`.circumstances.PARTIAL_COVERAGE_BELOW`)."""
    reach = (cone_radius(footprint.height_m + max(float(depth_m), 0.0),
                         footprint.tan_half_angle)
             if footprint is not None else FALLBACK_REACH_M)
    counts = counts_near(track, float(ned[0]), float(ned[1]), reach)
    return {**counts,
            "circumstances": circumstances_text(counts, is_partial(coverage_fraction))}


def run_contacts(views: list[TileView],
                 origin: tuple[float, float, float] | None = None) -> tuple[list[dict], dict]:
    """The run's contacts (dicts with the :data:`CONTACT_FIELDS`) from its tiles, and a
    summary (settings, origin, counts)."""
    if not views:
        return [], {"tiles": 0}
    pcfg, hw, imaging = _configs(views[0])
    if pcfg is None:
        raise TileFileError(f"{views[0].path}: no [products] in its processing "
                            "configuration: the tiles have no detections")
    _, min_fraction, use_footprint = coverage_settings(pcfg)
    dc = pcfg.detection
    run_line = views[0].line
    depth_axis = views[0].data["depth"]
    fulls = [v.data["coverage_full_pings"] for v in views
             if "coverage_full_pings" in v.data
             and v.data["coverage_full_pings"].shape == depth_axis.shape]
    full = np.max(fulls, axis=0) if fulls else None
    heights = [float(v.data["attrs"]["projector_height_m"]) for v in views
               if np.isfinite(float(v.data["attrs"].get("projector_height_m", np.nan)))]
    footprint = reach = None
    if heights and hw is not None and imaging is not None:
        reach = footprint_for(float(np.mean(heights)), hw, imaging)
        footprint = reach if use_footprint else None
    rows = []
    for v in views:
        table = v.data["detections"]
        if not len(table):
            continue
        xyz = np.stack([table["along_m"], table["cross_m"], table["depth_m"]], axis=1)
        ned = v.line.tile_to_ned(xyz)
        run = run_line.ned_to_tile(ned)
        run[:, 2] = xyz[:, 2]                     # depth below the seabed as imaged
        for i, row in enumerate(table):
            half = 0.5 * np.array([row["extent_along_m"], row["extent_cross_m"],
                                   row["extent_depth_m"]], dtype=np.float64)
            rows.append({"tile": v.path.name, "tile_row": i, "run_m": run[i],
                         "ned": ned[i], "half": half, "depth_m": float(xyz[i, 2]),
                         "peak_db": float(row["peak_db"]),
                         "excess_db": float(row["excess_db"]),
                         "threshold_db": _optional(table, row, "threshold_db"),
                         "false_alarms": _optional(table, row, "false_alarms"),
                         "coverage_pings": int(row["coverage_pings"]),
                         **_features(table, row)})
    n_tile_detections = len(rows)
    kept = filter_contacts(rows, full, depth_axis, min_fraction, dc.merge_m, dc.sidelobe_db,
                           dc.sidelobe_m, footprint, dc.later_echo_m)
    if origin is None:
        refs = [v.data["attrs"]["geodetic_ref"] for v in views
                if "geodetic_ref" in v.data["attrs"]]
        origin = survey_origin(refs[0]) if refs else None
    run_id = run_of_views(views)
    track = run_track(views)
    pings, stretched = run_circumstances(views, hw)
    out = []
    for k, r in enumerate(kept):
        lat = lon = float("nan")
        if origin is not None:
            la, lo, _ = ned_to_geodetic(r["ned"], origin)
            lat, lon = float(la), float(lo)
        size = r["hi"] - r["lo"]
        when, dist = closest_pass(track, r["ned"])
        c = {"contact": k, "run_id": run_id, "tile": r["tile"], "time_utc": when,
             "latitude_deg": lat, "longitude_deg": lon,
             "depth_below_seabed_m": r["depth_m"], "size_along_m": float(size[0]),
             "size_cross_m": float(size[1]), "size_depth_m": float(size[2]),
             "excess_db": r["excess_db"], "threshold_db": r["threshold_db"],
             "expected_false_alarms": r["false_alarms"],
             "north_m": float(r["ned"][0]), "east_m": float(r["ned"][1]),
             "along_m": float(r["run_m"][0]), "cross_m": float(r["run_m"][1]),
             "closest_pass_m": dist,
             "coverage_fraction": float(r["coverage_fraction"]),
             **contact_circumstances(pings, r["ned"], r["depth_m"],
                                     float(r["coverage_fraction"]), reach),
             "tile_row": r["tile_row"], "n_tiles": r["n_tiles"],
             **{k: r[k] for k in FEATURE_NAMES},
             "feature_notes": flags_text(r["feature_flags"]),
             "class": class_text(r["class"]), "p_manmade": r["p_manmade"],
             "class_from": FROM_IMAGE if r["class"] != NOT_CLASSIFIED else "",
             **NO_SPECTRA}
        out.append({name: _rounded(name, c[name]) for name, *_ in CONTACT_FIELDS})
    summary = {"tiles": len(views), "tile_detections": n_tile_detections,
               "run_id": run_id,
               "contacts": len(out), "origin": None if origin is None else list(origin),
               "min_coverage_fraction": min_fraction,
               "run_full_coverage_pings": None if full is None else int(full.max()),
               "sidelobe_db": dc.sidelobe_db,
               "footprint": None if footprint is None else
               {"height_m": footprint.height_m, "tan_half_angle": footprint.tan_half_angle},
               "stretches": {k: sum(1 for x in stretched if x.kind == k) for k in KINDS},
               "array_track": pings, "stretch_list": stretched}
    return out, summary


def _optional(table: np.ndarray, row, name: str) -> float:
    """A detection's optional column (NaN where an older tile has none or wrote -1: not
    known)."""
    if name not in (table.dtype.names or ()):
        return float("nan")
    v = float(row[name])
    return v if v >= 0.0 else float("nan")


def _features(table: np.ndarray, row) -> dict:
    """A detection's feature and class columns (their fill values where an older tile
    has none)."""
    names = table.dtype.names or ()
    out = {k: (row[k].item() if k in names else FEATURE_FILL[k]) for k in FEATURE_NAMES}
    out["feature_flags"] = int(out["feature_flags"])
    for k in CLASS_NAMES:        # its class (an older tile: not classified)
        out[k] = row[k].item() if k in names else CLASS_FILL[k]
    out["class"] = int(out["class"])
    return out


def _csv_value(name: str, v) -> str:
    if isinstance(v, float):
        if not math.isfinite(v):
            return ""
        d = _DECIMALS.get(name)
        return f"{v:.3g}" if d is None else f"{v:.{d}f}"
    return str(v)


def contacts_by_row(path: Path, otherwise: str) -> dict[tuple[str, str], dict]:
    """The rows of a contacts file (CSV text) by their tile detection (``tile``,
    ``tile_row``); none, with a warning ending in ``otherwise``, where the file is
    missing a column or cannot be read (a missing file: none, silently)."""
    if not path.is_file():
        return {}
    try:
        with open(path, newline="") as f:
            return {(r["tile"], r["tile_row"]): r for r in csv.DictReader(f)}
    except (OSError, csv.Error, KeyError, UnicodeDecodeError) as exc:
        log.warning("%s: not read (%s); %s", path, exc, otherwise)
        return {}


def kept_spectra(path: Path, contacts: list[dict]) -> int:
    """Rewritten without the pings (``svss products``, the worker), the contacts keep the
    resonance columns the contacts file at ``path`` had for the same tile detection
    (``tile``, ``tile_row``) at the same place (within 1 cm): they came from the
    recorded pings (``svss process``), which a rewrite from the tiles cannot measure
    again. Returns how many contacts kept them."""
    old = contacts_by_row(path, "its resonance columns are not kept")
    old = {k: r for k, r in old.items() if r.get("resonance_pings") not in (None, "", "0")}
    n = 0
    for c in contacts:
        r = old.get((str(c["tile"]), str(c["tile_row"])))
        if r is None:
            continue
        try:
            same = all(abs(float(r[k]) - float(c[k])) <= 0.01
                       for k in ("along_m", "cross_m", "depth_below_seabed_m"))
            values = {k: (float(r[k]) if r[k] != "" else math.nan) for k in SPECTRA_FIELDS}
        except (KeyError, ValueError):
            continue
        if same:
            values["resonance_pings"] = int(values["resonance_pings"])
            c.update(values)
            n += 1
    if n:
        log.info("%s: the resonance columns of %d contact(s) kept (measured from the "
                 "pings by svss process)", path, n)
    return n


def write_contacts_csv(path: Path, contacts: list[dict]) -> Path:
    """One row per contact, :data:`CONTACT_FIELDS` columns, each at its precision (NaN
    written empty)."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow([name for name, *_ in CONTACT_FIELDS])
        for c in contacts:
            w.writerow([_csv_value(k, c[k]) for k, *_ in CONTACT_FIELDS])
    return path


def stretch_geojson(k: int, st: Stretch, origin) -> dict:
    """A stretch as an RFC 7946 LineString feature along the array's track ([longitude,
    latitude] about the survey ``origin``; null geometry without one), id
    ``stretch-K``, properties ``kind`` (:data:`.circumstances.KINDS`), ``label``,
    ``first_sequence``, ``last_sequence``, ``pings``, ``start_utc``, ``end_utc``."""
    geometry = None
    if origin is not None and np.all(np.isfinite(np.asarray(origin, dtype=float)[:2])):
        ned = np.stack([st.north_m, st.east_m, np.zeros(st.north_m.size)], axis=1)
        lat, lon, _ = ned_to_geodetic(ned, tuple(origin))
        geometry = {"type": "LineString",
                    "coordinates": [[_rounded("longitude_deg", float(b)),
                                     _rounded("latitude_deg", float(a))]
                                    for a, b in zip(np.atleast_1d(lat), np.atleast_1d(lon))]}
    return {"type": "Feature", "id": f"stretch-{k}", "geometry": geometry,
            "properties": {"kind": st.kind, "label": LABELS[st.kind],
                           "first_sequence": st.first_sequence,
                           "last_sequence": st.last_sequence, "pings": st.pings,
                           "start_utc": utc_text(st.start_ns),
                           "end_utc": utc_text(st.end_ns)}}


def contacts_geojson(contacts: list[dict], summary: dict) -> dict:
    """RFC 7946 FeatureCollection: a Point [longitude, latitude] per contact (null
    geometry without a geodetic origin), the other columns as properties and ``kind``
    "contact"; after them the run's stretches (``summary["stretch_list"]``) as
    LineStrings (:func:`stretch_geojson`)."""
    feats = []
    for c in contacts:
        ok = math.isfinite(c["latitude_deg"]) and math.isfinite(c["longitude_deg"])
        props = {"kind": "contact",
                 **{k: (None if isinstance(c[k], float) and not math.isfinite(c[k])
                        else _rounded(k, c[k]))
                    for k, *_ in CONTACT_FIELDS if k not in ("latitude_deg", "longitude_deg")}}
        feats.append({"type": "Feature", "id": c["contact"],
                      "geometry": ({"type": "Point",
                                    "coordinates": [_rounded("longitude_deg",
                                                             c["longitude_deg"]),
                                                    _rounded("latitude_deg",
                                                             c["latitude_deg"])]}
                                   if ok else None),
                      "properties": props})
    feats += [stretch_geojson(k, st, summary.get("origin"))
              for k, st in enumerate(summary.get("stretch_list", ()))]
    return {"type": "FeatureCollection", "features": feats,
            "svss_run": {k: summary.get(k) for k in ("run_id", "tiles", "tile_detections",
                                                     "contacts", "origin", "stretches")}}


# ----------------------------------------------------------------------- the entry


def write_run_products(tiles_dir: str | Path, out_dir: str | Path | None = None,
                       origin: tuple[float, float, float] | None = None,
                       spectra=None) -> list[Path]:
    """Write the run products of the tiles in ``tiles_dir`` into ``out_dir`` (default:
    the same folder): ``contacts.csv``, ``contacts.geojson``, ``mosaic.png`` and
    ``mosaic.h5``, and with a survey origin the map products ``mosaic.tif`` (GeoTIFF)
    and ``contacts.gpkg`` (GeoPackage), in the survey's UTM zone. ``origin``: survey origin (lat deg, lon deg, height m) when the
    tiles carry no geodetic reference. Returns the files written (none when the
    folder has no tiles with products). ``spectra``: a function of the contacts and the
    tiles' frame (:class:`~svss_daq.frames.TrackLine`) giving each contact's resonance
    columns (:data:`~.contact_spectra.SPECTRA_FIELDS`, from the recorded pings:
    :func:`svss_proc.run_worker.process_raw`); None: those columns left empty."""
    tiles_dir = Path(tiles_dir)
    out = Path(out_dir) if out_dir is not None else tiles_dir
    views = load_views(tiles_dir)
    if not views:
        log.warning("%s: no tiles; no run products", tiles_dir)
        return []
    pcfg, _, _ = _configs(views[0])
    if pcfg is None:
        log.warning("%s: tiles without products; no run products", tiles_dir)
        return []
    out.mkdir(parents=True, exist_ok=True)
    contacts, summary = run_contacts(views, origin)
    measured = None
    if spectra is not None and contacts:
        try:                 # from the recorded pings: a failure there costs only them
            measured = spectra(contacts, views[0].line)
            if len(measured) != len(contacts):
                raise ValueError(f"{len(measured)} spectra for {len(contacts)} contacts")
        except Exception:
            log.exception("%s: the contacts' resonance lines failed; the run products are "
                          "written without them", tiles_dir)
            measured = None
    if measured is not None:
        for c, s in zip(contacts, measured, strict=True):
            c.update({k: _rounded(k, v) for k, v in s.items()})
    elif contacts:
        kept_spectra(out / CONTACTS_CSV, contacts)
    if pcfg.classify_pings is not None and pcfg.classify_pings.enabled and contacts:
        n = call_with_pings(contacts, pcfg.classify_pings)
        log.info("%s: %d of %d contact(s) called with the pings' features too "
                 "([products.classify_pings])", tiles_dir, n, len(contacts))
    origin = summary["origin"]
    track, found = summary["array_track"], summary["stretch_list"]
    m = run_mosaic(views)
    title = (f"SVSS run mosaic: {len(views)} tile(s) from {tiles_dir.name}, "
             f"{len(contacts)} contact(s) (from {summary['tile_detections']} tile "
             f"detections); cell {m['cell_m'] * 100:.0f} cm")
    geojson = json.dumps(contacts_geojson(contacts, summary), indent=1)
    writers = {CONTACTS_CSV: lambda p: write_contacts_csv(p, contacts),
               CONTACTS_GEOJSON: lambda p: p.write_text(geojson),
               MOSAIC_H5: lambda p: write_mosaic_h5(p, m, origin, track, found),
               MOSAIC_PNG: lambda p: write_mosaic_png(p, m, contacts, pcfg, title,
                                                      pcfg.quicklook.max_labels, track,
                                                      found, run_swath(views))}
    projection = None
    if origin is not None:                 # the map products (docs/products.md)
        try:
            projection = SurveyProjection(tuple(origin))
        except ValueError as exc:
            log.warning("%s: no %s or %s: %s", tiles_dir, MOSAIC_TIF, CONTACTS_GPKG, exc)
    if projection is not None:
        um = utm_mosaic(views, projection)
        what = (f"{title}; run {summary['run_id'] or 'unknown'}; plan-view MIP in dB re "
                f"background, WGS 84 / UTM (EPSG:{projection.epsg})")
        writers[MOSAIC_TIF] = lambda p: write_mosaic_geotiff(p, um, projection.epsg, what)
        writers[CONTACTS_GPKG] = lambda p: write_stretches_gpkg(write_contacts_gpkg(
            p, contacts, [k for k, *_ in CONTACT_FIELDS], projection),
            [{**stretch_geojson(0, st, None)["properties"], "north_m": st.north_m,
              "east_m": st.east_m} for st in found], projection)
    elif origin is None:
        log.info("%s: no survey origin (no ping with a geodetic position, no --origin): "
                 "no %s or %s", tiles_dir, MOSAIC_TIF, CONTACTS_GPKG)
    files = []
    for name, write in writers.items():
        final = out / name
        tmp = temporary_path(final)          # whole files only, under their final names
        try:
            write(tmp)
            os.replace(tmp, final)
        finally:
            tmp.unlink(missing_ok=True)
        files.append(final)
    log.info("%s: %d contact(s) from %d tile detection(s) in %d tile(s); wrote %s",
             out, len(contacts), summary["tile_detections"], len(views),
             ", ".join(p.name for p in files))
    return files


def run_products_at_end(tiles_dir: str | Path, spectra=None) -> list[Path]:
    """:func:`write_run_products` for the worker at a run's end: a failure is logged
    (naming the folder), never raised, so that it cannot cost the run's tiles."""
    try:
        return write_run_products(tiles_dir, spectra=spectra)
    except Exception:
        log.exception("%s: writing the run products failed (rewrite them with "
                      "'svss products %s')", tiles_dir, tiles_dir)
        return []


__all__ = [
    "CONTACTS_CSV",
    "CONTACTS_GEOJSON",
    "CONTACTS_GPKG",
    "MOSAIC_H5",
    "MOSAIC_PNG",
    "STRETCH_RGB",
    "TRACK_RGB",
    "TileView",
    "load_views",
    "run_track",
    "tile_corners_ne",
    "write_mosaic_png",
    "CONTACT_FIELDS",
    "MOSAIC_TIF",
    "closest_pass",
    "contact_circumstances",
    "filter_contacts",
    "run_circumstances",
    "run_contacts",
    "run_mosaic",
    "run_pings",
    "run_products_at_end",
    "utm_mosaic",
    "survey_origin",
    "write_run_products",
]
