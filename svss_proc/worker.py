"""The processing worker: subscribes to pings over ZeroMQ (or reads a raw run), images
them into tiles and writes the tile files as tiles complete."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Iterable

import zmq

from svss_daq import messages
from svss_daq.config import HardwareConfig, Loaded, ProcessingConfig
from svss_daq.ping import Ping
from svss_daq.progress import Progress
from svss_daq.rawfile import RawRunReader

from .imaging.imager import TileImager
from .products.chain import save_tile

log = logging.getLogger(__name__)

MANIFEST = "manifest.json"


class Worker:
    """Images a stream of pings into tile files in ``out_dir``."""

    def __init__(self, hardware: Loaded[HardwareConfig], processing: Loaded[ProcessingConfig],
                 out_dir: str | Path):
        self.hardware, self.processing = hardware, processing
        self.out = Path(out_dir)
        self.out.mkdir(parents=True, exist_ok=True)
        self.imager = TileImager(hardware, processing.value)
        self.written: list[Path] = []
        self.last_sequence: int | None = None
        self.gaps = 0

    def add(self, ping: Ping) -> None:
        if self.last_sequence is not None and ping.sequence != self.last_sequence + 1:
            self.gaps += 1
            log.warning("ping sequence jumps from %d to %d: %d ping(s) missing",
                        self.last_sequence, ping.sequence, ping.sequence - self.last_sequence - 1)
        self.last_sequence = ping.sequence
        for tile in self.imager.add(ping):
            self.written += save_tile(tile, self.out, self.hardware, self.processing)

    def finish(self) -> list[Path]:
        for tile in self.imager.finish():
            self.written += save_tile(tile, self.out, self.hardware, self.processing)
        manifest = self.out / MANIFEST
        manifest.write_text(json.dumps({
            "pings": self.imager.n_pings, "sequence_gaps": self.gaps,
            "voxel_channel_updates": self.imager.updates,
            "files": [p.name for p in self.written]}, indent=2))
        return self.written

    def run(self, pings: Iterable[Ping], total: int | None = None) -> list[Path]:
        progress = Progress("imaging", total, log)
        for ping in pings:
            self.add(ping)
            progress.update()
        return self.finish()


def process_raw(path: str | Path, out_dir: str | Path,
                processing: Loaded[ProcessingConfig]) -> list[Path]:
    """Image a recorded raw run with the hardware configuration it was recorded with."""
    with RawRunReader(path) as run:
        worker = Worker(run.hardware, processing, out_dir)
        return worker.run(iter(run), total=len(run))


def subscribe(endpoint: str, ctx: zmq.Context | None = None) -> zmq.Socket:
    """A SUB socket connected to a ping publisher, subscribed to all SVSS topics."""
    ctx = ctx or zmq.Context.instance()
    sock = ctx.socket(zmq.SUB)
    sock.setsockopt(zmq.RCVHWM, 0)
    sock.connect(endpoint)
    sock.setsockopt(zmq.SUBSCRIBE, b"svss.")
    return sock


def serve(endpoint: str, out_dir: str | Path, hardware: Loaded[HardwareConfig],
          processing: Loaded[ProcessingConfig], idle_timeout_s: float | None = None
          ) -> list[Path]:
    """Receive pings from ``endpoint`` until an end-of-run message (or ``idle_timeout_s``
    without a message); image them and write tiles. Returns the files written."""
    sock = subscribe(endpoint)
    worker = Worker(hardware, processing, out_dir)
    progress = Progress("imaging", None, log)
    poller = zmq.Poller()
    poller.register(sock, zmq.POLLIN)
    try:
        while True:
            timeout = None if idle_timeout_s is None else int(idle_timeout_s * 1000)
            if not poller.poll(timeout):
                log.warning("no message from %s for %.1f s: finishing", endpoint,
                            idle_timeout_s)
                break
            try:
                msg = messages.recv(sock)
            except messages.MessageError as exc:
                log.error("dropped a malformed message: %s", exc)
                continue
            if isinstance(msg, messages.RunEnd):
                log.info("end of run %s after %d pings", msg.run_id, msg.n_pings)
                break
            worker.add(msg)
            progress.update()
    finally:
        sock.close(linger=0)
    return worker.finish()
