"""The processing worker: subscribes to pings over ZeroMQ (or reads a raw run), images
them into tiles and writes the tile files as tiles complete."""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Iterable

import zmq

from svss_daq import messages
from svss_daq.config import HardwareConfig, Loaded, ProcessingConfig
from svss_daq.ping import Ping
from svss_daq.ping_gate import PingGate, PingRejected
from svss_daq.progress import Progress
from svss_daq.rawfile import RawRunReader
from svss_daq.endpoints import check_endpoint
from svss_daq.subscriber import subscribe

from .imaging.imager import TileImager
from .products.chain import save_tile

log = logging.getLogger(__name__)

MANIFEST = "manifest.json"
#: names of files a worker writes into its output folder (besides the manifest)
OUTPUT_PREFIXES = ("tile_", ".tile_")


def prepare_output_dir(out: Path, force: bool = False) -> None:
    """Make ``out``; refuse one that holds tiles or a manifest of an earlier run unless
    ``force``, which removes them (outputs of two runs are never mixed)."""
    out.mkdir(parents=True, exist_ok=True)
    old = sorted(p for p in out.iterdir()
                 if p.is_file() and (p.name == MANIFEST or p.name.startswith(OUTPUT_PREFIXES)))
    if not old:
        return
    if not force:
        raise FileExistsError(f"{out}: holds {len(old)} file(s) of an earlier run (e.g. "
                              f"{old[0].name}); choose an empty folder or pass --force to "
                              "replace them")
    for p in old:
        p.unlink()
    log.warning("%s: removed %d file(s) of an earlier run (--force)", out, len(old))


class Worker:
    """Images a stream of pings into tile files in ``out_dir``.

    Every ping passes the :class:`~svss_daq.ping_gate.PingGate` and the imager's pose
    checks first; a refused ping is logged, counted (``manifest.json``'s ``refused``) and
    skipped, and the run goes on. ``force`` replaces an earlier run's outputs in
    ``out_dir`` (otherwise refused)."""

    def __init__(self, hardware: Loaded[HardwareConfig], processing: Loaded[ProcessingConfig],
                 out_dir: str | Path, *, force: bool = False):
        self.hardware, self.processing = hardware, processing
        self.out = Path(out_dir)
        self.imager = TileImager(hardware, processing.value, source=processing.source)
        prepare_output_dir(self.out, force)
        self.gate = PingGate(hardware, name="worker")
        self.written: list[Path] = []
        self.last_sequence: int | None = None
        self.gaps = 0
        self.imaging_errors = 0
        self.malformed_messages = 0

    def add(self, ping: Ping) -> bool:
        """Gate and image one ping, writing the tiles it completes; False when refused."""
        if not self.gate.admit(ping):
            return False
        try:
            tiles = self.imager.add(ping)
        except PingRejected as exc:
            self.gate.refuse(exc)
            return False
        except Exception:                    # a defect must not lose the open tiles
            self.imaging_errors += 1
            log.exception("ping %d: imaging failed; ping skipped", ping.sequence)
            return False
        if self.last_sequence is not None and ping.sequence != self.last_sequence + 1:
            self.gaps += 1
            log.warning("ping sequence jumps from %d to %d: %d ping(s) missing",
                        self.last_sequence, ping.sequence, ping.sequence - self.last_sequence - 1)
        self.last_sequence = ping.sequence
        for tile in tiles:
            self.written += save_tile(tile, self.out, self.hardware, self.processing)
        return True

    def finish(self, complete: bool = True) -> list[Path]:
        """Write every open tile and the manifest; ``complete`` False when stopped early."""
        for tile in self.imager.finish():
            self.written += save_tile(tile, self.out, self.hardware, self.processing)
        refused = dict(self.gate.refused)
        if self.gate.n_refused or self.imaging_errors or self.imager.late_pings:
            log.warning("%d ping(s) refused %s, %d failed in imaging, %d reached only "
                        "tiles already written", self.gate.n_refused, refused,
                        self.imaging_errors, self.imager.late_pings)
        manifest = self.out / MANIFEST
        tmp = manifest.with_name(manifest.name + ".partial")
        tmp.write_text(json.dumps({
            "complete": complete, "pings": self.imager.n_pings,
            "pings_refused": self.gate.n_refused, "refused": refused,
            "imaging_errors": self.imaging_errors, "late_pings": self.imager.late_pings,
            "malformed_messages": self.malformed_messages,
            "track_reanchored": self.imager.track.reanchored,
            "sequence_gaps": self.gaps, "voxel_channel_updates": self.imager.updates,
            "files": [p.name for p in self.written]}, indent=2))
        os.replace(tmp, manifest)
        return self.written

    def run(self, pings: Iterable[Ping], total: int | None = None) -> list[Path]:
        """Image every ping of ``pings``; on SIGINT (KeyboardInterrupt) write the open
        tiles and the manifest (marked incomplete) and re-raise."""
        progress = Progress("imaging", total, log)
        try:
            for ping in pings:
                self.add(ping)
                progress.update()
        except KeyboardInterrupt:
            self.stop()
            raise
        return self.finish()

    def stop(self) -> list[Path]:
        """Stopped early (a signal): write the open tiles and the manifest, marked
        incomplete."""
        log.warning("stopped: writing %d open tile(s)", len(self.imager.active))
        return self.finish(complete=False)


def process_raw(path: str | Path, out_dir: str | Path,
                processing: Loaded[ProcessingConfig], *, force: bool = False) -> list[Path]:
    """Image a recorded raw run with the hardware configuration it was recorded with."""
    with RawRunReader(path) as run:
        worker = Worker(run.hardware, processing, out_dir, force=force)
        return worker.run(iter(run), total=len(run))


#: longest wait in one poll, s (signals are handled between polls)
POLL_SLICE_S = 0.2


def serve(endpoint: str, out_dir: str | Path, hardware: Loaded[HardwareConfig],
          processing: Loaded[ProcessingConfig], idle_timeout_s: float | None = None, *,
          receive_hwm: int = 500, force: bool = False) -> list[Path]:
    """Receive pings from ``endpoint`` until an end-of-run message (or ``idle_timeout_s``
    without a message); image them and write tiles. Returns the files written. SIGINT
    (KeyboardInterrupt, also while idle) writes the open tiles and the manifest, marked
    incomplete, and re-raises."""
    check_endpoint(endpoint, bind=False)            # before anything is written
    worker = Worker(hardware, processing, out_dir, force=force)
    sock = subscribe(endpoint, receive_hwm)
    log.info("worker: waiting for pings from %s", endpoint)
    progress = Progress("imaging", None, log)
    poller = zmq.Poller()
    poller.register(sock, zmq.POLLIN)
    try:
        idle = 0.0
        while True:
            if not poller.poll(int(POLL_SLICE_S * 1000)):
                idle += POLL_SLICE_S
                if idle_timeout_s is not None and idle >= idle_timeout_s:
                    log.warning("no message from %s for %.1f s: finishing", endpoint,
                                idle_timeout_s)
                    break
                continue
            idle = 0.0
            try:
                msg = messages.recv(sock)
            except messages.MessageError as exc:
                worker.malformed_messages += 1
                log.error("dropped a malformed message: %s", exc)
                continue
            if isinstance(msg, messages.RunEnd):
                received = worker.gate.admitted + worker.gate.n_refused
                log.info("end of run %s after %d pings (%d received)", msg.run_id,
                         msg.n_pings, received)
                break
            worker.add(msg)
            progress.update()
    except KeyboardInterrupt:
        worker.stop()
        raise
    finally:
        sock.close(linger=0)
    return worker.finish()
