#!/usr/bin/env python
"""Write classifier fields (``config/scenes/classify_*.toml``) drawn from one seeded
distribution of seed-like targets, so that training and test fields come from the same
population and only the random draw and the sediment set them apart (issue 51;
docs/classification.md).

Each field: eight targets 2 m apart (6-20 m along, cross-track alternately +-0.3 m),
four man-made and four rocks in a random order.

- man-made: a 12 lb cast-iron shot put; a steel shell (10-18 cm, 6-10 mm wall, empty or
  TNT-like fill); an aluminium cylinder of 30.5 or 61 cm (15.2 cm diameter) at any
  heading to the track;
- rocks: granite or basalt slabs 20-44 cm across and 4-12 cm thick, half of them flat
  (tilt below 8 deg), half tilted 8-40 deg, at any heading;
- each target proud (resting on the bed) with probability 1/4, otherwise its centre
  buried 5-50 cm deep, its top at least 1 cm under the bed.

``--sediment silt`` is 0.6 m of very fine silt over stiff clay (the seed's site);
``--sediment sand`` a medium-sand half-space.

    python benchmarks/make_classify_fields.py --name classify_train_4 --sediment sand --seed 51104 --role train
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "config" / "scenes"
TEMPLATE = SCENES / "classify_train_1.toml"

SEDIMENTS = {
    "silt": ('[[seabed.layers]]\nsediment = "very_fine_silt"\nthickness_m = 0.6\n\n'
             '[[seabed.layers]]\nsediment = "stiff_clay"     # half-space\n',
             "silt over stiff clay"),
    "sand": ('[[seabed.layers]]\nsediment = "medium_sand"    # half-space\n',
             "medium sand"),
}
ROLES = {
    "train": ("A TRAINING field of benchmarks/fit_classifier.py: the classifier's coefficients\n"
              "# (config/processing.toml [products.classify]) are fitted on it."),
    "test": ("A HELD-OUT TEST field of benchmarks/bench_classify.py: never used in the fit\n"
             "# (benchmarks/fit_classifier.py) nor looked at while choosing the features."),
}


def _depth(rng, half_height: float) -> tuple[float, str]:
    """(centre depth, words): proud (resting on the bed) or buried, its centre 5-50 cm
    deep and its top at least 1 cm under the bed (a buried object never pokes out)."""
    if rng.random() < 0.25:
        return -half_height, "proud"
    lo = max(0.05, half_height + 0.01)
    d = max(round(float(rng.uniform(lo, 0.5)), 2), math.ceil(lo * 100) / 100)
    return d, f"centre {d * 100:.0f} cm deep"


def manmade(rng) -> dict:
    """One seed-like ordnance target (a scene ``[[targets]]`` table)."""
    kind = rng.choice(["shot", "shell", "cylinder"])
    if kind == "shot":
        depth, where = _depth(rng, 0.051)
        return dict(kind="sphere", material="cast_iron", depth_m=depth, radius_m=0.051,
                    description=f"12 lb cast-iron shot put (10.2 cm), {where}")
    if kind == "shell":
        radius = round(float(rng.uniform(0.05, 0.09)), 3)
        wall = round(float(rng.uniform(0.006, 0.010)), 3)
        fill = rng.choice(["vacuum", "tnt_like"])
        depth, where = _depth(rng, radius)
        t = dict(kind="shell", material="steel", depth_m=depth, radius_m=radius,
                 thickness_m=wall,
                 description=(f"{2 * radius * 100:.1f} cm steel shell, {wall * 1000:.0f} mm "
                              f"wall, {'empty' if fill == 'vacuum' else 'TNT-like fill'}, "
                              f"{where}"))
        if fill != "vacuum":
            t["fill"] = fill
        return t
    length = float(rng.choice([0.305, 0.61]))
    heading = float(rng.integers(0, 36)) * 5.0
    depth, where = _depth(rng, 0.076)
    return dict(kind="cylinder", material="aluminium", depth_m=depth, radius_m=0.076,
                length_m=length, axis_heading_deg=heading, axis_tilt_deg=0.0,
                description=(f"{length * 100:.1f} cm aluminium cylinder (15.2 cm diameter), "
                             f"axis {heading:.0f} deg from the track, {where}"))


def rock(rng, tilted: bool) -> dict:
    """One granite or basalt slab, flat or tilted."""
    material = str(rng.choice(["granite", "basalt"]))
    radius = round(float(rng.uniform(0.10, 0.22)), 2)
    thick = round(float(rng.uniform(0.04, 0.12)), 2)
    tilt = float(rng.integers(8, 41)) if tilted else float(rng.integers(0, 8))
    heading = float(rng.integers(0, 36)) * 10.0
    half = 0.5 * (2 * radius * math.sin(math.radians(tilt)) + thick * math.cos(math.radians(tilt)))
    depth, where = _depth(rng, round(half, 3))
    shape = "flat" if tilt < 8 else f"tilted {tilt:.0f} deg"
    return dict(kind="disc", material=material, depth_m=depth, radius_m=radius,
                thickness_m=thick, axis_heading_deg=heading, axis_tilt_deg=tilt,
                description=(f"{material} slab {2 * radius * 100:.0f} cm across, "
                             f"{thick * 100:.0f} cm thick, {shape}, {where}"))


def targets(rng) -> list[dict]:
    """Four man-made targets and four rocks (two flat, two tilted), shuffled, placed."""
    ts = [manmade(rng) for _ in range(4)] + [rock(rng, False), rock(rng, False),
                                            rock(rng, True), rock(rng, True)]
    order = rng.permutation(len(ts))
    out = []
    for k, i in enumerate(order):
        t = dict(ts[i])
        t["along_m"] = 6.0 + 2.0 * k
        t["cross_m"] = 0.3 if k % 2 == 0 else -0.3
        out.append(t)
    return out


def _value(v) -> str:
    if isinstance(v, str):
        return f'"{v}"'
    return repr(float(v))


def field_toml(name: str, sediment: str, seed: int, role: str) -> str:
    """The scene TOML of one field."""
    rng = np.random.default_rng(seed)
    text = TEMPLATE.read_text()
    head, _ = text.split("[[targets]]", 1)
    body_start = head.index("[medium]")
    seabed_start = head.index("[[seabed.layers]]")
    seabed_end = head.index("[scattering]")
    layers, words = SEDIMENTS[sediment]
    title = (f"Classifier {role} field {name}: shot puts, steel shells, aluminium "
             f"cylinders and rock slabs in {words}")
    out = [f"# {title} (issue 51; docs/contact_features.md, classification).",
           f"# {ROLES[role]}",
           f"# Drawn by benchmarks/make_classify_fields.py --name {name} --sediment "
           f"{sediment} --seed {seed} --role {role}.",
           "# Eight targets 2 m apart (6-20 m along, inside the array's full aperture: it",
           "# passes 3 m ahead of the body). Depths of the target centre below the interface",
           "# (negative: above it, proud). Format: docs/simulator.md.",
           "[scene]", f'name = "{name.replace("_", "-")}"', f'description = "{title}"',
           f"seed = {seed}", "", head[body_start:seabed_start] + layers + "\n"
           + head[seabed_end:]]
    keys = ("kind", "material", "fill", "along_m", "cross_m", "depth_m", "radius_m",
            "thickness_m", "length_m", "axis_heading_deg", "axis_tilt_deg", "description")
    for t in targets(rng):
        out.append("[[targets]]")
        out += [f"{k} = {_value(t[k])}" for k in keys if k in t]
        out.append("")
    return "\n".join(out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--name", required=True)
    p.add_argument("--sediment", choices=sorted(SEDIMENTS), required=True)
    p.add_argument("--seed", type=int, required=True)
    p.add_argument("--role", choices=sorted(ROLES), required=True)
    a = p.parse_args(argv)
    path = SCENES / f"{a.name}.toml"
    path.write_text(field_toml(a.name, a.sediment, a.seed, a.role))
    print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
