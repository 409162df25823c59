"""Pareto fronts, the defaults' place on them, a recommendation for a time budget, and
the table (CSV, JSON, markdown) and plots (PNG) of a trade run."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

#: timings on a shared machine scatter: one row dominates another only if it is at
#: least this much faster (relative) or, at equal time, less in error
TIME_TOLERANCE = 0.10
#: errors below this are equal (imaging: relative RMS; others: dB)
ERROR_TOLERANCE = {"imaging": 1e-4, "simulation": 0.05, "normalisation": 1e-3}


def dominates(a: dict, b: dict, area: str) -> bool:
    """``a`` is as good as ``b`` in time and error, and better in one beyond noise."""
    et = ERROR_TOLERANCE[area]
    faster = a["tile_s"] < b["tile_s"] * (1 - TIME_TOLERANCE)
    not_slower = a["tile_s"] <= b["tile_s"] * (1 + TIME_TOLERANCE)
    better = a["error"] < b["error"] - et
    not_worse = a["error"] <= b["error"] + et
    return (faster and not_worse) or (better and not_slower)


def mark_front(rows: list[dict]) -> None:
    """Set ``on_front`` on every row of one area (rows marked ``is_floor`` take no part)."""
    cands = [r for r in rows if not r.get("is_floor")]
    for r in rows:
        r["on_front"] = (not r.get("is_floor")) and not any(
            dominates(o, r, r["area"]) for o in cands if o is not r)


def recommend(rows: list[dict], budget_s: float) -> dict | None:
    """The least-error row whose time per tile fits ``budget_s`` (ties: the faster)."""
    ok = [r for r in rows if not r.get("is_floor") and r["tile_s"] <= budget_s]
    return min(ok, key=lambda r: (r["error"], r["tile_s"])) if ok else None


def recommend_chain(imaging: list[dict], norm: list[dict], budget_s: float):
    """(imaging row, normalisation row) of least imaging error, then least background
    error, whose times per tile add up to at most ``budget_s``."""
    best = None
    for a in imaging:
        for b in norm:
            if a["tile_s"] + b["tile_s"] <= budget_s:
                key = (a["error"], b["error"], a["tile_s"] + b["tile_s"])
                if best is None or key < best[0]:
                    best = (key, a, b)
    return None if best is None else (best[1], best[2])


def describe(r: dict | None) -> str:
    return "none fits" if r is None else f"{r['option']} = {r['value']}"


def _fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        if not math.isfinite(v):
            return "-inf" if v < 0 else "inf"
        return f"{v:.3g}"
    return str(v)


COLUMNS = ("area", "option", "value", "time_s", "tile_s", "error", "on_front",
           "is_default", "is_reference")
EXTRA = {"imaging": ("rel_rms_db", "vs_default_db", "peak_db", "peak_shift_m", "error_basis",
                    "cpu_s"),
         "simulation": ("d_level_db", "d_contrast_db", "d_excess_db", "scintillation",
                        "ks_exponential"),
         "normalisation": ("max_db", "mean_db")}


def flat_rows(rows: list[dict]) -> list[dict]:
    out = []
    for r in rows:
        d = {k: r.get(k) for k in COLUMNS}
        for k in EXTRA[r["area"]]:
            d[k] = r["metrics"].get(k, r.get(k))
        out.append(d)
    return out


def _json_safe(x):
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {str(k): _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    return x


def markdown(result) -> str:
    lines = [f"Machine: {result.machine}", "",
             f"Workloads: {'; '.join(f'{k}: {v}' for k, v in result.workloads.items())}", ""]
    for area, rows in result.areas.items():
        extra = EXTRA[area]
        lines += [f"### {area}", "", f"Error: {rows[0]['error_name']}.", "",
                  "| option | value | time (s) | s per tile | error | " +
                  " | ".join(extra) + " | front |",
                  "|" + "---|" * (6 + len(extra))]
        for r in rows:
            tag = " (default)" if r["is_default"] else " (reference)" if r[
                "is_reference"] else ""
            lines.append(f"| {r['option']}{tag} | {r['value']} | {_fmt(r['time_s'])} | "
                         f"{_fmt(r['tile_s'])} | {_fmt(r['error'])} | " +
                         " | ".join(_fmt(r['metrics'].get(k, r.get(k))) for k in extra) +
                         f" | {'yes' if r['on_front'] else ''} |")
        lines.append("")
    lines += ["### Defaults and recommendation", ""] + [f"- {s}" for s in result.summary]
    return "\n".join(lines) + "\n"


def write(result, out: Path) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    rows = [r for rs in result.areas.values() for r in rs]
    flat = flat_rows(rows)
    keys = list(dict.fromkeys(k for d in flat for k in d))
    paths = [out / "trade.csv", out / "trade.json", out / "trade.md"]
    with open(paths[0], "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        for d in flat:
            w.writerow({k: d.get(k) for k in keys})
    paths[1].write_text(json.dumps(_json_safe({
        "machine": result.machine, "budget_s": result.budget_s, "quick": result.quick,
        "workloads": result.workloads, "summary": result.summary,
        "recommendation": result.recommendation, "defaults_on_front":
        result.defaults_on_front, "rows": rows}), indent=2))
    paths[2].write_text(markdown(result))
    paths += plot(result, out)
    return paths


def plot(result, out: Path) -> list[Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    paths = []
    for area, rows in result.areas.items():
        fig, ax = plt.subplots(figsize=(7, 4.5))
        floor = min([r["error"] for r in rows if r["error"] > 0] or [1e-6]) / 10
        for r in rows:
            y = max(r["error"], floor)
            style = {"marker": "o", "color": "tab:blue" if r["on_front"] else "tab:gray"}
            if r["is_default"]:
                style.update(marker="*", color="tab:red", markersize=14)
            if r["is_reference"]:
                style.update(marker="s", color="black")
            ax.plot(r["tile_s"], y, linestyle="none", **style)
            ax.annotate(f"{r['option']}={r['value']}", (r["tile_s"], y), fontsize=6,
                        xytext=(3, 3), textcoords="offset points")
        front = sorted((r for r in rows if r["on_front"]), key=lambda r: r["tile_s"])
        ax.plot([r["tile_s"] for r in front], [max(r["error"], floor) for r in front],
                color="tab:blue", linewidth=0.8)
        ax.axvline(result.budget_s, color="tab:green", linestyle="--", linewidth=0.8,
                   label=f"budget {result.budget_s:g} s per tile")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("seconds per tile (extrapolated, this machine)")
        ax.set_ylabel(rows[0]["error_name"] + " (reference plotted at the floor)")
        ax.set_title(f"{area}: time against error (red star: default, black: reference)",
                     fontsize=9)
        ax.legend(fontsize=7)
        fig.tight_layout()
        p = out / f"pareto_{area}.png"
        fig.savefig(p, dpi=110, bbox_inches="tight")
        plt.close(fig)
        paths.append(p)
    return paths
