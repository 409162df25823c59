"""Imaging: conditioned pings backprojected into tile image planes.

Stages, each its own module: :mod:`.grid` (the tile's voxel axes), :mod:`.delays`
(travel times: straight rays, the refraction table, exact Fermat paths), the kernels
(:mod:`.cpu_kernel` with :mod:`.window_gather`, :mod:`.gpu_kernel`, both built from the
scalar functions of :mod:`.kernel_math`), and :mod:`.imager`, which places each ping in
the tile frame, chooses the tiles it reaches and hands finished tiles on.
"""
