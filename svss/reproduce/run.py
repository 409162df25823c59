"""``svss reproduce``: simulate the seed's scenes, image them, measure, draw, report.

The cases (:func:`plan`): both arrays (the paper-era 4 x 8 with five projectors, the
80-channel field array) x both sediments (medium sand, very fine silt) x both cylinder
orientations (axis across and along the track); seabed realisations (other seeds) and
roughness-spectrum variants for the configuration the report argues is the seed's
(:data:`SEED_CONFIG`); the Sayers-like test field with the 80-channel array. Each case
simulates only the pings whose projector cone reaches the target down to 1.2 m
(:func:`case_pings`) and images three regions with the exact sediment speed
(:mod:`.image`): a narrow column under the track for the depth profile, a box about the
target for its excess, and (for the figure cases) a wide box for the slices.

``quick``: one extra seed, fewer variants, the test field shortened to three of its
objects, figure voxels of 4 cm, and 1 scatterer per
resolution cell instead of the scene files' 2 (docs/simulator_speed.md: the level, profile
and background at the target stay within the statistical floor of another seabed).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import figures, image, measures, report, scenes
from .scenes import Variant

log = logging.getLogger(__name__)

#: the configuration the report argues is the seed's (docs/reproduce.md): the paper-era
#: array with the cylinder's axis along the track
SEED_CONFIG = {"array": "paper", "axis": "along"}
#: the seeds of the extra seabed realisations (the scene files' seed is the first)
EXTRA_SEEDS = (101, 202, 303, 404, 505, 606, 707, 808, 909)
#: roughness-spectrum variants (sand): gamma tilted about K = 2k, w2 scaled
ROUGHNESS = (Variant(gamma=3.0), Variant(gamma=3.5), Variant(w2_scale=0.5),
             Variant(w2_scale=2.0))
#: imaging depth of the regions (m): the profile reaches below the second-order
#: multipath (2.945 m by the path arithmetic)
PROFILE_DEPTH = (-0.3, 3.5)
#: the profile's voxel (m): 1 cm, a sixth of the sand's depth resolution c/(2B) = 5.9 cm;
#: 2 cm voxels put the parabola-refined second-order peak 7 mm deep (2.951 against
#: 2.944 m at 1 cm, same seabed)
PROFILE_VOXEL = 0.01
#: the profile's column under the track: |cross| <= this (m)
PROFILE_HALF_WIDTH = 0.05
TARGET_DEPTH = (0.5, 1.5)
FIGURE_DEPTH = (-0.2, 3.3)


@dataclass(frozen=True)
class Case:
    """One simulation: ``array``, ``scene`` ("sand", "silt"), ``variant``, whether it
    draws the slices figure, and its ``group`` in the report."""
    array: str
    scene: str
    variant: Variant
    figure: bool = False
    group: str = "main"

    @property
    def tag(self) -> str:
        v = self.variant
        parts = [self.array, self.scene, v.axis]
        if v.gamma is not None:
            parts.append(f"g{v.gamma:g}")
        if v.w2_scale != 1.0:
            parts.append(f"w2x{v.w2_scale:g}")
        if v.seed is not None:
            parts.append(f"s{v.seed}")
        return "_".join(parts)


def plan(quick: bool, n_seeds: int) -> list[Case]:
    """The cases of a run (see the module docstring); ``n_seeds`` seabeds in all for the
    seed's configuration (the scene file's seed and ``n_seeds - 1`` more)."""
    per_cell = 1.0 if quick else None
    arr, axis = SEED_CONFIG["array"], SEED_CONFIG["axis"]
    cases = []
    for array in ("paper", "80ch"):
        for sed in ("sand", "silt"):
            for ax in ("across", "along"):
                if quick and array != arr and ax != axis:
                    continue
                cases.append(Case(array, sed, Variant(axis=ax, per_cell=per_cell),
                                  figure=(array == arr and ax == axis)))
    for seed in EXTRA_SEEDS[:max(n_seeds - 1, 0)]:
        for sed in ("sand", "silt"):
            cases.append(Case(arr, sed, Variant(axis=axis, seed=seed, per_cell=per_cell),
                              group="seeds"))
    for v in (ROUGHNESS[1:2] if quick else ROUGHNESS):
        cases.append(Case(arr, "sand", dataclasses.replace(v, axis=axis, per_cell=per_cell),
                          group="roughness"))
    return cases


def case_pings(src, target) -> range:
    """The pings whose projector cone reaches the target's column down to 1.2 m (the
    target's full synthetic aperture), with 0.3 m to spare on each side."""
    r = scenes.reach_m(src, 1.2)
    return scenes.pings_over(src, target.along_m - r - 0.3, target.along_m + r + 0.3)


def regions(target, quick: bool, figure: bool) -> dict[str, image.Region]:
    """The regions a case images about ``target`` (see the module docstring)."""
    a = target.along_m
    out = {"profile": image.Region((a - 1.2, a + 1.2), PROFILE_HALF_WIDTH, *PROFILE_DEPTH,
                                   PROFILE_VOXEL),
           "target": image.Region((a - 1.0, a + 1.0), 0.3, *TARGET_DEPTH, 0.02)}
    if figure:
        out["figure"] = image.Region((a - 2.0, a + 2.0), 1.0, *FIGURE_DEPTH,
                                     0.04 if quick else 0.02)
    return out


def measure_case(case: Case, quick: bool) -> tuple[dict, dict]:
    """Simulate, image and measure one case; returns (result, volumes for figures)."""
    src = scenes.source(case.array, case.scene, case.variant)
    tgt = src.scene.targets[0]
    pings = case_pings(src, tgt)
    vols, times = image.image_regions(src, pings, regions(tgt, quick, case.figure), case.tag)
    p = vols["profile"]
    prof = measures.depth_profile(p.image, p.axes, half_width=PROFILE_HALF_WIDTH,
                                  exclude_along=(tgt.along_m, 0.6))
    db = measures.to_db(prof)
    first, second, feats = measures.multipath_features(p.depth, db)
    t = vols["target"]
    exc = measures.target_excess(t.image, t.axes, t.voxel,
                                 (tgt.along_m, tgt.cross_m, tgt.depth_m))
    sur = measures.surround_excess(t.image, t.axes, (tgt.along_m, tgt.cross_m, tgt.depth_m))
    cw, cs = float(src.media.c[0]), float(src.media.c[1])
    res = {"tag": case.tag, "array": case.array, "scene": case.scene,
           "group": case.group, "variant": dataclasses.asdict(case.variant),
           "label": case.variant.label(), "ping_range": [pings.start, pings.stop - 1],
           "n_channels": int(src.hw.digitiser.n_channels), "water_speed": cw,
           "sediment_speed": cs, "excess_db": exc.excess_db, "peak": exc.peak,
           "surround_excess_db": sur.excess_db,
           "first": None if first is None else dataclasses.asdict(first),
           "second": None if second is None else dataclasses.asdict(second),
           "features": [dataclasses.asdict(f) for f in feats],
           "profile_depth": p.depth.tolist(), "profile_db": db.tolist(), **times}
    log.info("%s: excess %.1f dB (re surroundings %.1f dB) at %s; multipath features %s; "
             "%.0f s", case.tag, exc.excess_db, sur.excess_db,
             tuple(round(x, 2) for x in exc.peak),
             [round(f.depth, 3) for f in feats], times["simulation_s"] + times["imaging_s"])
    keep = {"figure": vols["figure"]} if "figure" in vols else {}
    return res, keep


def field_case(out: Path, quick: bool) -> dict:
    """The Sayers-like test field with the 80-channel array: image, products (the
    processing configuration's [products]: 3-D median background, normalisation,
    compression), the depth slice and the cross-track MIP."""
    from svss_daq.config import ProcessingConfig, config_path, load
    from svss_proc.products.chain import compute_products
    src = scenes.source("80ch", "field", Variant(per_cell=1.0 if quick else None))
    # quick: three objects (a proud cylinder at 45 deg, a shot put 10 cm deep, a
    # cylinder 15 cm deep) instead of nine
    targets = src.scene.targets[3:6] if quick else src.scene.targets
    lo = min(t.along_m for t in targets) - 1.0
    hi = max(t.along_m for t in targets) + 1.0
    r = scenes.reach_m(src, 0.8)
    pings = scenes.pings_over(src, lo - r, hi + r)
    region = image.Region((lo, hi), 1.0, -0.3, 1.0, 0.04 if quick else 0.02)
    vols, times = image.image_regions(src, pings, {"field": region}, "field")
    v = vols["field"]
    cfg = load(ProcessingConfig, config_path("processing.toml")).products
    prod = compute_products(v.image, v.axes, v.voxel, cfg)
    d = cfg.drc
    from svss_proc.products.drc import compress
    mip = compress(prod.mips["mip_cross"], d.floor_db, d.knee_db, d.ceiling_db)
    marks = [(t.along_m, t.cross_m, t.depth_m, f"{t.kind[:3]} {t.depth_m:+.2f}")
             for t in targets]
    depth_slice = 0.15
    path = figures.field_figure(out / "field_slice_mip.png", prod.drc, mip, v.axes,
                                depth_slice, marks,
                                f"Sayers-like test field, 80-channel array, pings "
                                f"{pings.start}-{pings.stop - 1}: depth slice and "
                                f"cross-track MIP after background normalisation and "
                                f"compression")
    det = prod.detections
    return {**times, "figure": path.name, "ping_range": [pings.start, pings.stop - 1],
            "n_targets": len(targets), "depth_slice_m": depth_slice,
            "detections": len(det)}


def run(out: str | Path, quick: bool = False, n_seeds: int | None = None,
        field: bool = True) -> Path:
    """The whole reproduction into folder ``out``; returns the report's path."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    n_seeds = (2 if quick else 5) if n_seeds is None else n_seeds
    if n_seeds < 1:
        raise ValueError(f"--seeds must be at least 1, got {n_seeds}")
    t0 = time.perf_counter()
    cases = plan(quick, n_seeds)
    log.info("reproduce: %d cases%s into %s", len(cases), " (quick)" if quick else "", out)
    results, figs = [], {}
    for n, case in enumerate(cases):
        log.info("case %d of %d: %s", n + 1, len(cases), case.tag)
        res, vols = measure_case(case, quick)
        results.append(res)
        if "figure" in vols:
            v = vols["figure"]
            gain = 10.0 if case.scene == "sand" else 0.0
            name = f"slices_{case.scene}_{case.array}_{case.variant.axis}.png"
            figures.orthogonal_slices(
                out / name, v.image, v.axes, tuple(res["peak"]),
                f"{case.scene}, {case.array} array, cylinder axis {case.variant.axis} the "
                f"track: three slices through the target peak"
                + (" (10 dB/m depth-varying gain)" if gain else ""), gain_db_per_m=gain)
            figs[case.scene] = name
    main = [r for r in results if r["group"] == "main" and r["scene"] == "sand"]
    prof = {f"{r['array']}, axis {r['variant']['axis']}": np.asarray(r["profile_db"])
            for r in main}
    feats = {f"{r['array']}, axis {r['variant']['axis']}":
             [measures.Feature(**f) for f in r["features"]] for r in main}
    cw, cs = main[0]["water_speed"], main[0]["sediment_speed"]
    expected = {"first order (1 m)": measures.multipath_depth_expected(1.0, cw, cs),
                "second order (5 m)": measures.multipath_depth_expected(5.0, cw, cs)}
    figures.profile_figure(out / "profile_sand.png", np.asarray(main[0]["profile_depth"]),
                           prof, feats, expected,
                           "medium sand: background under the track (|cross| <= 0.05 m, "
                           "the target's columns left out)")
    figs["profile"] = "profile_sand.png"
    fld = field_case(out, quick) if field else None
    elapsed = time.perf_counter() - t0
    summary = {"quick": quick, "n_seeds": n_seeds, "elapsed_s": elapsed, "cases": results,
               "field": fld, "figures": figs, "expected": expected,
               "seed_config": SEED_CONFIG}
    (out / "results.json").write_text(json.dumps(summary, indent=1))
    path = report.write_report(out / "report.md", summary)
    log.info("reproduce: report %s (%.0f s)", path, elapsed)
    return path
