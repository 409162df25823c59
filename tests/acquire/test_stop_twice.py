"""The daemon's stop is safe to call twice even when the first ended "failed": a stop
signal inside a segment's creation failed the recording, the run's own handler stopped
the daemon, and the command's handler stopped it again, publishing on the closed status
socket (exit 1 instead of 130 for a SIGTERM)."""

from __future__ import annotations

from svss_daq.acquire_config import load_acquire
from svss_daq.daemon import AcquisitionDaemon

from .conftest import acquire_toml


def test_a_failed_stop_is_not_repeated(tmp_path):
    daemon = AcquisitionDaemon(load_acquire(acquire_toml(tmp_path,
                                                         catch_up={"linger_s": 0.0})))
    daemon.bind()                       # real recording and loopback sockets
    daemon.failure = "recording stopped: interrupted while a segment was created"
    daemon.stop()
    assert daemon.state == "failed"
    daemon.stop()                       # the command's handler, after the run's own
    assert daemon.state == "failed"
