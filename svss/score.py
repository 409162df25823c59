"""``svss score TILES_DIR --scene SCENE.toml``: detections of a folder of tiles against a
simulated scene's ground truth.

The truth is read here, in the command-line tool, never in ``svss_proc``. Every true
target with along/cross/depth coordinates in the scene (``[[points]]`` and any other
array of tables with ``along_m``, ``cross_m``, ``depth_m``) is placed in the survey frame
through the scene's own track line, then into each tile's frame through the line the
tile was imaged in (its root attributes), so the comparison holds whether the tiles
were formed with ``track_line = "first_ping"`` or a fixed line. Targets outside every
tile's volume are listed but not scored.

Each target has a truth class (:func:`truth_class`): ``man-made`` for the targets of
metal (shells, cylinders, spheres: every material but the rocks), ``natural`` for the
rocks (:data:`NATURAL_MATERIALS`), ``other`` for points and rigid stand-ins. The report
gives, per class, how many were detected and how the detections were called
(:mod:`svss_proc.products.classify`: man-made, natural, undecided, not classified).
"""

from __future__ import annotations

import dataclasses
import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim_device.scene import load_scene
from sim_device.track import truth_line
from svss_daq.config import ConfigError, ProcessingConfig, loads
from svss_proc import tiles
from svss_proc.products import detect
from svss_proc.products.classify import CLASS_CODE, class_text
from svss_proc.products.run_products import (CONTACTS_CSV, TileView, contacts_by_row,
                                             run_contacts)

log = logging.getLogger(__name__)

#: the worker's list of the files it wrote (``svss_proc.run_folder.MANIFEST``)
MANIFEST = "manifest.json"
#: materials of config/materials.toml that are rocks: a target of one is natural clutter
NATURAL_MATERIALS = ("granite", "basalt", "limestone")
#: the truth classes, and what a detection may be called
CLASSES = ("man-made", "natural", "other")
CALLS = ("man-made", "natural", "undecided", "not classified")


@dataclass
class Score:
    """Detections against ground truth. ``pairs``: (truth index, detection index,
    distance m) one-to-one, nearest first; a detection within the radius of a true
    target already detected by another is a ``duplicate``, not a false alarm."""
    n_truth: int
    n_detections: int
    pairs: list[tuple[int, int, float]]
    missed: list[int]
    false_alarms: list[int]
    duplicates: list[int]

    @property
    def hits(self) -> int:
        return len(self.pairs)

    @property
    def probability_of_detection(self) -> float:
        return self.hits / self.n_truth if self.n_truth else float("nan")

    def summary(self) -> dict:
        return {"truth": self.n_truth, "detections": self.n_detections, "hits": self.hits,
                "misses": len(self.missed), "false_alarms": len(self.false_alarms),
                "duplicates": len(self.duplicates),
                "probability_of_detection": (self.probability_of_detection
                                             if self.n_truth else None)}


def score(detections_m: np.ndarray, truth_m: np.ndarray, radius_m: float,
          extents_m: np.ndarray | None = None) -> Score:
    """Match detections (n, 3) to true targets (m, 3), positions (along, cross, depth) in
    one frame (m): a pair is closer than ``radius_m`` (Euclidean) to the target's
    extent, the sphere of radius ``extents_m`` (per target, m; None: points) about its
    centre (a contact on a cylinder's top or end is that cylinder's); pairs are taken
    nearest first, each target and each detection at most once."""
    det = np.asarray(detections_m, dtype=np.float64).reshape(-1, 3)
    truth = np.asarray(truth_m, dtype=np.float64).reshape(-1, 3)
    ext = (np.zeros(len(truth)) if extents_m is None
           else np.asarray(extents_m, dtype=np.float64).reshape(-1))
    dist = np.maximum(np.linalg.norm(truth[:, None, :] - det[None, :, :], axis=2)
                      - ext[:, None], 0.0)
    ti, di = np.nonzero(dist <= radius_m)
    order = np.argsort(dist[ti, di], kind="stable")
    used_t, used_d, pairs = set(), set(), []
    for t, d in zip(ti[order], di[order]):
        if t not in used_t and d not in used_d:
            used_t.add(int(t))
            used_d.add(int(d))
            pairs.append((int(t), int(d), float(dist[t, d])))
    near = (dist <= radius_m).any(axis=0) if truth.size else np.zeros(len(det), bool)
    rest = [d for d in range(len(det)) if d not in used_d]
    return Score(n_truth=len(truth), n_detections=len(det), pairs=pairs,
                 missed=[t for t in range(len(truth)) if t not in used_t],
                 false_alarms=[d for d in rest if not near[d]],
                 duplicates=[d for d in rest if near[d]])


def half_extent(target: dict) -> float:
    """A true target's largest half-size, m (a cylinder's half length or its radius, a
    sphere's or a disc's radius; a point's 0), from :func:`scene_truth`'s ``fields``."""
    f = target.get("fields") or {}
    return max(0.5 * float(f.get("length_m") or 0.0), float(f.get("radius_m") or 0.0))


def truth_class(target: dict) -> str:
    """A true target's class (:func:`scene_truth`'s entry): ``natural`` for a rock
    (:data:`NATURAL_MATERIALS`), ``man-made`` for any other material, ``other`` for a
    target without one (a point) or a rigid stand-in."""
    material = (target.get("fields") or {}).get("material")
    if not isinstance(material, str) or material == "rigid":
        return "other"
    return "natural" if material in NATURAL_MATERIALS else "man-made"


def per_class(truth: list[dict]) -> dict:
    """Per truth class of the scored targets (status not ``outside``): ``targets``,
    ``detected``, the detections' calls (``man-made``, ``natural``, ``undecided``,
    ``not classified``), ``detected_fraction`` and ``called_manmade_fraction`` (of the
    class's targets: a missed target is not called man-made); classes without targets
    are left out."""
    out = {}
    for cls in CLASSES:
        ts = [t for t in truth if t.get("class") == cls and t.get("status") != "outside"]
        if not ts:
            continue
        det = [t for t in ts if t["status"] == "detected"]
        row = {"targets": len(ts), "detected": len(det),
               **{c: sum(1 for t in det if t.get("called") == c) for c in CALLS}}
        row["detected_fraction"] = row["detected"] / row["targets"]
        row["called_manmade_fraction"] = row["man-made"] / row["targets"]
        out[cls] = row
    return out


def scene_truth(scene) -> list[dict]:
    """True targets of a scene: ``table`` (the scene's array of tables they come from,
    e.g. ``points``), ``index`` in it, ``scene_m`` (along, cross, depth; m, in the
    scene's own frame) and their other ``fields``."""
    out = []
    for f in dataclasses.fields(scene):
        items = getattr(scene, f.name)
        if not isinstance(items, tuple):
            continue
        for i, item in enumerate(items):
            if dataclasses.is_dataclass(item) and all(
                    hasattr(item, k) for k in ("along_m", "cross_m", "depth_m")):
                extra = {k: v for k, v in dataclasses.asdict(item).items()
                         if k not in ("along_m", "cross_m", "depth_m")}
                out.append({"table": f.name, "index": i,
                            "scene_m": [item.along_m, item.cross_m, item.depth_m],
                            "fields": extra})
    return out


def _radius_from_tile(path: Path, header: dict) -> float | None:
    """The match radius the tile was processed with (its stored processing
    configuration), None when it has no detection settings."""
    text = header.get("processing_config_toml")
    if text is None:
        return None
    try:
        proc = loads(ProcessingConfig, text, f"{path}:/provenance/processing_config_toml")
    except ConfigError as exc:
        raise ValueError(f"{exc}; give --radius") from None
    if proc.products is None:
        return None
    return float(proc.products.detection.match_radius_m)


def tile_paths(tiles_dir: str | Path) -> list[Path]:
    """The tiles of one run in ``tiles_dir``: those its ``manifest.json`` lists (tiles
    in the folder it does not list, e.g. from an earlier run, are excluded with a
    warning naming them); without a manifest every ``tile_*.h5`` (with a warning).
    Temporary files of tiles being written are never included."""
    tiles_dir = Path(tiles_dir)
    found = tiles.finished_tile_paths(tiles_dir)
    manifest = tiles_dir / MANIFEST
    if not manifest.is_file():
        if found:
            log.warning("%s: no %s; scoring all %d tile_*.h5 files in the folder (they may "
                        "come from more than one run)", tiles_dir, MANIFEST, len(found))
        return found
    try:
        files = json.loads(manifest.read_text())["files"]
        if not isinstance(files, list) or not all(isinstance(n, str) for n in files):
            raise TypeError
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{manifest}: cannot read ({exc})") from None
    except (ValueError, KeyError, TypeError):
        raise ValueError(f"{manifest}: expected a JSON object whose 'files' is a list of "
                         "file names") from None
    listed = [tiles_dir / n for n in files
              if n.endswith(".h5") and Path(n).name == n and not tiles.is_temporary(n)]
    missing = [p.name for p in listed if not p.is_file()]
    if missing:
        raise FileNotFoundError(f"{manifest} lists {', '.join(missing)}, not in {tiles_dir}")
    extra = [p.name for p in found if p not in listed]
    if extra:
        log.warning("%s: %s not listed in %s (another run's?): excluded", tiles_dir,
                    ", ".join(extra), MANIFEST)
    return listed


def score_tiles(tiles_dir: str | Path, scene_path: str | Path,
                radius_m: float | None = None, level: str = "run",
                min_excess_db: float | None = None) -> dict:
    """Score the tiles of ``tiles_dir`` (:func:`tile_paths`) against the scene's
    targets. ``level``: ``"run"`` scores the run's contacts (the tiles' detections
    filtered across tiles: :mod:`svss_proc.products.run_products`, what an operator
    gets, with the calls of the run's contacts file where it has them: :func:`run_calls`),
    ``"tile"`` every tile's own detections and calls. The match radius is ``radius_m`` or
    the ``products.detection.match_radius_m`` the tiles were processed with. A tile that
    cannot be read, or has no detections (processed without products), is an error
    naming it. ``min_excess_db``: only the detections at least this far over their
    background are scored (a higher detection floor applied afterwards, as
    benchmarks/bench_sand_detection.py sweeps it). Returns a JSON-serialisable report, with false alarms per tile and per
    square metre of the tiles' plan area."""
    if level not in ("run", "tile"):
        raise ValueError(f"level is {level!r}; expected 'run' or 'tile'")
    tiles_dir = Path(tiles_dir)
    paths = tile_paths(tiles_dir)
    if not paths:
        raise FileNotFoundError(f"{tiles_dir}: no tile_*.h5 files")
    headers = [tiles.read_tile_header(p) for p in paths]
    for path, header in zip(paths, headers):
        if "detections" not in header["products"]:
            raise tiles.TileFileError(f"{path}: group '/detections' missing (processed "
                                      "without [products]?); nothing to score")
    if radius_m is None:
        radius_m = _radius_from_tile(paths[0], headers[0])
        if radius_m is None:
            raise ValueError(f"{paths[0]}: its processing configuration has no "
                             "products.detection.match_radius_m; give --radius")
    scene = load_scene(scene_path)
    truth = scene_truth(scene)
    truth_ned = truth_line(scene.track).tile_to_ned(
        np.array([t["scene_m"] for t in truth], dtype=np.float64).reshape(-1, 3))
    det_rows, det_ned = [], []
    covered = np.zeros(len(truth), dtype=bool)
    kept = None
    if level == "run":
        try:
            contacts, _ = run_contacts([TileView(p, h) for p, h in zip(paths, headers)])
            kept = {(c["tile"], c["tile_row"]) for c in contacts}
        except tiles.TileFileError as exc:
            log.warning("%s; scoring every tile's own detections instead", exc)
            level = "tile"
    area = 0.0
    for path, header in zip(paths, headers):
        table, attrs = header["detections"], header["attrs"]
        voxel = float(attrs["voxel_m"])
        area += (header["along"].size * voxel) * (header["cross"].size * voxel)
        index = np.arange(len(table))         # each row's place in the tile's table
        if kept is not None and len(table):
            index = index[[(path.name, i) in kept for i in range(len(table))]]
        if min_excess_db is not None and len(table):
            index = index[table["excess_db"][index] >= min_excess_db]
        table = table[index] if len(table) else table
        line = tiles.tile_line(attrs)
        axes = [header[d] for d in tiles.DIMS]
        t_tile = line.ned_to_tile(truth_ned)
        inside = np.ones(len(truth), dtype=bool)
        for k, ax in enumerate(axes):
            # depth: objects resting on the bottom above a tile that starts at the
            # interface are imaged in its top voxels: within the radius counts
            pad = voxel / 2 + (radius_m if k == 2 else 0.0)
            inside &= (t_tile[:, k] >= ax[0] - pad) & (t_tile[:, k] <= ax[-1] + pad)
        covered |= inside
        for t, pos in zip(np.flatnonzero(inside), t_tile[inside]):
            truth[t].setdefault("tile_m", {})[path.name] = pos.tolist()
        if len(table):
            xyz = np.stack([table["along_m"], table["cross_m"], table["depth_m"]], axis=1)
            det_ned.append(line.tile_to_ned(xyz))
            for i, row in zip(index, table):
                det_rows.append({"tile": path.name, "row": int(i),
                                 **{k: row[k].item() for k in detect.DTYPE.names}})
    det_ned = np.concatenate(det_ned) if det_ned else np.zeros((0, 3))
    if level == "run":
        n = run_calls(tiles_dir / CONTACTS_CSV, det_rows)
        log.debug("%s: the calls of %d of %d contact(s) from %s", tiles_dir, n,
                 len(det_rows), CONTACTS_CSV)
    scored = np.flatnonzero(covered)
    result = score(det_ned, truth_ned[scored], radius_m,
                   np.array([half_extent(truth[t]) for t in scored]))
    for t in truth:
        t["status"] = "outside"
        t["class"] = truth_class(t)
    for t in scored:
        truth[t]["status"] = "missed"
    for ti, di, dist in result.pairs:
        t = truth[scored[ti]]
        p = det_rows[di].get("p_manmade")
        t.update(status="detected", detection=di, distance_m=dist,
                 excess_db=det_rows[di]["excess_db"],
                 called=class_text(det_rows[di].get("class", -2)) or "not classified",
                 p_manmade=None if p is None or p != p else float(p))
    for di in result.false_alarms:
        det_rows[di]["status"] = "false alarm"
    for di in result.duplicates:
        det_rows[di]["status"] = "duplicate"
    for _, di, _ in result.pairs:
        det_rows[di]["status"] = "hit"
    summary = result.summary()
    summary["per_class"] = per_class(truth)
    summary["outside"] = int(len(truth) - scored.size)
    per_tile = {p.name: 0 for p in paths}
    for di in result.false_alarms:
        per_tile[det_rows[di]["tile"]] += 1
    summary.update(level=level, plan_area_m2=area,
                   false_alarms_per_tile=len(result.false_alarms) / len(paths),
                   false_alarms_per_m2=len(result.false_alarms) / area if area else None,
                   false_alarms_by_tile=per_tile)
    return {"tiles_dir": str(tiles_dir), "scene": str(scene_path), "scene_name":
            scene.scene.name, "tiles": [p.name for p in paths], "match_radius_m": radius_m,
            "summary": summary, "truth": truth, "detections": det_rows}


def run_calls(path: Path, det_rows: list[dict]) -> int:
    """Each scored run contact's call as the run's contacts file gives it (``class``,
    ``p_manmade``, ``class_from``, and the pings' ``late_over_background_db``; the tile's
    own as ``class_image`` and ``p_manmade_image``): the call
    made at the run's end with the pings' features (``[products.classify_pings]``) where
    ``svss process`` measured them, what the operator gets. Matched by tile and row,
    the same excess within 0.01 dB and depth within 1 cm; a file missing or from other
    tiles changes nothing. Returns how many rows took the file's call."""
    rows = contacts_by_row(path, "the tiles' calls are scored")
    n = 0
    for d in det_rows:
        r = rows.get((d["tile"], str(d["row"])))
        try:
            if r is None or abs(float(r["excess_db"]) - d["excess_db"]) > 0.01 \
                    or abs(float(r["depth_below_seabed_m"]) - d["depth_m"]) > 0.01:
                continue
            d.update({"class_image": d.get("class"), "p_manmade_image": d.get("p_manmade"),
                      "class": CLASS_CODE[r["class"]], "class_from": r.get("class_from", ""),
                      "p_manmade": float(r["p_manmade"]) if r["p_manmade"] else float("nan"),
                      "late_over_background_db": float(r["late_over_background_db"])
                      if r.get("late_over_background_db") else float("nan")})
        except (KeyError, ValueError):
            continue
        n += 1
    return n


def _f(v) -> str:
    return "-" if v is None else f"{v:.2f}"


def format_report(r: dict) -> str:
    """Text of a :func:`score_tiles` report."""
    s = r["summary"]
    lines = [f"scene {r['scene_name']} against {len(r['tiles'])} tile(s) in {r['tiles_dir']}"
             f" (match radius {r['match_radius_m']:g} m)",
             f"  {s['truth']} target(s) in the imaged volume ({s['outside']} outside), "
             f"{s['detections']} detection(s): {s['hits']} detected, {s['misses']} missed, "
             f"{s['false_alarms']} false alarm(s), {s['duplicates']} duplicate(s); "
             f"Pd = {_f(s['probability_of_detection'])}",
             f"  {s.get('level', 'tile')}-level detections; false alarms: "
             f"{s.get('false_alarms_per_tile', float('nan')):.2f} per tile, "
             f"{s.get('false_alarms_per_m2') or 0.0:.3g} per m2 of "
             f"{s.get('plan_area_m2', float('nan')):.1f} m2 imaged (plan)",
             ]
    for cls, row in s.get("per_class", {}).items():
        lines.append(f"  {cls}: {row['detected']}/{row['targets']} detected; called "
                     f"man-made {row['man-made']}, natural {row['natural']}, undecided "
                     f"{row['undecided']}, not classified {row['not classified']} "
                     f"(man-made {row['called_manmade_fraction']:.2f} of the class)")
    lines.append("  target        along_m  cross_m  depth_m  status     dist_m  excess_dB"
                 "  class     called     p_manmade")
    for t in r["truth"]:
        a, c, d = t["scene_m"]
        dist = f"{t['distance_m']:.3f}" if "distance_m" in t else "-"
        exc = f"{t['excess_db']:.1f}" if "excess_db" in t else "-"
        p = t.get("p_manmade")
        p = f"{p:.2f}" if isinstance(p, float) and p == p else "-"
        lines.append(f"  {t['table']}[{t['index']}]".ljust(15) + f"{a:7.3f} {c:8.3f} {d:8.3f}"
                     f"  {t['status']:<9} {dist:>7} {exc:>10}  {t.get('class', '-'):<9} "
                     f"{t.get('called', '-'):<14} {p:>5}")
    fa = [d for d in r["detections"] if d.get("status") == "false alarm"]
    if fa:
        lines.append("  false alarms (tile frame):")
        for d in fa:
            lines.append(f"    {d['tile']}#{d['row']}: along {d['along_m']:.3f} cross "
                         f"{d['cross_m']:.3f} depth {d['depth_m']:.3f} m, excess "
                         f"{d['excess_db']:.1f} dB")
    return "\n".join(lines)
