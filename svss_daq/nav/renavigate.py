"""Re-navigation: every pose of a recorded run recomputed from the instrument records
the run keeps.

``svss acquire`` records, beside the pings, every record its navigation was fed: the
NMEA sentences (``/Platform/NMEA``), the PD0 ensembles (``/Platform/PD0``) and the
sequencer's transmit records (``/Platform/ping_clock``), each with its host receive
time, and the navigation configuration it posed the pings with (root
attribute ``navigation_config_toml``; docs/formats.md). :func:`renavigate` decodes them
again (:mod:`svss_daq.protocols.nmea`, :mod:`svss_daq.protocols.pd0`) and feeds a
:class:`~svss_daq.navigation.Navigator` in receive-time order as the daemon fed it (with
the ping-clock events it judged the instrument clocks by, ``/Platform/ping_clock``),
then poses every ping of the run at its transmit time with the smoother over the whole
recording (docs/navigation.md).

A run written before the records were kept, or without any (a simulated run, a run
acquired without navigation links), cannot be re-navigated: :func:`records_problem`
says why, and :func:`renavigation` raises :class:`RenavigationError` with it.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from svss_daq.config import (ConfigError, DevicesConfig, NavigationConfig, config_path,
                             from_dict, read_toml)
from svss_daq.protocols.nmea import NmeaStreamParser
from svss_daq.protocols.pd0 import Pd0DecodeError, decode_ensemble
from svss_daq.ping import NavSnapshot
from svss_daq.rawfile import NAV_CONFIG_ATTR, PD0, RawRunReader

from .navigator import Navigator

log = logging.getLogger(__name__)

#: records kept beyond the recording's span when the navigator prunes its history, s
HISTORY_MARGIN_S = 60.0


class RenavigationError(ValueError):
    """A run that cannot be re-navigated (the message says why, naming the file)."""


# ----------------------------------------------------------------- configuration


def navigation_config_text(cfg: NavigationConfig) -> str:
    """The TOML text of a ``[navigation]`` table's keys (omitted keys left out), as a run
    records it (:data:`~svss_daq.rawfile.NAV_CONFIG_ATTR`)."""
    lines = []
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        if v is None:
            continue
        if isinstance(v, bool):
            text = "true" if v else "false"
        elif isinstance(v, (int, float)):
            text = repr(v) if math.isfinite(v) else ("inf" if v > 0 else "-inf")
        elif isinstance(v, str):
            text = '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        else:
            raise TypeError(f"navigation key {f.name!r}: cannot write {v!r} as TOML")
        lines.append(f"{f.name} = {text}")
    return "\n".join(lines) + "\n"


def navigation_config_from_text(text: str, source: str) -> NavigationConfig:
    """A recorded ``[navigation]`` table's text validated against today's schema. Keys
    the schema gained since the run was recorded are taken from the project's
    ``config/devices.toml`` (logged); keys it lost are dropped (logged)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: not valid TOML: {exc}") from None
    names = {f.name for f in dataclasses.fields(NavigationConfig)}
    dropped = sorted(set(data) - names)
    if dropped:
        log.warning("%s: keys %s are no longer navigation settings; ignored", source,
                    dropped)
        data = {k: v for k, v in data.items() if k in names}
    try:
        return from_dict(NavigationConfig, data, source)
    except ConfigError:
        current_path = config_path("devices.toml")
        current = read_toml(current_path).get("navigation", {})
        added = sorted(k for k in current if k in names and k not in data)
        if not added:
            raise
        log.warning("%s: recorded without %s (settings added since); taken from %s",
                    source, added, current_path)
        return from_dict(NavigationConfig, {**{k: current[k] for k in added}, **data},
                         source)


def current_navigation_config() -> NavigationConfig:
    """The ``[navigation]`` table of the project's ``config/devices.toml``."""
    path = config_path("devices.toml")
    return from_dict(DevicesConfig, read_toml(path), str(path)).navigation


# ----------------------------------------------------------------- re-navigation


@dataclass(frozen=True)
class Renavigation:
    """The poses of a run's pings recomputed from its instrument records."""
    poses: list[NavSnapshot]
    #: NMEA sentences and PD0 ensembles fed to the navigation
    n_nmea: int
    n_pd0: int
    #: recorded ensembles that did not decode (left out)
    n_bad_pd0: int
    #: where the navigation configuration came from
    config_source: str
    #: the navigation configuration the poses were made with
    config: NavigationConfig | None = None

    @property
    def description(self) -> str:
        """What the poses are, for logs and provenance."""
        return (f"re-navigated from {self.n_nmea} NMEA sentences and {self.n_pd0} PD0 "
                "ensembles (smoothed over the whole recording)")


def _readers(run) -> tuple[list[RawRunReader], list[RawRunReader]]:
    """(the run's segment readers in order, those opened here to be closed)."""
    items = run if isinstance(run, (list, tuple)) else [run]
    if not items:
        raise RenavigationError("re-navigation: no raw-run file given")
    readers, opened = [], []
    try:
        for item in items:
            if isinstance(item, RawRunReader):
                readers.append(item)
            else:
                r = RawRunReader(Path(item))
                opened.append(r)
                readers.append(r)
    except BaseException:
        for r in opened:
            r.close()
        raise
    return readers, opened


def records_problem(run: RawRunReader | Sequence[RawRunReader]) -> str | None:
    """Why ``run`` (a reader, or a run's segment readers) cannot be re-navigated, None
    when it can: it must keep the PD0 ensembles (files written before they were kept
    lack the DVL's records) and hold at least one NMEA sentence or PD0 ensemble."""
    readers = list(run) if isinstance(run, (list, tuple)) else [run]
    names = ", ".join(str(r.path) for r in readers)
    old = [r for r in readers if not r.keeps_pd0]
    if old:
        return (f"{old[0].path}: written before the DVL's PD0 ensembles were recorded "
                f"(no '/{PD0}'); its instrument records are incomplete and only the "
                "recorded live poses can image it")
    if not any(r.n_nmea or r.n_pd0 for r in readers):
        return (f"{names}: records no NMEA sentence and no PD0 ensemble (a simulated run, "
                "or one acquired without navigation links): only its recorded poses can "
                "image it")
    return None


def _config(readers: list[RawRunReader], nav_cfg) -> tuple[NavigationConfig, str]:
    if nav_cfg is not None:
        return nav_cfg, "given"
    r = readers[0]
    text = r.navigation_config
    if text is None:
        log.warning("%s: records no navigation configuration (root attribute %s); "
                    "re-navigating with config/devices.toml's [navigation]", r.path,
                    NAV_CONFIG_ATTR)
        return current_navigation_config(), str(config_path("devices.toml"))
    source = f"{r.path}:/{NAV_CONFIG_ATTR}"
    try:
        return navigation_config_from_text(text, source), source
    except ConfigError as exc:
        raise RenavigationError(f"the recorded navigation configuration is not one this "
                                f"software reads ({exc}); give one, or image with the "
                                "recorded poses") from None


def _feed(navigator: Navigator, nmea: list[tuple[int, str]], pd0: list[tuple[int, bytes]],
          clock: list[tuple[int, int]], where: str) -> tuple[int, int, int]:
    """Decode the records and feed them to ``navigator`` in receive-time order as the
    acquisition daemon does (``AcquisitionDaemon._on_transmit``, ``_on_nmea``,
    ``_on_pd0``): each ping-clock event (``add_reference``), each NMEA record with its
    receive time (``add_nmea([(receive_ns, record)])``), each PD0 ensemble with its
    receive time; at equal times in that order. Then the end of the recording
    (``flush``: GPS epochs still waiting for their GST are decided). Returns
    (sentences, ensembles fed, ensembles that did not decode)."""
    parser = NmeaStreamParser()
    events = sorted([(t, 0, k) for k, (t, _) in enumerate(clock)]
                    + [(t, 1, k) for k, (t, _) in enumerate(nmea)]
                    + [(t, 2, k) for k, (t, _) in enumerate(pd0)])
    n_nmea = n_pd0 = bad = 0
    first_error = None
    for t, kind, k in events:
        if kind == 0:
            navigator.add_reference(t, clock[k][1])
        elif kind == 1:
            n_nmea += 1
            for rec in parser.feed(nmea[k][1].encode("ascii", "replace") + b"\r\n"):
                navigator.add_nmea([(t, rec)])
        else:
            try:
                ens = decode_ensemble(pd0[k][1])
            except Pd0DecodeError as exc:
                bad += 1
                first_error = first_error or f"ensemble {k} received at {t} ns: {exc}"
                continue
            n_pd0 += 1
            navigator.add_pd0(ens, receive_ns=t)
    navigator.flush()
    if bad:
        log.warning("%s: %d recorded PD0 ensemble(s) did not decode and were left out "
                    "(first: %s)", where, bad, first_error)
    return n_nmea, n_pd0, bad


def renavigation(run, nav_cfg: NavigationConfig | None = None, *,
                 times_ns: Iterable[int] | None = None) -> Renavigation:
    """Re-navigate ``run`` (a :class:`~svss_daq.rawfile.RawRunReader`, a raw-run path,
    or a run's segments in order): the pose of every ping (or at ``times_ns``) from
    its recorded NMEA sentences and PD0 ensembles, with ``nav_cfg`` (default: the
    navigation configuration the run records) and the lever arms of the hardware
    configuration it records. Raises :class:`RenavigationError` naming the file when
    the run has no instrument records (:func:`records_problem`) or the navigation
    finds no solution."""
    readers, opened = _readers(run)
    try:
        problem = records_problem(readers)
        if problem is not None:
            raise RenavigationError(problem)
        where = str(readers[0].path) + (f" (+{len(readers) - 1} segment(s))"
                                        if len(readers) > 1 else "")
        cfg, source = _config(readers, nav_cfg)
        nmea = [rec for r in readers for rec in r.nmea()]
        pd0 = [rec for r in readers for rec in r.pd0()]
        clock = [rec for r in readers for rec in r.ping_clock()]
        if times_ns is None:
            times = np.concatenate([r.ping_table()["ping_time"] for r in readers])
        else:
            times = np.asarray(list(times_ns), dtype=np.int64)
        hardware = readers[0].hardware.value
    finally:
        for r in opened:
            r.close()
    stamps = [t for t, _ in nmea] + [t for t, _ in pd0] + times.tolist()
    span_s = (max(stamps) - min(stamps)) * 1e-9 if stamps else 0.0
    navigator = Navigator(cfg, hardware.lever_arms,
                          history_s=span_s + HISTORY_MARGIN_S)
    n_nmea, n_pd0, bad = _feed(navigator, nmea, pd0, clock, where)
    try:
        poses = navigator.poses(times, smooth=True)
    except (ValueError, IndexError) as exc:
        raise RenavigationError(f"{where}: re-navigation from {n_nmea} NMEA sentences and "
                                f"{n_pd0} PD0 ensembles found no solution ({exc})") from None
    out = Renavigation(list(poses), n_nmea, n_pd0, bad, source, cfg)
    log.info("%s: %d ping(s) %s (navigation configuration: %s)", where, len(out.poses),
             out.description, source)
    return out


def renavigate(run, nav_cfg: NavigationConfig | None = None) -> list[NavSnapshot]:
    """The pose of every ping of ``run`` recomputed from its instrument records
    (:func:`renavigation`)."""
    return renavigation(run, nav_cfg).poses


__all__ = ["RenavigationError", "Renavigation", "renavigate",
           "renavigation", "records_problem", "navigation_config_text",
           "navigation_config_from_text", "current_navigation_config"]
