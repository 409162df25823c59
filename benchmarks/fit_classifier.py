#!/usr/bin/env python
"""Fit the contact classifier (svss_proc.products.classify; docs/classification.md) on
simulated training fields, apart from the test fields of
benchmarks/bench_classify.py.

Each training field (``config/scenes/classify_train_*.toml``: shot puts, steel shells
empty and filled, aluminium cylinders of 30.5 and 61 cm at several headings, granite
slabs flat and tilted, proud and buried 0-0.5 m in silt over stiff clay or medium sand)
is simulated once into ``--cache`` (``svss simulate``) and processed with ``svss process`` and the
shipped ``config/processing.toml`` (the sediment's speed estimated from the echoes, as
a crew would run it). The run's contacts are matched to the scene's targets
(:func:`svss.score.score_tiles`); each detected target's features (its contact's) and
its truth class (man-made: metal; natural: rock) make one training row. Rows with a
missing feature, or a flag of ``undecided_flags``, are left out (the product calls them
undecided).

The model: a logistic regression on the standardised features (the training rows' mean
and standard deviation), by maximum likelihood with a small ridge penalty
(``--l2``, on the standardised coefficients, not the intercept: a separable training
set has no finite maximum without it). ``--write`` puts ``features``, ``mean``,
``scale``, ``coefficients`` and ``intercept`` into ``[products.classify]`` of
config/processing.toml (the thresholds are left as configured).

``--table products.classify_pings`` fits the run-level model instead, whose features may
include the recorded pings' (``late_over_background_db``, measured by ``svss process``
at the run's end and read from the run's contacts file): on the training targets with
every one of its features measured, written into ``[products.classify_pings]``.

    python benchmarks/fit_classifier.py --cache /tmp/bench_classify --out benchmarks/results/fit_classifier.json --write
    python benchmarks/fit_classifier.py --cache /tmp/bench_classify --table products.classify_pings --features aspect_width_deg late_to_specular_db late_over_background_db --out benchmarks/results/fit_classifier_pings.json --write
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import re
import sys
from pathlib import Path

import h5py
import numpy as np
from scipy.optimize import minimize

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_false_alarms import _run, simulated_line  # noqa: E402
from bench_isa import machine_isa  # noqa: E402
from svss.score import score_tiles  # noqa: E402
from svss_daq.config import ProcessingConfig, config_path, load  # noqa: E402
from svss_proc.products.classify import class_text, logistic  # noqa: E402
from svss_proc.products.contact_features import (FEATURE_NAMES, flags_text,  # noqa: E402
                                                 point_fraction)

log = logging.getLogger("fit_classifier")

TRAIN = ("classify_train_1", "classify_train_2", "classify_train_3", "classify_train_4",
         "classify_train_5", "classify_train_6", "classify_train_7")
#: the model's features (physically motivated: docs/classification.md)
FEATURES = ("aspect_width_deg", "late_to_specular_db")
#: targets whose response is a point's both ways: the references of the point fraction
POINT_KINDS = ("sphere", "shell")
PROCESSING = ROOT / "config" / "processing.toml"


def processed(name: str, cache: Path, processing: Path, tag: str, force: bool) -> Path:
    """Field ``name`` simulated once into ``cache`` and processed with ``processing``
    into ``cache/<name>-<tag>`` (reused where its manifest is there, unless ``force``)."""
    raw = simulated_line(name, cache)
    out = cache / f"{name}-{tag}"
    if force or not (out / "manifest.json").is_file():
        secs = _run([sys.executable, "-m", "svss", "process", str(raw), "--out", str(out),
                     "--processing", str(processing), "--force"],
                    cache / f"{name}-{tag}.log")
        log.info("%s (%s): processed in %.0f s", name, tag, secs)
    return out


#: a voxel this close to the interface (m, either side) is in the interface's own echo
INTERFACE_LAYER_M = 0.05


def peak_near(tiles_dir: Path, at_m, radius_m: float = 0.35) -> dict | None:
    """The brightest voxel within ``radius_m`` along, across and in depth of ``at_m``
    (along, cross, depth in the tiles' frame: these fields' tracks start at the origin
    heading north, so the scene's frame), over the tiles that hold it: its level over its
    background (``db``), where it is (``at_m``) and whether it lies in the interface's
    own echo (``interface``: within :data:`INTERFACE_LAYER_M` of it, above or below:
    then the level may be the interface's, not the target's); None where no tile holds
    it. What a missed target reached against the detection threshold."""
    best = None
    for path in sorted(Path(tiles_dir).glob("tile_*.h5")):
        with h5py.File(path, "r") as f:
            axes = [f[k][:] for k in ("along", "cross", "depth")]
            box = [np.flatnonzero(np.abs(ax - float(x)) <= radius_m)
                   for ax, x in zip(axes, at_m)]
            if any(b.size == 0 for b in box):
                continue
            sl = tuple(slice(b[0], b[-1] + 1) for b in box)
            img = np.abs(f["image"][sl])
            bg = f["background"][sl]
        with np.errstate(divide="ignore", invalid="ignore"):
            level = 20.0 * np.log10(img / bg)
        level = np.where(np.isfinite(level), level, -np.inf)
        k = np.unravel_index(int(np.argmax(level)), level.shape)
        if np.isfinite(level[k]) and (best is None or level[k] > best["db"]):
            where = [float(ax[b[0] + i]) for ax, b, i in zip(axes, box, k)]
            best = {"db": float(level[k]), "at_m": where,
                    "interface": abs(where[2]) <= INTERFACE_LAYER_M}
    return best


def field_rows(name: str, tiles_dir: Path) -> list[dict]:
    """One row per target of the field's scene: its truth class, status, and where
    detected its contact's features, class and p_manmade (:func:`score_tiles`)."""
    scene = ROOT / "config" / "scenes" / f"{name}.toml"
    r = score_tiles(tiles_dir, scene)
    rows = []
    for t in r["truth"]:
        f = t["fields"]
        row = {"scene": name, "target": f.get("description") or f.get("kind", t["table"]),
               "kind": f.get("kind"), "material": f.get("material"),
               "truth_m": t["scene_m"], "class": t["class"], "status": t["status"]}
        if t["status"] == "detected":
            d = r["detections"][t["detection"]]
            row.update({"excess_db": d["excess_db"], "depth_m": d["depth_m"],
                        **{n: d[n] for n in FEATURE_NAMES},
                        "late_over_background_db": d.get("late_over_background_db",
                                                         math.nan),
                        "feature_notes": flags_text(int(d["feature_flags"])),
                        "called": class_text(int(d["class"])) or "not classified",
                        "called_image": class_text(int(d.get("class_image", d["class"])))
                        or "not classified",
                        "class_from": d.get("class_from", ""),
                        "p_manmade": _probability(d["p_manmade"]),
                        "p_manmade_image": _probability(d.get("p_manmade_image",
                                                              d["p_manmade"]))})
        elif t["status"] == "missed":
            peak = peak_near(tiles_dir, t["scene_m"])
            row.update({"peak_excess_db": None, "peak_at_m": None,
                        "peak_in_interface_echo": None} if peak is None else
                       {"peak_excess_db": peak["db"], "peak_at_m": peak["at_m"],
                        "peak_in_interface_echo": peak["interface"]})
        rows.append(row)
    return rows


def _probability(p) -> float | None:
    return None if p is None or p != p else float(p)


def point_reference(rows: list[dict]) -> list[float]:
    """A point scatterer's look-angle spreads (along, across; deg): the median over the
    detected spheres and shells of ``rows`` (``[products.features] point_aspect_deg``)."""
    pts = [r for r in rows if r["status"] == "detected" and r["kind"] in POINT_KINDS
           and all(math.isfinite(r[n]) for n in ("aspect_width_deg", "aspect_cross_width_deg"))]
    if not pts:
        raise ValueError("no detected sphere or shell with both aspects measured: no point "
                         "reference")
    return [float(np.median([r[n] for r in pts]))
            for n in ("aspect_width_deg", "aspect_cross_width_deg")]


def with_point_fraction(rows: list[dict], ref) -> None:
    """Each detected row's ``aspect_point_fraction`` (and error) against ``ref``
    (the fields may have been processed with other references)."""
    for r in rows:
        if r["status"] == "detected":
            r["aspect_point_fraction"], r["aspect_point_fraction_err"] = point_fraction(
                (r["aspect_width_deg"], r["aspect_cross_width_deg"]),
                (r["aspect_width_err_deg"], r["aspect_cross_width_err_deg"]), ref)


def usable(row: dict, features, undecided_flags) -> bool:
    """A detected man-made or natural target whose features are all measured and not
    flagged undecided."""
    if row["status"] != "detected" or row["class"] not in ("man-made", "natural"):
        return False
    flags = int(row["feature_flags"])
    mask = 0
    for b in undecided_flags:
        mask |= int(b)
    return flags >= 0 and not flags & mask and all(
        row[n] is not None and math.isfinite(row[n]) for n in features)


def fit_logistic(x: np.ndarray, y: np.ndarray, l2: float) -> dict:
    """Logistic regression of ``y`` (1 man-made, 0 natural) on ``x`` (n, k): the
    features standardised by their mean and (population) standard deviation, maximum
    likelihood with ``l2`` * |w|^2 / 2 on the standardised weights. Returns mean, scale,
    coefficients, intercept and the penalised negative log-likelihood."""
    mean = x.mean(axis=0)
    scale = x.std(axis=0)
    scale[scale <= 0] = 1.0
    z = (x - mean) / scale

    def cost(theta):
        t = theta[0] + z @ theta[1:]
        # -log-likelihood: sum log(1 + e^t) - y t, stably
        nll = np.sum(np.logaddexp(0.0, t) - y * t) + 0.5 * l2 * np.sum(theta[1:] ** 2)
        g = logistic(t) - y
        grad = np.concatenate([[g.sum()], z.T @ g + l2 * theta[1:]])
        return nll, grad

    res = minimize(cost, np.zeros(z.shape[1] + 1), jac=True, method="BFGS")
    return {"mean": mean.tolist(), "scale": scale.tolist(),
            "coefficients": res.x[1:].tolist(), "intercept": float(res.x[0]),
            "neg_log_likelihood": float(res.fun), "converged": bool(res.success)}


def leave_one_out(x: np.ndarray, y: np.ndarray, l2: float) -> np.ndarray:
    """Each row's p_manmade from the model fitted without it (the training set's own
    estimate of how the model does on targets it has not seen)."""
    out = np.full(len(y), np.nan)
    for i in range(len(y)):
        keep = np.arange(len(y)) != i
        m = fit_logistic(x[keep], y[keep], l2)
        z = (x[i] - np.array(m["mean"])) / np.array(m["scale"])
        out[i] = logistic(np.array([m["intercept"] + z @ np.array(m["coefficients"])]))[0]
    return out


def _toml_list(v) -> str:
    return "[" + ", ".join(f'"{x}"' if isinstance(x, str) else f"{x:.4g}" for x in v) + "]"


def _replace_keys(text: str, table: str, values: dict, path: Path) -> str:
    """``text`` with each ``key = ...`` line of ``[table]`` set to ``values[key]`` (its
    comment kept)."""
    start = text.index(f"[{table}]")
    end = text.find("\n[", start + 1)
    end = len(text) if end < 0 else end
    block = text[start:end]
    for key, v in values.items():
        block, n = re.subn(rf"(?m)^{key} = [^#\n]*?(\s*#.*)?$",
                           lambda m, k=key, v=v: f"{k} = {v}" + (
                               m.group(1) if m.group(1) else ""), block, count=1)
        if n != 1:
            raise ValueError(f"{path}: [{table}] has no '{key}' line to replace")
    return text[:start] + block + text[end:]


def write_model(model: dict, features, point_ref, path: Path = PROCESSING,
                table: str = "products.classify") -> None:
    """Put the fitted ``features``, ``mean``, ``scale``, ``coefficients`` and
    ``intercept`` into ``[table]`` of ``path``, and with the image's model
    (``products.classify``) the point reference into ``[products.features]
    point_aspect_deg``."""
    text = _replace_keys(path.read_text(), table, {
        "features": _toml_list(features), "mean": _toml_list(model["mean"]),
        "scale": _toml_list(model["scale"]),
        "coefficients": _toml_list(model["coefficients"]),
        "intercept": f"{model['intercept']:.4g}"}, path)
    if table == "products.classify":
        text = _replace_keys(text, "products.features",
                             {"point_aspect_deg": _toml_list(point_ref)}, path)
    path.write_text(text)
    load(ProcessingConfig, path)          # still valid


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--features", nargs="+", default=list(FEATURES))
    ap.add_argument("--l2", type=float, default=1.0,
                    help="ridge penalty on the standardised coefficients (default 1)")
    ap.add_argument("--write", action="store_true",
                    help="write the fitted model into config/processing.toml")
    ap.add_argument("--table", default="products.classify",
                    choices=("products.classify", "products.classify_pings"),
                    help="the model fitted and written: the image's (default) or the "
                         "run's, which may use the pings' features and is fitted on the "
                         "targets they were measured for")
    ap.add_argument("--reprocess", action="store_true",
                    help="process the fields again even where their output is cached")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s",
                        datefmt="%H:%M:%S")
    args.cache.mkdir(parents=True, exist_ok=True)
    ccfg = getattr(load(ProcessingConfig, config_path("processing.toml")).products,
                   args.table.split(".")[1])
    flags = ccfg.undecided_flags if ccfg is not None else ()
    rows = []
    for name in TRAIN:
        out = processed(name, args.cache, PROCESSING, "shipped", args.reprocess)
        rows += field_rows(name, out)
    point_ref = point_reference(rows)
    with_point_fraction(rows, point_ref)
    log.info("a point's look-angle spreads (the training spheres' and shells' median): "
             "%.2f deg along, %.2f across", *point_ref)
    train = [r for r in rows if usable(r, args.features, flags)]
    x = np.array([[r[n] for n in args.features] for r in train], dtype=np.float64)
    y = np.array([r["class"] == "man-made" for r in train], dtype=np.float64)
    model = fit_logistic(x, y, args.l2)
    cfg = type("M", (), {**model, "features": args.features})
    z = (x - np.array(cfg.mean)) / np.array(cfg.scale)
    p = logistic(cfg.intercept + z @ np.array(cfg.coefficients))
    for r, pi, pl in zip(train, p, leave_one_out(x, y, args.l2)):
        r["p_fit"], r["p_leave_one_out"] = float(pi), float(pl)
    for r in rows:
        log.info("%-18s %-9s %-8s %-70s aspect %5.1f across %4.1f point %4.2f  L/S %6.1f  "
                 "p %s (left out: %s)", r["scene"], r["class"], r["status"], r["target"][:70],
                 r.get("aspect_width_deg", np.nan), r.get("aspect_cross_width_deg", np.nan),
                 r.get("aspect_point_fraction", np.nan),
                 r.get("late_to_specular_db", np.nan),
                 f"{r['p_fit']:.2f}" if "p_fit" in r else "-",
                 f"{r['p_leave_one_out']:.2f}" if "p_leave_one_out" in r else "-")
    acc = float(np.mean((p > 0.5) == (y > 0.5))) if len(y) else float("nan")
    loo = np.array([r["p_leave_one_out"] for r in train])
    thr = ccfg.manmade_above if ccfg is not None else 0.5
    loo_rates = {"manmade_called": float(np.mean(loo[y > 0.5] > thr)),
                 "natural_called": float(np.mean(loo[y < 0.5] > thr)), "threshold": thr}
    log.info("leave-one-out on the training targets at p > %.2f: man-made called "
             "man-made %.2f, natural called man-made %.2f", thr,
             loo_rates["manmade_called"], loo_rates["natural_called"])
    log.info("fitted on %d of %d targets (%d man-made, %d natural): %s; training accuracy "
             "at 0.5: %.2f", len(train), len(rows), int(y.sum()), int(len(y) - y.sum()),
             {k: model[k] for k in ("mean", "scale", "coefficients", "intercept")}, acc)
    if args.write:
        write_model(model, args.features, point_ref, table=args.table)
        log.info("written to %s [%s]", PROCESSING, args.table)
    if args.out:
        args.out.write_text(json.dumps({
            "machine": machine_isa(), "command": " ".join(["python"] + sys.argv),
            "fields": list(TRAIN), "table": args.table, "features": args.features,
            "l2": args.l2,
            "point_aspect_deg": point_ref,
            "model": model, "training_accuracy_at_0.5": acc, "n_fit": len(train),
            "leave_one_out": loo_rates,
            "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
