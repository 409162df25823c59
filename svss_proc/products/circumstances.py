"""The circumstances of a run's pings: where pings are missing and where their poses
were held or dead-reckoned, so that each contact and product can say what happened
around it (docs/run_products.md, "Circumstances"). Pure functions on a table of the run's
imaged pings (sequence, time, position, navigation flags); no files.

A *stretch* is a run of pings sharing one circumstance:

- ``missing``: sequences absent between two imaged pings (a gap): never recorded,
  dropped on the way to the worker, or refused by the ping gate (a held pose under
  ``ping_gate.held = "refuse"`` is missing from the image like a dropped ping). The
  missing pings are placed on the straight track between the two imaged pings around
  the gap, evenly by sequence;
- ``dead_reckoned``: poses flagged :data:`~svss_daq.ping.NAV_DEAD_RECKONED`, what a crew
  calls "no GPS fix": the fusion (live and re-navigated alike,
  :mod:`svss_daq.nav.fusion`) flags a pose so when no GPS fix is within
  ``gps_fix_max_age_s`` of the ping and the DVL's bottom track carried the position
  (a GPS outage);
- ``held``: poses flagged :data:`~svss_daq.ping.NAV_HELD`: extrapolated past the last
  navigation record, or carried across an outage with neither a fix nor bottom lock.

A gap ends a pose stretch (the missing pings' poses are not known). A pose may be both
dead-reckoned and held; each flag is counted. Pings whose flags are not known (tiles
written before the flags were kept) count in no pose stretch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from svss_daq.ping import NAV_DEAD_RECKONED, NAV_HELD

#: the kinds of stretch, in the order the products list them
KINDS = ("missing", "dead_reckoned", "held")
#: the navigation flag of each pose stretch
POSE_FLAGS = {"dead_reckoned": NAV_DEAD_RECKONED, "held": NAV_HELD}
#: what each kind is called in a contact's ``circumstances`` and on the map
LABELS = {"missing": "missing pings (gap)", "dead_reckoned": "dead-reckoned (no GPS fix)",
          "held": "held pose"}
#: a contact imaged by fewer pings than this fraction of the run's full coverage at
#: its depth is marked "partial coverage" (the detection's own floor is
#: ``min_coverage_fraction``, 0.5 shipped; the demo's six points, every ping there, have
#: 0.80-1.0: a point 0.4 m off the track sees a shorter chord of the cone)
PARTIAL_COVERAGE_BELOW = 0.75
#: the horizontal reach (m) taken for "the pings that could see a point" where the
#: projector's footprint is not known (tiles without coverage or configuration)
FALLBACK_REACH_M = 1.5
#: at most this many positions in a stretch's line (longer ones are thinned, ends kept)
MAX_LINE_POINTS = 200


@dataclass(frozen=True)
class PingTrack:
    """The run's imaged pings, once each, in sequence order: ``sequence`` (int64),
    ``time_ns`` (int64, UTC), ``north_m``, ``east_m`` (where the caller places a ping:
    the run products use the array's position), ``flags`` (uint32 NAV_* bits) and
    ``known`` (the flags are known)."""
    sequence: np.ndarray
    time_ns: np.ndarray
    north_m: np.ndarray
    east_m: np.ndarray
    flags: np.ndarray
    known: np.ndarray

    def __len__(self) -> int:
        return int(self.sequence.size)

    def moved(self, d_north: np.ndarray | float, d_east: np.ndarray | float) -> "PingTrack":
        """The same pings with their positions moved by ``d_north``, ``d_east`` (m)."""
        return PingTrack(self.sequence, self.time_ns, self.north_m + d_north,
                         self.east_m + d_east, self.flags, self.known)


def ping_track(sequence, time_ns, north_m, east_m, flags=None) -> PingTrack:
    """A :class:`PingTrack` from per-ping arrays in any order, a sequence given twice
    kept once (its first row). ``flags``: NAV_* bits per ping, None where not known (a
    whole array, or an object array holding None for some pings). Pings without a
    finite position are left out."""
    seq = np.asarray(sequence, dtype=np.int64).ravel()
    t = np.asarray(time_ns, dtype=np.int64).ravel()
    n = np.asarray(north_m, dtype=np.float64).ravel()
    e = np.asarray(east_m, dtype=np.float64).ravel()
    if not seq.size == t.size == n.size == e.size:
        raise ValueError(f"ping track: {seq.size} sequences, {t.size} times, {n.size} "
                         f"norths and {e.size} easts; expected one of each per ping")
    if flags is None:
        q = np.zeros(seq.size, dtype=np.uint32)
        known = np.zeros(seq.size, dtype=bool)
    else:
        raw = np.asarray(flags, dtype=object).ravel()
        if raw.size != seq.size:
            raise ValueError(f"ping track: {raw.size} flags for {seq.size} pings")
        known = np.array([v is not None for v in raw], dtype=bool)
        q = np.array([int(v) if v is not None else 0 for v in raw], dtype=np.uint32)
    _, first = np.unique(seq, return_index=True)         # sorted by sequence
    first = first[np.isfinite(n[first]) & np.isfinite(e[first])]
    return PingTrack(seq[first], t[first], n[first], e[first], q[first], known[first])


@dataclass(frozen=True)
class Stretch:
    """A run of pings sharing one circumstance (:data:`KINDS`): ``first_sequence`` to
    ``last_sequence`` (the missing ones, or the flagged ones), ``pings`` (how many),
    ``start_ns``, ``end_ns`` (UTC; a gap's from its missing pings' times interpolated
    between the imaged pings around it) and the stretch's line ``north_m``, ``east_m``
    (at least two positions: a gap's runs between the imaged pings around it, a pose
    stretch's from halfway to the ping before it to halfway to the ping after it)."""
    kind: str
    first_sequence: int
    last_sequence: int
    pings: int
    start_ns: int
    end_ns: int
    north_m: np.ndarray
    east_m: np.ndarray


def _thinned(n: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    if n.size <= MAX_LINE_POINTS:
        return n, e
    k = np.unique(np.round(np.linspace(0, n.size - 1, MAX_LINE_POINTS)).astype(np.int64))
    return n[k], e[k]


def _gaps(track: PingTrack) -> np.ndarray:
    """Indices i of the imaged pings followed by a gap (sequence i+1 is not i's next)."""
    return np.flatnonzero(np.diff(track.sequence) > 1)


def _runs(mask: np.ndarray, joined: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) indices of each run of True in ``mask`` whose neighbours are
    ``joined`` (``joined[i]``: i and i + 1 may be in one run)."""
    link = mask[:-1] & mask[1:] & joined
    starts = np.flatnonzero(mask & ~np.concatenate([[False], link]))
    ends = np.flatnonzero(mask & ~np.concatenate([link, [False]]))
    return list(zip(starts.tolist(), ends.tolist()))


def stretches(track: PingTrack) -> list[Stretch]:
    """Every stretch of the run (:data:`KINDS`), by kind then time."""
    out: list[Stretch] = []
    s, t, n, e = track.sequence, track.time_ns, track.north_m, track.east_m
    for i in _gaps(track):
        m = int(s[i + 1] - s[i] - 1)
        span = float(s[i + 1] - s[i])

        def at(k: int) -> int:
            return int(t[i]) + int(round((k - int(s[i])) / span * float(t[i + 1] - t[i])))
        out.append(Stretch("missing", int(s[i]) + 1, int(s[i + 1]) - 1, m,
                           at(int(s[i]) + 1), at(int(s[i + 1]) - 1),
                           n[i:i + 2].copy(), e[i:i + 2].copy()))
    # a gap ends a pose stretch (the missing pings' poses are not known) and a
    # stretch's line reaches halfway to its neighbours only where no gap parts them
    joined = np.diff(track.sequence) == 1             # ping i and i + 1 are successive
    for kind in KINDS[1:]:
        flagged = track.known & ((track.flags & POSE_FLAGS[kind]) != 0)
        for a, b in _runs(flagged, joined):
            ln, le = n[a:b + 1], e[a:b + 1]
            if a > 0 and joined[a - 1]:
                ln = np.concatenate([[0.5 * (n[a - 1] + n[a])], ln])
                le = np.concatenate([[0.5 * (e[a - 1] + e[a])], le])
            if b + 1 < len(track) and joined[b]:
                ln = np.concatenate([ln, [0.5 * (n[b] + n[b + 1])]])
                le = np.concatenate([le, [0.5 * (e[b] + e[b + 1])]])
            if ln.size < 2:                      # a single ping and nothing around it
                ln, le = np.repeat(ln, 2), np.repeat(le, 2)
            ln, le = _thinned(ln, le)
            out.append(Stretch(kind, int(s[a]), int(s[b]), b - a + 1, int(t[a]), int(t[b]),
                               ln, le))
    return out


def _missing_within(a: np.ndarray, b: np.ndarray, m: int, p: np.ndarray,
                    reach: float) -> int:
    """How many of the ``m`` points evenly between ``a`` and ``b`` (exclusive: at
    fractions k / (m + 1), k = 1..m) lie within ``reach`` of ``p``."""
    d, w = b - a, a - p
    qa, qb, qc = float(d @ d), 2.0 * float(w @ d), float(w @ w) - reach * reach
    if qa == 0.0:
        return m if qc <= 0.0 else 0
    disc = qb * qb - 4.0 * qa * qc
    if disc < 0.0:
        return 0
    root = math.sqrt(disc)
    u0, u1 = (-qb - root) / (2.0 * qa), (-qb + root) / (2.0 * qa)
    k0 = max(1, math.ceil(u0 * (m + 1) - 1e-9))
    k1 = min(m, math.floor(u1 * (m + 1) + 1e-9))
    return max(0, k1 - k0 + 1)


def counts_near(track: PingTrack, north_m: float, east_m: float, reach_m: float
                ) -> dict[str, int]:
    """What happened among the pings within ``reach_m`` (horizontally) of the point
    (``north_m``, ``east_m``): ``pings_missing`` (missing pings placed on the track of
    their gap, :func:`stretches`), ``poses_dead_reckoned`` and ``poses_held`` (imaged
    pings with those flags)."""
    out = {"pings_missing": 0, "poses_dead_reckoned": 0, "poses_held": 0}
    if not len(track):
        return out
    p = np.array([north_m, east_m], dtype=np.float64)
    near = np.hypot(track.north_m - p[0], track.east_m - p[1]) <= reach_m
    for kind in KINDS[1:]:
        out[f"poses_{kind}"] = int(np.count_nonzero(
            near & track.known & ((track.flags & POSE_FLAGS[kind]) != 0)))
    pts = np.stack([track.north_m, track.east_m], axis=1)
    for i in _gaps(track):
        out["pings_missing"] += _missing_within(
            pts[i], pts[i + 1], int(track.sequence[i + 1] - track.sequence[i] - 1), p,
            reach_m)
    return out


def tile_counts(sequences, flags=None) -> dict[str, int]:
    """A tile's own counts from its pings' ``sequences`` and (None: not known) their
    NAV_* ``flags``: ``pings_missing`` (sequences absent between its first and last
    ping) and, with flags, ``poses_dead_reckoned`` and ``poses_held``."""
    seq = np.unique(np.asarray(sequences, dtype=np.int64))
    out = {"pings_missing": int(seq[-1] - seq[0] + 1 - seq.size) if seq.size else 0}
    if flags is not None:
        q = np.asarray(flags, dtype=np.uint32)
        for kind in KINDS[1:]:
            out[f"poses_{kind}"] = int(np.count_nonzero(q & POSE_FLAGS[kind]))
    return out


def _plural(k: int, word: str) -> str:
    return f"{k} {word}" if k == 1 else f"{k} {word}s"


def circumstances_text(counts: dict[str, int], partial_coverage: bool = False) -> str:
    """A contact's or tile's circumstances in words, "" when clean: e.g. "gap 8 pings;
    dead-reckoned 30 poses; held 2 poses; partial coverage"."""
    parts = []
    if counts.get("pings_missing"):
        parts.append(f"gap {_plural(counts['pings_missing'], 'ping')}")
    if counts.get("poses_dead_reckoned"):
        parts.append(f"dead-reckoned {_plural(counts['poses_dead_reckoned'], 'pose')}")
    if counts.get("poses_held"):
        parts.append(f"held {_plural(counts['poses_held'], 'pose')}")
    if partial_coverage:
        parts.append("partial coverage")
    return "; ".join(parts)


def is_partial(coverage_fraction: float) -> bool:
    """Whether a coverage fraction (NaN: not known) is partial
    (:data:`PARTIAL_COVERAGE_BELOW`)."""
    return bool(math.isfinite(coverage_fraction)
                and coverage_fraction < PARTIAL_COVERAGE_BELOW)


__all__ = ["FALLBACK_REACH_M", "KINDS", "LABELS", "PARTIAL_COVERAGE_BELOW", "PingTrack",
           "Stretch", "circumstances_text", "counts_near", "is_partial", "ping_track",
           "stretches", "tile_counts"]
