"""numba's OpenMP threads wait passively unless the environment says otherwise
(svss_daq/__init__.py: spinning threads starve the daemon and the worker beside them)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PROBE = ("import svss_proc.imaging.imager, os; "
         "print(os.environ.get('OMP_WAIT_POLICY'))")


def _policy(env: dict) -> str:
    p = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True,
                       env=env, cwd=ROOT, timeout=120)
    assert p.returncode == 0, p.stderr
    return p.stdout.strip()


def test_passive_by_default_and_the_environment_wins():
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    assert _policy(env) == "PASSIVE"
    assert _policy({**env, "OMP_WAIT_POLICY": "ACTIVE"}) == "ACTIVE"
