"""The GPU pieces the imaging kernels share with the simulator's GPU synthesis, which
live in :mod:`svss_daq.gpu_shared` (below both packages); re-exported here for the
imaging kernels."""

from svss_daq.gpu_shared import THREADS, DeviceBuffers, block_count_for  # noqa: F401
