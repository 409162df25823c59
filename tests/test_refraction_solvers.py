"""The imager's two-medium Fermat solver and the simulator's layered ray solver are
written independently (the imager never shares code with the truth it is imaged
against); they must agree on every two-medium path, including near the critical angle
and at grazing offsets."""

from __future__ import annotations

import numpy as np
import pytest

from sim_device.layered_rays import solve_leg
from svss_proc.imaging.delays import one_way_time, vertical_slowness


@pytest.mark.parametrize("cs", [1476.0, 1767.0, 2000.0])
def test_solvers_agree(cs):
    cw = 1500.0
    c = np.array([cw, cs])
    z_top = np.array([0.0])               # interface at depth 0, one sediment layer below
    rng = np.random.default_rng(2)
    for _ in range(200):
        h = rng.uniform(0.5, 5.0)
        z = rng.uniform(1e-4, 3.0)
        rho = rng.choice([0.0, rng.uniform(0, 1e-3), rng.uniform(0, 5.0), rng.uniform(5, 40)])
        leg = solve_leg(rho, h, z, 1, c, z_top)
        t = one_way_time(h, rho, z, cw, cs)
        assert abs(t - leg["time"]) < 1e-12 + 1e-10 * t, (h, z, rho)
        # and the vertical slowness of the water leg (dT/dh) from the ray parameter
        eta = np.sqrt(1 / cw**2 - leg["p"] ** 2)
        assert abs(vertical_slowness(h, rho, z, cw, cs) - eta) < 1e-9 / cw
