"""Where the simulated sonar's samples come from, ahead of the sequencer's pings.

Every source has one interface: :meth:`start` (the track index of the first ping after
START and the commanded interval), :meth:`want` (the sequencer has just transmitted
track ping ``k``: synthesise up to ``k + lookahead``, forget anything before ``k``),
:meth:`get` (the samples of track ping ``k`` within a timeout, or None) and
:meth:`close`. Three kinds:

* :class:`InlineSynthesis`: one thread of the device process runs
  ``EnvironmentSource.ping(k)`` (cheap scenes);
* :class:`PoolSynthesis`: worker processes (``spawn``), each with its own
  EnvironmentSource, synthesise the next ``lookahead`` pings in parallel;
* :class:`RunFileSource`: pings of a raw run made beforehand by ``svss simulate``
  (ping ``k`` of the track is the run's ping with sequence ``k``).

Track ping ``k`` is the scene's ping ``k``: its pose is the true pose at
``track start + k * interval``. A commanded interval (PRI) other than the hardware
configuration's ``sequencer.ping_interval_s`` is honoured by the synthesising sources
(their EnvironmentSource is built for that interval); a run file has its own interval.
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import logging
import multiprocessing
import signal
import threading
import time
from typing import Optional

import numpy as np

from svss_daq.config import HardwareConfig, Loaded

__all__ = ["InlineSynthesis", "PoolSynthesis", "RunFileSource", "measure_ping_cost"]

log = logging.getLogger(__name__)


def _hardware_for(hw: Loaded[HardwareConfig], interval_ns: int) -> Loaded[HardwareConfig]:
    """``hw`` with ``sequencer.ping_interval_s`` set to ``interval_ns`` (unchanged if equal)."""
    v = hw.value
    if round(v.sequencer.ping_interval_s * 1e9) == interval_ns:
        return hw
    seq = dataclasses.replace(v.sequencer, ping_interval_s=interval_ns * 1e-9)
    return Loaded(dataclasses.replace(v, sequencer=seq), hw.text, hw.source)


class _Synthesiser:
    """EnvironmentSources of one scene, one per commanded interval."""

    def __init__(self, hw: Loaded[HardwareConfig], scene_path: str) -> None:
        from sim_device.scene import load_scene
        self.hw, self.scene = hw, load_scene(scene_path)
        self._sources: dict = {}

    def __call__(self, k: int, interval_ns: int) -> np.ndarray:
        from sim_device.environment_source import EnvironmentSource
        src = self._sources.get(interval_ns)
        if src is None:
            src = self._sources[interval_ns] = EnvironmentSource(
                _hardware_for(self.hw, interval_ns), self.scene)
        return np.ascontiguousarray(src.ping(k).samples, dtype=np.int32)


def measure_ping_cost(hw: Loaded[HardwareConfig], scene_path: str, n: int = 2) -> float:
    """Host seconds to synthesise one ping of the scene in this process (the median of
    ``n`` pings after a first one that pays for compilation and tables)."""
    synth = _Synthesiser(hw, scene_path)
    interval = round(hw.value.sequencer.ping_interval_s * 1e9)
    synth(0, interval)
    times = []
    for k in range(1, n + 1):
        t0 = time.perf_counter()
        synth(k, interval)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


class _AheadSource:
    """Shared bookkeeping: the commanded interval, the wanted window [low, high]."""

    mode = "?"

    def __init__(self, lookahead: int) -> None:
        self.lookahead = max(1, int(lookahead))
        self.interval_ns: Optional[int] = None
        self.low = 0
        self.high = -1
        self.made = 0      #: pings synthesised (or read)
        self.wasted = 0    #: pings made but never asked for in time

    def start(self, k0: int, interval_ns: int) -> None:
        self.interval_ns = int(interval_ns)
        self.want(k0)

    def want(self, k: int) -> None:
        self.low, self.high = k, k + self.lookahead

    def describe(self) -> str:
        return self.mode


class InlineSynthesis(_AheadSource):
    """Synthesis in a thread of this process (``EnvironmentSource`` built here)."""

    mode = "on the fly, in-process"

    def __init__(self, hw: Loaded[HardwareConfig], scene_path: str, lookahead: int = 4) -> None:
        super().__init__(lookahead)
        self._synth = _Synthesiser(hw, scene_path)
        self._ready: dict[int, np.ndarray] = {}
        self._next = 0
        self._cond = threading.Condition()
        self._stop = False
        self._thread = threading.Thread(target=self._run, name="sim-synthesis", daemon=True)
        self._thread.start()

    def start(self, k0: int, interval_ns: int) -> None:
        with self._cond:
            if interval_ns != self.interval_ns:
                self._ready.clear()
            super().start(k0, interval_ns)
            self._next = k0
            self._cond.notify_all()

    def want(self, k: int) -> None:
        with self._cond:
            super().want(k)
            for old in [j for j in self._ready if j < k]:
                del self._ready[old]
                self.wasted += 1
            self._next = max(self._next, k)
            self._cond.notify_all()

    def get(self, k: int, timeout_s: float) -> Optional[np.ndarray]:
        deadline = time.monotonic() + max(0.0, timeout_s)
        with self._cond:
            while k not in self._ready:
                left = deadline - time.monotonic()
                if left <= 0 or self._stop:
                    return None
                self._cond.wait(left)
            return self._ready.pop(k)

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._stop and (self.interval_ns is None or self._next > self.high):
                    self._cond.wait(0.5)
                if self._stop:
                    return
                k, interval = self._next, self.interval_ns
                self._next += 1
            try:
                samples = self._synth(k, interval)
            except Exception:
                log.exception("synthesis of track ping %d failed", k)
                continue
            with self._cond:
                self.made += 1
                if k >= self.low and interval == self.interval_ns:
                    self._ready[k] = samples
                    self._cond.notify_all()
                else:
                    self.wasted += 1

    def close(self) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        self._thread.join(10.0)


_WORKER: Optional[_Synthesiser] = None


def _worker_init(hw: Loaded[HardwareConfig], scene_path: str) -> None:
    global _WORKER
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent shuts the pool down
    _WORKER = _Synthesiser(hw, scene_path)


def _worker_ping(k: int, interval_ns: int) -> np.ndarray:
    return _WORKER(k, interval_ns)


class PoolSynthesis(_AheadSource):
    """Synthesis in ``workers`` processes (``spawn``: each builds its own
    EnvironmentSource), the next ``lookahead`` pings in flight."""

    def __init__(self, hw: Loaded[HardwareConfig], scene_path: str, workers: int,
                 lookahead: int = 8) -> None:
        super().__init__(lookahead)
        self.workers = int(workers)
        self.mode = f"on the fly, {self.workers} worker process(es)"
        self._pool = cf.ProcessPoolExecutor(self.workers,
                                            mp_context=multiprocessing.get_context("spawn"),
                                            initializer=_worker_init,
                                            initargs=(hw, str(scene_path)))
        self._futures: dict[int, cf.Future] = {}
        self._lock = threading.Lock()
        # build every worker's source now, not on the first ping
        for f in [self._pool.submit(_worker_ping, 0, round(hw.value.sequencer.ping_interval_s
                                                           * 1e9)) for _ in range(self.workers)]:
            f.result()

    def start(self, k0: int, interval_ns: int) -> None:
        with self._lock:
            if interval_ns != self.interval_ns:
                self._drop_before(1 << 62)
        super().start(k0, interval_ns)

    def _drop_before(self, k: int) -> None:
        for j in [j for j in self._futures if j < k]:
            f = self._futures.pop(j)
            if not f.cancel() and f.done():
                self.wasted += 1

    def want(self, k: int) -> None:
        super().want(k)
        with self._lock:
            self._drop_before(k)
            for j in range(k, k + self.lookahead + 1):
                if j not in self._futures:
                    self._futures[j] = self._pool.submit(_worker_ping, j, self.interval_ns)

    def get(self, k: int, timeout_s: float) -> Optional[np.ndarray]:
        with self._lock:
            f = self._futures.get(k)
        if f is None:
            return None
        try:
            samples = f.result(timeout=max(0.0, timeout_s))
        except cf.TimeoutError:
            return None
        except cf.CancelledError:     # dropped by want(): the sequencer is past it, late
            log.debug("track ping %d: its synthesis was dropped (late)", k)
            return None
        except Exception:
            log.exception("synthesis of track ping %d failed in a worker", k)
            return None
        with self._lock:
            self._futures.pop(k, None)
        self.made += 1
        return samples

    def close(self) -> None:
        """Stop at once: pending pings are cancelled and the workers terminated (a ping
        of a costly scene may take seconds; nothing waits for it)."""
        procs = list(getattr(self._pool, "_processes", {}).values())
        self._pool.shutdown(wait=False, cancel_futures=True)
        for p in procs:
            p.terminate()
        for p in procs:
            p.join(5.0)


class RunFileSource(_AheadSource):
    """Pings of a raw run (``svss simulate``): track ping ``k`` is the run's ping with
    sequence ``k``; beyond the run there is nothing to send (None, logged once)."""

    def __init__(self, path: str, hw: Loaded[HardwareConfig]) -> None:
        from svss_daq.rawfile import RawRunReader
        super().__init__(1)
        self.path = str(path)
        self.run = RawRunReader(path)
        seqs = self.run.ping_table()["ping_sequence"]
        self.index = {int(s): i for i, s in enumerate(seqs)}
        t = self.run.ping_table()["ping_time"]
        self.run_interval_ns = int(np.median(np.diff(t))) if len(t) > 1 else None
        self.mode = f"from the raw run {self.path} ({len(self.run)} pings)"
        if self.run.shape != (hw.value.digitiser.n_channels, hw.value.digitiser.window_samples):
            log.warning("%s: pings of %s samples; the hardware configuration has %d x %d",
                        self.path, self.run.shape, hw.value.digitiser.n_channels,
                        hw.value.digitiser.window_samples)
        self._warned_end = False
        self._lock = threading.Lock()

    def start(self, k0: int, interval_ns: int) -> None:
        super().start(k0, interval_ns)
        if self.run_interval_ns is not None and abs(self.run_interval_ns - interval_ns) > 1000:
            log.warning("%s was recorded at %.6f s between pings; the sequencer was "
                        "commanded %.6f s: ping k of the run is sent for track ping k",
                        self.path, self.run_interval_ns * 1e-9, interval_ns * 1e-9)

    def get(self, k: int, timeout_s: float) -> Optional[np.ndarray]:
        i = self.index.get(k)
        if i is None:
            if not self._warned_end:
                self._warned_end = True
                log.warning("%s has no ping %d (the run holds sequences %d..%d): the "
                            "digitiser sends nothing for track pings outside the run",
                            self.path, k, min(self.index, default=0), max(self.index, default=-1))
            return None
        with self._lock:  # h5py: one reader at a time
            samples = np.ascontiguousarray(self.run.ping(i).samples, dtype=np.int32)
        self.made += 1
        return samples

    def close(self) -> None:
        self.run.close()
