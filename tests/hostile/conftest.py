"""Shared helpers for the hostile-input tests: the fuzzing budget and small valid
files to damage."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

from svss_daq.config import ProcessingConfig, loaded_from_text
from svss_daq.frames import TrackLine
from svss_daq.rawfile import RawRunWriter

#: hypothesis examples per fuzz test: 100 by default (new ones each run: hypothesis is not
#: derandomised), e.g. 10000 with ``SVSS_FUZZ_EXAMPLES=10000``
FUZZ_EXAMPLES = int(os.environ.get("SVSS_FUZZ_EXAMPLES", "100"))
ROOT = Path(__file__).resolve().parents[2]


def fuzz_settings(**kw) -> settings:
    """Hypothesis settings for fuzzing a reader: :data:`FUZZ_EXAMPLES` examples, no
    per-example deadline (tests bound the time themselves)."""
    kw.setdefault("max_examples", FUZZ_EXAMPLES)
    return settings(deadline=None, derandomize=False,
                    suppress_health_check=[HealthCheck.function_scoped_fixture,
                                           HealthCheck.too_slow], **kw)


def ping_for(hardware, i):
    """Ping ``i`` of the test runs (random codes, distinct per ping, never all zero)."""
    from tests.test_rawfile import _ping_for
    return _ping_for(hardware, i)


def write_run(path, hardware, n_pings: int = 6, flush_every: int = 2, **kw) -> Path:
    """A small valid raw run, closed cleanly."""
    with RawRunWriter(path, hardware, flush_every_pings=flush_every,
                      run_attrs={"scene_name": "hostile"}, **kw) as w:
        for i in range(n_pings):
            w.append(ping_for(hardware, i))
        w.append_nmea(123, "$GPGGA,120000.00,4052.0,N,07752.0,W,1,08,0.9,10.0,M,,,,*47")
    return Path(path)


def small_processing(demo_processing):
    """The demo processing configuration on a small tile (0.4 x 0.3 x 0.2 m)."""
    text = (demo_processing.text.replace("length_m = 3.0", "length_m = 0.4")
            .replace("width_m = 1.2", "width_m = 0.3").replace("depth_m = 1.0", "depth_m = 0.2"))
    assert text != demo_processing.text
    return loaded_from_text(ProcessingConfig, text, "small-processing")


def small_tile(processing, index: int = 1, seed: int = 5):
    """A small finished tile of speckle with one planted target."""
    from svss_proc.imaging.grid import tile_grid
    from tests.products import make_tile, plant, rayleigh_median, speckle
    grid = tile_grid(processing.value.tile, index)
    img = speckle(grid.shape, np.random.default_rng(seed))
    axes = (grid.along, grid.cross, grid.depth)
    plant(img, axes, [a[a.size // 2] for a in axes], rayleigh_median(1.0) * 10 ** 1.5)
    return make_tile(grid, TrackLine((10.0, 20.0), 0.5, 3.0), img, pings=range(3, 9),
                     updates=99)


def copy(src: Path, dst: Path) -> Path:
    shutil.copyfile(src, dst)
    return dst


@pytest.fixture(scope="session")
def small_proc(demo_processing):
    return small_processing(demo_processing)


@dataclass
class CliResult:
    """One ``svss`` command's exit status, standard error and seconds taken."""
    returncode: int
    stderr: str
    elapsed: float


#: runs ``svss.cli.main`` on each argument list of argv[1] (JSON), each with its own
#: standard output and error (the CLI's own logging set up by its first call writes to
#: whichever is current); an exception out of a command is its traceback and status 1,
#: as ``python -m svss`` gives
_CLI_CALLS = """
import io, json, sys, time, traceback
from svss.cli import main


class _Current:
    target = None

    def write(self, text):
        return self.target.write(text)

    def flush(self):
        self.target.flush()


out, err = _Current(), _Current()
real_stdout = sys.stdout
sys.stdout, sys.stderr = out, err
results = []
for argv in json.loads(sys.argv[1]):
    out.target, err.target = io.StringIO(), io.StringIO()
    t0 = time.monotonic()
    try:
        rc = main(argv)
    except SystemExit as exc:
        rc = exc.code if isinstance(exc.code, int) else 1
    except BaseException:
        traceback.print_exc(file=err.target)
        rc = 1
    results.append([rc, err.target.getvalue(), time.monotonic() - t0])
real_stdout.write(json.dumps(results))
"""


def svss_calls(*calls, timeout: float = 180) -> list[CliResult]:
    """The ``svss`` commands ``calls`` (argument lists) run one after another in one
    fresh Python process (one start-up, its imports, for all of them): each one's
    :class:`CliResult`."""
    argv = json.dumps([[str(a) for a in call] for call in calls])
    res = subprocess.run([sys.executable, "-c", _CLI_CALLS, argv], capture_output=True,
                         text=True, timeout=timeout, cwd=ROOT,
                         env={**os.environ, "PYTHONPATH": str(ROOT)}, check=False)
    assert res.returncode == 0, (res.returncode, res.stderr[-3000:])
    return [CliResult(*r) for r in json.loads(res.stdout)]
