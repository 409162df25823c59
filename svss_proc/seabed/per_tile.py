"""The sediment speed tile by tile: what each tile's own buried responses say, against
the run's estimate the tiles are imaged with (docs/seabed.md).

A run is imaged with one speed (:mod:`.speed`). Where it crosses from one sediment into
another, its responses disagree along the track; each response's scan already carries
its speed and standard deviation, so each tile's own estimate is their inverse-variance
mean, and the tiles' disagreement is a chi-square of those means about the run's
(degrees of freedom: the tiles with responses, less one). A run whose tiles disagree
at ``DISAGREE_P`` is reported (a warning, ``tiles_disagree`` in the records): its tiles
are imaged with a mixture of two sediments' speeds. Layered estimates are left out
(their responses belong to different media).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import chi2

from ..imaging.grid import tile_index

__all__ = ["tile_speeds"]

#: the tiles' speeds disagree where their chi-square about the run's is this unlikely
DISAGREE_P = 0.01


def tile_speeds(summary: dict, tile_cfg) -> tuple[list[dict], bool | None]:
    """(one entry per tile with responses: ``tile``, ``speed_m_s``, ``sigma_m_s``,
    ``responses``; whether they disagree, None where it cannot be told) of a
    :meth:`.speed.SpeedEstimate.summary` with the tiles of ``tile_cfg``."""
    if summary.get("status") != "estimated" or summary.get("layers"):
        return [], None
    by_tile: dict[int, list[tuple[float, float]]] = {}
    for r in summary.get("responses") or []:
        c, s = r.get("speed_m_s"), r.get("sigma_m_s")
        if c is None or s is None or not s > 0:
            continue
        by_tile.setdefault(tile_index(tile_cfg, float(r["along_m"])), []).append((c, s))
    out = []
    for k in sorted(by_tile):
        c = np.array([v for v, _ in by_tile[k]])
        w = 1.0 / np.array([s for _, s in by_tile[k]]) ** 2
        out.append({"tile": int(k), "speed_m_s": round(float((w * c).sum() / w.sum()), 1),
                    "sigma_m_s": round(float(1.0 / math.sqrt(w.sum())), 1),
                    "responses": int(c.size)})
    if len(out) < 2:
        return out, None
    run = float(summary["sediment_sound_speed_m_s"])
    x2 = sum(((t["speed_m_s"] - run) / t["sigma_m_s"]) ** 2 for t in out)
    return out, bool(chi2.sf(x2, len(out) - 1) < DISAGREE_P)
