"""SVSS acquisition: configuration, array geometry, pings and their messages, files,
wire protocols and device drivers."""

import os as _os

__version__ = "0.1.0"

# numba's OpenMP threads sleep between parallel regions instead of spinning (libgomp
# reads this when numba first loads it, at the first parallel kernel). On a computer the
# daemon, the worker and the simulator share, spinning threads take the CPU the others
# need: two test files of small kernels beside two CPU-bound processes took 75 s with
# spinning, 34 s without (alone: 23 s and 28 s). Set OMP_WAIT_POLICY to override.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
