"""The simulated device: one process with the sonar's and the navigation's device ends,
for hardware-in-the-loop runs of the acquisition side (``svss sim-device``).

* the transmit sequencer on a pseudo-terminal, at ``<run dir>/sequencer`` (a symlink);
* the digitiser, a TCP server on 127.0.0.1 (ephemeral port);
* the DVL and GPS on pseudo-terminals, at ``<run dir>/dvl`` and ``<run dir>/gps``;

all on one :class:`~sim_device.devices.clock.SimClock` that reads the scene track's start
time when the device starts and runs ``time_scale`` times as fast as the host.

For each PING the sequencer emits while RUNNING (sequence, projector, transmit time on
the devices' clock; the transmissions fall on the track's ping grid, see
:mod:`sim_device.devices.sequencer`), the digitiser streams that ping's samples once its
receive window has closed: ping number = the sequence, the same transmit time, samples
of the scene's track ping ``k`` (``EnvironmentSource(hw, scene).ping(k)``, ``k`` = true
time since the track start / the commanded interval). The samples are made ahead of time
(:mod:`sim_device.ping_sources`): in-process, in worker processes, or read from a raw run.

A ping whose samples are not ready one ping interval after its window closed is
**dropped** (logged and counted in ``late``): the device keeps its timing, as a
digitiser whose buffer overflowed would; the drivers see the gap in ping numbers.
"""

from __future__ import annotations

import logging
import os
import queue
import shutil
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from svss_daq.config import (ConfigError, DevicesConfig, HardwareConfig, Loaded, config_path,
                             from_dict, read_toml, spec)

from sim_device.devices.clock import SimClock
from sim_device.devices.digitiser import DigitiserEmulator
from sim_device.devices.instruments_config import DvlSimConfig, GpsSimConfig
from sim_device.devices.sequencer import SequencerEmulator

__all__ = ["SimDevice", "SimDeviceConfig", "SonarSimConfig", "load_sim_device_config",
           "devices_toml"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SonarSimConfig:
    """The simulated sonar (sequencer and digitiser)."""
    channels_per_frame: int = spec("channels in one digitiser data frame", lo=1, hi=4096)
    lookahead_pings: int = spec("pings synthesised ahead of the sequencer", lo=1, hi=256)
    workers: int = spec("synthesis worker processes; 0: chosen from the measured cost of "
                        "a ping", lo=0, hi=256)
    inline_max_load: float = spec("synthesise in the device process when one ping costs "
                                  "less than this fraction of the host time between pings",
                                  lo=0.0, hi=1.0)
    max_pending_pings: int = spec("pings queued for a digitiser client that does not keep "
                                  "up before further ones are discarded", lo=1, hi=1024)


@dataclass(frozen=True)
class SimDeviceConfig:
    """``config/sim-device.toml``: the simulated device's instruments."""
    sonar: SonarSimConfig = spec("simulated sequencer and digitiser")
    dvl: DvlSimConfig = spec("simulated DVL")
    gps: GpsSimConfig = spec("simulated GPS")


def load_sim_device_config(path: str | os.PathLike | None = None) -> SimDeviceConfig:
    """Read ``config/sim-device.toml`` (or ``path``); errors name the file and key."""
    from sim_device.devices.instruments_config import load_instruments
    path = path or config_path("sim-device.toml")
    data = read_toml(path)
    if "sonar" not in data:
        raise ConfigError(f"{path}: missing table 'sonar'; expected the simulated sonar's "
                          "settings")
    sonar = from_dict(SonarSimConfig, data["sonar"], f"{path} [sonar]")
    nav = load_instruments(path)
    return SimDeviceConfig(sonar, nav.dvl, nav.gps)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} as a TOML value")


def devices_toml(ports: dict[str, dict[str, Any]],
                 base: str | os.PathLike | None = None) -> str:
    """A whole devices configuration (``config/devices.toml`` or ``base``) with the
    links in ``ports`` (section -> {key: value}) replaced; checked against
    :class:`DevicesConfig`. Links absent from ``ports`` that the device cannot serve
    (dvl, gps) are left out."""
    base = base or config_path("devices.toml")
    data = read_toml(base)
    for opt in ("dvl", "gps"):
        if opt not in ports:
            data.pop(opt, None)
    for sec, kv in ports.items():
        data.setdefault(sec, {}).update(kv)
    lines = [f"# Simulated device links (svss sim-device); other settings from {base}"]
    for sec, table in data.items():
        lines.append(f"\n[{sec}]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in table.items() if v is not None]
    text = "\n".join(lines) + "\n"
    from svss_daq.config import loads
    loads(DevicesConfig, text, "simulated devices configuration")
    return text


class SimDevice:
    """The whole simulated device. ``hardware``: the hardware configuration; ``scene_path``:
    the scene TOML; ``from_run``: stream a raw run's pings instead of synthesising;
    ``faults``: a faults TOML file (:mod:`sim_device.faults`); ``run_dir``: where the
    serial ports' symlinks go (default: a new temporary folder, removed on close);
    ``workers``: synthesis processes (None: ``sonar.workers`` of the configuration)."""

    def __init__(self, hardware: Loaded[HardwareConfig], scene_path: str | os.PathLike, *,
                 time_scale: float = 1.0, faults: str | os.PathLike | None = None,
                 from_run: str | os.PathLike | None = None,
                 run_dir: str | os.PathLike | None = None,
                 config: SimDeviceConfig | str | os.PathLike | None = None,
                 workers: Optional[int] = None, navigation: bool = True,
                 lead_s: float = 0.0) -> None:
        from sim_device.scene import load_scene
        from sim_device.track import parse_utc_ns

        self.hw = hardware
        self.scene_path = str(scene_path)
        self.scene = load_scene(scene_path)
        self.cfg = config if isinstance(config, SimDeviceConfig) else \
            load_sim_device_config(config)
        self.sonar = self.cfg.sonar
        self.clock = SimClock(parse_utc_ns(self.scene.track.start_time_utc), time_scale,
                              lead_s)
        self.time_scale = float(time_scale)
        self.faults_path = str(faults) if faults else None
        self._faults = None
        if faults:
            from sim_device.faults import load_faults
            self._faults = load_faults(faults)
        self._own_dir = run_dir is None
        self.run_dir = Path(run_dir or tempfile.mkdtemp(prefix="svss-sim-device-"))
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.from_run = str(from_run) if from_run else None
        self.workers = self.sonar.workers if workers is None else int(workers)
        self.with_navigation = navigation
        # counters
        self.pings_seen = 0      #: PINGs the sequencer emitted while RUNNING
        self.pings_sent = 0      #: pings handed to the digitiser
        self.late = 0            #: pings dropped: samples not ready in time
        self.not_streaming = 0   #: pings with no digitiser client streaming
        self.start_true_ns: Optional[int] = None
        self._interval_ns: Optional[int] = None
        self._triggers: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self.source = None
        self.sequencer = self.digitiser = self.dvl = self.gps = None
        self.scheduler = None
        self._sender: Optional[threading.Thread] = None
        self._warned_track_end = False

    # -- set-up ----------------------------------------------------------------------

    def _choose_source(self):
        from sim_device import ping_sources as ps
        if self.from_run:
            src = ps.RunFileSource(self.from_run, self.hw)
            log.info("sonar samples: streamed from the pre-synthesised run %s", self.from_run)
            return src
        budget = self.hw.value.sequencer.ping_interval_s / self.time_scale
        workers = self.workers
        if workers == 0:
            cost = ps.measure_ping_cost(self.hw, self.scene_path)
            n_cpu = os.cpu_count() or 1
            log.info("one ping of %s costs %.4f s to synthesise here; %.4f s of host time "
                     "between pings (interval %.3f s, time scale %g)", self.scene.scene.name,
                     cost, budget, self.hw.value.sequencer.ping_interval_s, self.time_scale)
            if cost < self.sonar.inline_max_load * budget:
                log.info("sonar samples: synthesised on the fly in the device process")
                return ps.InlineSynthesis(self.hw, self.scene_path,
                                          self.sonar.lookahead_pings)
            workers = n_cpu
            if cost / workers > budget:
                log.warning("%d worker(s) cannot keep up with %s: %.3f s per ping each, "
                            "%.3f s available; expect late (dropped) pings. Use "
                            "--time-scale %.3g or less, or --from-run with a run made by "
                            "svss simulate", workers, self.scene.scene.name, cost, budget,
                            0.8 * self.time_scale * budget * workers / cost)
        log.info("sonar samples: synthesised ahead in %d worker process(es), %d pings ahead",
                 workers, self.sonar.lookahead_pings)
        return ps.PoolSynthesis(self.hw, self.scene_path, workers, self.sonar.lookahead_pings)

    def _bed(self):
        """The scene's sloping bed for the DVL (down = k0 + kn north + ke east), or None."""
        seabed = self.scene.seabed
        if seabed is None or seabed.slope_deg is None or not any(seabed.slope_deg):
            return None
        from sim_device.bed_plane import BedPlane, ned_plane
        from sim_device.track import truth_line
        return ned_plane(BedPlane.from_slopes(*seabed.slope_deg), truth_line(self.scene.track))

    def _bed_ranges(self):
        """The DVL's beam ranges to an undulating bed
        (:func:`sim_device.bed_surface.ned_beam_ranges`), or None."""
        seabed = self.scene.seabed
        if seabed is None or not seabed.undulation:
            return None
        from sim_device.bed_plane import BedPlane
        from sim_device.bed_surface import BedSurface, ned_beam_ranges
        from sim_device.bed_undulation import Undulation
        from sim_device.track import truth_line
        plane = (BedPlane.from_slopes(*seabed.slope_deg)
                 if seabed.slope_deg is not None and any(seabed.slope_deg) else None)
        und = Undulation.from_terms([(t.amplitude_m, t.wavelength_m, t.direction_deg,
                                      t.phase_deg) for t in seabed.undulation])
        return ned_beam_ranges(BedSurface(plane, und), truth_line(self.scene.track))

    def _pose_fn(self):
        from sim_device.track import pose_at
        track, seed, t0 = self.scene.track, self.scene.scene.seed, self.clock.start_ns
        return lambda true_ns: pose_at(track, (true_ns - t0) * 1e-9, seed)

    def start(self) -> "SimDevice":
        """Start every device end and the clock; returns once they serve."""
        self.source = self._choose_source()
        self.digitiser = DigitiserEmulator(None, ping_interval_s=None,
                                           channels_per_frame=self.sonar.channels_per_frame,
                                           max_pending=self.sonar.max_pending_pings)
        self.sequencer = SequencerEmulator(clock=self.clock, on_ping=self._on_ping,
                                           on_start=self._on_start,
                                           link_path=self.run_dir / "sequencer")
        if self.with_navigation:
            from sim_device.devices.dvl import DvlEmulator
            from sim_device.devices.gps import GpsEmulator
            lever = self.hw.value.lever_arms
            self.dvl = DvlEmulator(self.cfg.dvl, lever, self.clock, self._pose_fn(),
                                   self.run_dir, "dvl", bed=self._bed(),
                                   bed_ranges=self._bed_ranges())
            self.gps = GpsEmulator(self.cfg.gps, lever, self.clock, self._pose_fn(),
                                   self.run_dir, "gps")
        self.clock.start()
        self._sender = threading.Thread(target=self._send_loop, name="sim-sonar-sender",
                                        daemon=True)
        self._sender.start()
        self.digitiser.start()
        self.sequencer.start()
        for dev in (self.dvl, self.gps):
            if dev is not None:
                dev.start()
        if self._faults is not None:
            from sim_device.faults import FaultScheduler
            faults, seed = self._faults
            targets = {"sequencer": self.sequencer, "digitiser": self.digitiser,
                       "dvl": self.dvl, "gps": self.gps, "clock": self.clock}
            self.scheduler = FaultScheduler(faults, self.clock, targets,
                                            lambda: self.start_true_ns, seed).start()
            log.info("%d fault(s) scheduled from %s", len(faults), self.faults_path)
        log.info("simulated device up: scene %s, track start %s, time scale %g; sequencer "
                 "on %s, digitiser on %s:%d%s", self.scene.scene.name,
                 self.scene.track.start_time_utc, self.time_scale, self.sequencer.port,
                 self.digitiser.host, self.digitiser.port,
                 f", DVL on {self.dvl.port}, GPS on {self.gps.port}" if self.dvl else "")
        return self

    def ports(self) -> dict[str, dict[str, Any]]:
        """Where each device end is, as devices-configuration sections."""
        out: dict[str, dict[str, Any]] = {
            "sequencer": {"port": self.sequencer.port},
            "digitiser": {"host": self.digitiser.host, "port": self.digitiser.port}}
        if self.dvl is not None:
            out["dvl"] = {"port": self.dvl.port}
        if self.gps is not None:
            g = self.cfg.gps
            out["gps"] = {"port": self.gps.port}
            # the site's survey origin: the scene's NED frame is the GPS emulator's
            out["navigation"] = {"origin_latitude_deg": g.origin_latitude_deg,
                                 "origin_longitude_deg": g.origin_longitude_deg,
                                 "origin_height_m": g.origin_height_m}
        return out

    def devices_toml(self) -> str:
        """The devices configuration that reaches this device (``config/devices.toml``
        with the links replaced)."""
        return devices_toml(self.ports())

    # -- ping path -------------------------------------------------------------------

    def _on_start(self, k0: int, interval_ns: int) -> None:
        if self.start_true_ns is None:
            self.start_true_ns = self.clock.true_ns()
        self._interval_ns = interval_ns
        order = tuple(self.hw.value.sequencer.projector_order)
        if self.sequencer.schedule != order:
            log.warning("commanded schedule %s differs from the hardware configuration's "
                        "%s: the echoes are synthesised for the latter", self.sequencer.schedule,
                        order)
        self.source.start(k0, interval_ns)
        log.info("sequencer START at simulated t = track + %.3f s: first ping is track ping "
                 "%d, every %.6f s", (self.clock.true_ns() - self.clock.start_ns) * 1e-9,
                 k0, interval_ns * 1e-9)

    def _on_ping(self, event, k: int) -> None:
        self.pings_seen += 1
        self.source.want(k)
        if k >= self.scene.track.n_pings and not self._warned_track_end:
            self._warned_track_end = True
            log.info("track ping %d is past the scene's %d pings: the platform continues "
                     "along its line", k, self.scene.track.n_pings)
        self._triggers.put((event, k, self._interval_ns, self.sequencer.window))

    def _send_loop(self) -> None:
        window_default = (round(self.hw.value.digitiser.window_start_s * 1e9),
                          round(self.hw.value.digitiser.window_samples
                                / self.hw.value.digitiser.sample_rate_hz * 1e9))
        while not self._stop.is_set():
            try:
                event, k, interval, window = self._triggers.get(timeout=0.1)
            except queue.Empty:
                continue
            start_ns, length_ns = window or window_default
            tx_true = self.clock.start_ns + k * interval
            due = tx_true + start_ns + length_ns      # the receive window has closed
            if not self.clock.sleep_until(due, self._stop):
                return
            wait_s = self.clock.host_delay_s(due + interval)
            samples = self.source.get(k, wait_s)
            if samples is None:
                self.late += 1
                if self.late <= 10 or self.late % 100 == 0:  # the first ten, then every 100th
                    log.warning("ping %d (track ping %d) not ready %.3f s after its "
                                "receive window closed: dropped (%d late so far)",
                                event.sequence, k, interval * 1e-9, self.late)
                continue
            first = event.transmit_time_ns + round(self.hw.value.digitiser.window_start_s * 1e9)
            if self.digitiser.trigger(event.sequence, event.transmit_time_ns, first, samples):
                self.pings_sent += 1
            else:
                self.not_streaming += 1
                log.debug("ping %d not sent: no digitiser client streaming", event.sequence)

    # -- shut-down -------------------------------------------------------------------

    def stats(self) -> dict[str, Any]:
        return {"pings_seen": self.pings_seen, "pings_sent": self.pings_sent,
                "late": self.late, "not_streaming": self.not_streaming,
                "source": self.source.describe() if self.source else None,
                "made": getattr(self.source, "made", 0),
                "faults_fired": len(self.scheduler.fired) if self.scheduler else 0}

    def close(self) -> None:
        """Stop everything; remove the run folder if the device made it."""
        self._stop.set()
        if self.scheduler is not None:
            self.scheduler.close()
        for dev in (self.sequencer, self.gps, self.dvl, self.digitiser):
            if dev is not None:
                try:
                    dev.close()
                except Exception:
                    log.exception("closing %r failed", dev)
        if self._sender is not None:
            self._sender.join(5.0)
        if self.source is not None:
            self.source.close()
        log.info("simulated device stopped: %s", self.stats())
        if self._own_dir:
            shutil.rmtree(self.run_dir, ignore_errors=True)

    def __enter__(self) -> "SimDevice":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()
