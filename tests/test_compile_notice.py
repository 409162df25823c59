"""The line before numba compiles: said when a kernel is compiled, not when it is loaded
from the on-disk cache (two fresh processes sharing one cache folder)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

from svss.compile_notice import MESSAGE

ROOT = Path(__file__).resolve().parents[1]


def test_said_on_the_first_run_only(tmp_path):
    (tmp_path / "kernel_mod.py").write_text(textwrap.dedent("""
        import numba

        @numba.njit(cache=True)
        def twice(x):
            return 2 * x
    """))
    script = textwrap.dedent("""
        import logging, sys
        logging.basicConfig(level=logging.INFO, format="%(message)s")
        from svss.compile_notice import announce_compiling
        announce_compiling()
        announce_compiling()                  # installed once
        import kernel_mod
        assert kernel_mod.twice(21) == 42
        assert kernel_mod.twice(2.5) == 5.0   # a second compile: no second line
    """)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"),
               PYTHONPATH=os.pathsep.join([str(tmp_path), str(ROOT)]))

    def run() -> str:
        p = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                           env=env, timeout=120)
        assert p.returncode == 0, p.stderr
        return p.stderr

    assert run().count(MESSAGE) == 1          # compiled: said once
    assert MESSAGE not in run()               # loaded from the cache: nothing said
