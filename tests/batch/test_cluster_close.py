"""svss batch's own LocalCluster closed on a loaded machine (issue 27, item 10): worker
processes held up while the cluster closes woke into a heartbeat to the closed
scheduler and logged it with a traceback, after a successful batch. Real processes; the
load is a SIGSTOP of the workers for 1 to 3.4 s (the nanny kills a worker after 4 s): each
wakes at another moment of the close."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

from .conftest import Path

pytest.importorskip("distributed")

ROOT = Path(__file__).resolve().parents[2]

CLOSE = """
    import os, signal, sys, threading, time
    import distributed
    from svss_proc.batch.run import _close_client
    if __name__ == "__main__":
        cluster = distributed.LocalCluster(n_workers=4, threads_per_worker=1,
                                           processes=True, host="127.0.0.1",
                                           dashboard_address=None)
        client = distributed.Client(cluster)
        assert client.gather(client.map(abs, range(-8, 0))) == list(range(8, 0, -1))
        pids = list(client.run(os.getpid).values())
        for p in pids:
            os.kill(p, signal.SIGSTOP)           # held up by the machine's load
        def cont():
            t0 = time.monotonic()
            for k, p in enumerate(pids):
                time.sleep(max(0.0, t0 + 1.0 + 0.8 * k - time.monotonic()))
                try:
                    os.kill(p, signal.SIGCONT)
                except ProcessLookupError:
                    pass
        threading.Thread(target=cont, daemon=True).start()
        _close_client(client, cluster)
        time.sleep(1.0)                          # a late worker's last words
        print("closed", flush=True)
"""


@pytest.mark.slow
def test_closing_a_held_up_cluster_logs_no_heartbeat_traceback(tmp_path):
    script = tmp_path / "close.py"
    script.write_text(textwrap.dedent(CLOSE))
    res = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                         timeout=180, cwd=ROOT)
    assert res.returncode == 0 and "closed" in res.stdout, res.stderr[-3000:]
    assert "heartbeat" not in res.stderr and "Traceback" not in res.stderr, \
        res.stderr[-3000:]
