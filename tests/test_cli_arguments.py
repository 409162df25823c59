"""Command-line arguments a user gets wrong are refused before anything starts, saying
what is wrong (the real ``svss`` command, in its own process)."""

from __future__ import annotations

import subprocess
import sys

import pytest


def _svss(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "svss", *args], capture_output=True,
                          text=True, timeout=120, cwd=cwd)


@pytest.mark.parametrize("args, says", [
    (("acquire", "--pings", "-3"), "-3 is not above zero"),
    (("acquire", "--duration", "-1.5"), "-1.5 is not above zero"),
    (("acquire", "--pings", "many"), "'many' is not a number"),
    (("view", "--port", "99999"), "web port 99999 is outside 0-65535"),
])
def test_bad_numbers_are_refused_before_anything_starts(args, says):
    r = _svss(*args)
    assert r.returncode == 2, r.stderr
    assert says in r.stderr, r.stderr
    assert "zeromq" not in r.stderr.lower()       # (the web port was called an endpoint)


def test_products_of_a_file_says_it_wants_the_tile_folder(tmp_path):
    f = tmp_path / "tile_0000.h5"
    f.write_bytes(b"not a folder")
    r = _svss("products", str(f))
    assert r.returncode == 2
    assert "not a folder" in r.stderr and "tile folder" in r.stderr, r.stderr
