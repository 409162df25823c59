"""The fast accumulation (``[scattering] synthesis = "fast"``, the default) against the
reference kernel on the same scatterers, and the fidelity options of
:mod:`sim_device.fidelity`: per-path volume depth limits (honoured exactly by the
kernel; their levels follow the sonar equation) and densities per resolution cell."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sim_device.environment_source import EnvironmentSource
from sim_device.fidelity import densities, resolution_cell
from sim_device.scene import load_scene
from sim_device.synthesis import Points, TransmitLegs, beam_of, transmit_legs
from svss_daq.config import config_path

PING = 100


def sand(**scattering):
    """The seed's sand scene, thinned (explicit densities, 10x below the file's former
    ones) and cut at 1.2 m so that a ping is quick, no level cut-off; multipath to second
    order; no coherent returns, no targets."""
    sc = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
    opts = {"specular": False, "interface_density_per_m2": 100.0,
            "volume_density_per_m3": 400.0, "volume_max_depth_m": 1.2,
            "scatterers_per_resolution_cell": None, "volume_below_noise_db": None}
    opts.update(scattering)
    return dataclasses.replace(sc, scattering=dataclasses.replace(sc.scattering, **opts),
                               targets=())


def rel(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


@pytest.fixture(scope="module")
def sand_pair(hardware):
    fast = EnvironmentSource(hardware, sand())
    ref = EnvironmentSource(hardware, sand(synthesis="reference"))
    return fast, ref


def test_fast_path_agrees_with_the_reference_to_float32_rounding(sand_pair):
    fast, ref = sand_pair
    assert fast.synthesis == "fast" and ref.synthesis == "reference"
    a = fast.scattered(PING)
    ea = fast.last_stats["echoes"]
    b = ref.scattered(PING)
    assert fast.last_stats["in_view"] == ref.last_stats["in_view"] > 10000
    assert ea == ref.last_stats["echoes"] > 1_000_000        # the same echoes ...
    assert rel(a, b) < 1e-5                                  # ... summed in float32


@pytest.mark.extended      # the default precision's agreement runs by default (above)
@pytest.mark.parametrize("precision", ["exact", "float32"])
def test_fast_path_agrees_at_other_precisions(hardware, precision):
    """exact: every refracted leg goes through the fast path's scalar fall-back (Brent);
    float32: single-precision inputs."""
    opts = {"precision": precision, "volume_max_depth_m": 0.5,
            "interface_density_per_m2": 30.0, "volume_density_per_m3": 100.0}
    a = EnvironmentSource(hardware, sand(**opts))
    b = EnvironmentSource(hardware, sand(**opts, synthesis="reference"))
    pa, pb = a.scattered(PING), b.scattered(PING)
    assert a.last_stats["echoes"] == b.last_stats["echoes"] > 10000
    assert rel(pa, pb) < (1e-5 if precision == "exact" else 1e-4)


def test_fast_path_agrees_on_points_in_water(hardware):
    demo = load_scene(config_path("scenes/demo.toml"))
    ref = dataclasses.replace(demo, scattering=None)
    a = EnvironmentSource(hardware, ref)
    b = EnvironmentSource(hardware, ref)
    b.synthesis = "reference"
    pa, pb = a.scattered(40), b.scattered(40)
    assert a.last_stats["echoes"] == b.last_stats["echoes"] > 0
    assert rel(pa, pb) < 1e-5


def test_per_path_depth_limits_are_honoured(sand_pair, hardware):
    fast, _ = sand_pair
    # every path cut at 0.5 m == the scene cut at 0.5 m (the same seabed cells)
    cut = EnvironmentSource(hardware, sand(volume_max_depth_m=0.5, synthesis="reference"))
    fast.zmax = np.full(fast.allowed.shape, 0.5)
    try:
        a = fast.scattered(PING)
    finally:
        fast.zmax = np.full(fast.allowed.shape, np.inf)
    assert rel(a, cut.scattered(PING)) < 1e-5
    # multipath only from the interface (volume limit below it) == the direct path plus
    # the interface's multipath: check on the volume alone, where it is the direct path
    vol = EnvironmentSource(hardware, sand(interface=False))
    direct = EnvironmentSource(hardware, sand(interface=False))
    vol.zmax = np.where(np.eye(*vol.allowed.shape, dtype=bool) & (np.arange(
        vol.allowed.shape[0])[:, None] == 0), np.inf, -1.0)
    direct.allowed = np.zeros_like(direct.allowed)
    direct.allowed[0, 0] = True
    pv, pd = vol.scattered(PING), direct.scattered(PING)
    assert vol.last_stats["echoes"] == direct.last_stats["echoes"] > 0
    assert rel(pv, pd) < 1e-5


def test_volume_limits_follow_the_sonar_equation(hardware):
    """Each path keeps its volume down to the depth where its level meets the floor:
    multipath (weaker) stops shallower than the direct path, and 10 dB more margin
    goes 10 dB / (4 alpha 10 log10 e) deeper (sand: 27.6 dB/m two-way), the slowly
    varying spreading aside."""
    a = EnvironmentSource(hardware, sand(volume_below_noise_db=0.0, volume_max_depth_m=6.0))
    b = EnvironmentSource(hardware, sand(volume_below_noise_db=10.0, volume_max_depth_m=6.0))
    za, zb = a.zmax, b.zmax
    assert za[0, 0] > za[0, 1] > za[0, 2] > 0 and za[1, 0] == za[0, 1]
    assert za[1, 1] < za[0, 1]
    g = a.frame(0)
    nu = a.media.c[1] / a.media.c[0]
    db_e = 10 * math.log10(math.e)
    for ab, h_r in [((0, 0), 2.0), ((0, 1), 3.0), ((0, 2), 7.0)]:
        z = 0.5 * (za[ab] + zb[ab])
        h_t = -g.tx[2]
        # dB/m: attenuation both ways and the water-equivalent spreading 1/(h + nu z)^2
        # on each leg
        slope = 4 * a.media.alpha[1] * db_e + 2 * db_e * nu * (1 / (h_t + nu * z)
                                                               + 1 / (h_r + nu * z))
        assert zb[ab] - za[ab] == pytest.approx(10.0 / slope, abs=0.01), ab
    # the generated seabed stops at the deepest kept path
    assert a.seabed.z_cut == pytest.approx(za[a.allowed].max())
    s = a.scatterers(PING)
    assert s.z.max() <= za[0, 0] + 1e-12


def test_resolution_cell_and_densities(hardware):
    hw = hardware.value
    src = EnvironmentSource(hardware, sand(scatterers_per_resolution_cell=2.0))
    cell = src.resolution
    lam = 1500.0 / hw.waveform.center_hz
    h = 2.0                                                  # array above the interface
    assert cell.along == pytest.approx(lam * h / (8 * 0.091), rel=1e-3)
    assert cell.across == pytest.approx(lam * h / (12 * 0.091), rel=1e-3)
    assert cell.depth_sediment == pytest.approx(src.media.c[1] / (2 * 15000.0))
    di, dv = src.seabed.densities
    assert di * cell.area == pytest.approx(2.0) and dv * cell.volume == pytest.approx(2.0)
    assert densities(cell, 1.0) == pytest.approx((di / 2, dv / 2))
    c2 = resolution_cell(np.array([[0, 0, 0], [1, 2, 0.0]]), 0.5, 1e4, 3e4, 3.0, 1500, 1800)
    assert (c2.along, c2.across, c2.depth_water) == pytest.approx((0.1, 0.06, 0.075))


@pytest.mark.extended      # numba compiles the scalar leg for a call from Python (~40 s);
                           # the default run checks the echoes (below)
def test_near_critical_receive_legs_agree_with_the_scalar_leg(hardware):
    """The fast kernel's receive legs (table s checked and, where the table is poor,
    refined by Newton's method, all vectorised across channels) against the scalar leg
    the reference kernel uses (table, its residual check and Brent): shallow sediment
    scatterers seen from near the critical angle, where the table is poorest (measured:
    8025 legs in the checked part of the table, 2795 of them poor; delays within 2e-18 s,
    amplitudes 3e-12; without the refinement the delays are off by 2.5e-8 s)."""
    from sim_device import layered_rays, synthesis_fast_legs as fl
    from sim_device.layered_rays import TABLE_CEILING, TABLE_RESIDUAL, TABLE_TRUSTED
    from sim_device.synthesis import leg_body

    src = EnvironmentSource(hardware, sand())
    g = src.frame(PING)
    rx = g.rx - [g.tx[0], g.tx[1], 0.0]
    img = src._images(rx)                                  # (channels, images, 6)
    imt = np.ascontiguousarray(img.transpose(1, 2, 0))
    m, beam = src.media, src.rx_beam
    tab = src.table
    gtab = fl._beam_table(beam.front, beam.back)
    itab = fl._interface_tables(src.r_top, src.r_bot)
    ms = fl._receive_scalars(m.c, m.alpha, g.bore, beam.front, beam.back,
                             float(beam.lo_front), float(beam.lo_back))
    nch = img.shape[0]
    fix, wk = np.zeros(nch, dtype=np.bool_), np.empty((11, nch))
    tr, ar_re, ar_im = wk[8], wk[9], wk[10]          # the legs' outputs
    hbuf, cbuf = np.empty(m.n + 1), np.empty(2)
    cx, cy = rx[:, 0].mean(), rx[:, 1].mean()
    n_checked = n_poor = n_fix = 0
    worst_tau = worst_amp = 0.0
    for zk in (0.002, 0.01, 0.03, 0.1):
        for r in np.linspace(1.6, 4.0, 13):
            for az in (0.3, 1.9, 3.6):
                xk, yk = cx + r * math.cos(az), cy + r * math.sin(az)
                fl._receive_legs(xk, yk, zk, 1, 0, imt, ms, tab.reshape(-1), tab.shape[1],
                                 itab, gtab, src.sig, fix, wk)
                for ch in range(nch):
                    # the table's own s and residual (what decides the path)
                    ex, ey, h0 = img[ch, 0, 0], img[ch, 0, 1], img[ch, 0, 2]
                    rho = math.hypot(xk - ex, yk - ey)
                    t = layered_rays.table_ray_tan(rho, h0, zk, m.c[0], m.c[1], tab, hbuf,
                                                   cbuf)
                    s = t / math.sqrt(1.0 + t * t)
                    if TABLE_TRUSTED <= s < TABLE_CEILING:
                        n_checked += 1
                    tau, a, _ = leg_body(ex, ey, h0, img[ch, 0, 3], img[ch, 0, 4],
                                         int(img[ch, 0, 5]), xk, yk, zk, 1, True, m.c,
                                         m.rho, m.delta, m.alpha, m.z_top, tab, src.r_top,
                                         src.r_bot, g.bore, beam.front, beam.back,
                                         beam.lo_front, beam.lo_back, hbuf, cbuf)
                    if fix[ch]:              # left to the scalar leg by the kernel
                        n_fix += 1
                        continue
                    n_poor += _table_is_poor(rho, h0, zk, m.c[0], m.c[1], tab,
                                             TABLE_TRUSTED, TABLE_RESIDUAL)
                    worst_tau = max(worst_tau, abs(tr[ch] - tau))
                    if a != 0.0:
                        worst_amp = max(worst_amp,
                                        abs(complex(ar_re[ch], ar_im[ch]) - a) / abs(a))
    # the set reaches both the checked part of the table and legs where it is poor
    assert n_checked > 1000 and n_poor > 100, (n_checked, n_poor)
    assert worst_tau < 1e-14                   # s (delay 2-4 ms: 5 ulp)
    assert worst_amp < 1e-9


def _table_is_poor(rho, h0, h1, c0, c1, tab, trusted, residual):
    """The two-medium table's s, interpolated as the kernels do, fails its residual
    check (layered_rays.table_ray_tan), so that the leg needs a solver."""
    nw, nv = tab.shape
    d = h0 + h1
    x, y = h0 / d * (nw - 1), rho / (rho + d) * (nv - 1)
    i, j = min(int(x), nw - 2), min(int(y), nv - 2)
    fx, fy = x - i, y - j
    s = ((1 - fx) * ((1 - fy) * tab[i, j] + fy * tab[i, j + 1])
         + fx * ((1 - fy) * tab[i + 1, j] + fy * tab[i + 1, j + 1]))
    if s < trusted or s >= 1.0:
        return False
    cmax = max(c0, c1)
    off = sum(h * (s * c / cmax) / math.sqrt(1 - (s * c / cmax) ** 2)
              for h, c in ((h0, c0), (h1, c1)))
    return abs(off - rho) > residual * d


def test_near_critical_echoes_agree_with_the_reference_kernel(hardware):
    """The echoes of shallow sediment scatterers seen near the critical angle (the
    table's checked part, and where it is poor: Newton's method in the fast kernel,
    Brent in the reference), through a receive beam that sees every direction, so that
    those legs carry amplitude: the fast kernel agrees with the reference kernel to
    float32 rounding (measured without the refinement: 1.5e-2)."""
    from sim_device.synthesis import (Beam, Pass2, Paths, Points, TransmitLegs, accumulate,
                                      accumulate_fast)

    src = EnvironmentSource(hardware, sand())
    g = src.frame(PING)
    ox, oy = g.tx[0], g.tx[1]
    tx, rx = g.tx - [ox, oy, 0.0], g.rx - [ox, oy, 0.0]
    cx, cy = rx[:, 0].mean(), rx[:, 1].mean()
    zk, r, az = np.meshgrid([0.002, 0.01, 0.03], np.linspace(2.4, 3.4, 11),
                            np.linspace(0.0, 2 * np.pi, 7)[:-1], indexing="ij")
    sx = (cx + r * np.cos(az)).ravel()
    sy = (cy + r * np.sin(az)).ravel()
    sz = zk.ravel().copy()
    med = np.ones(sx.size, dtype=np.int64)
    n = sx.size
    # one transmit leg per scatterer, unit amplitude, a plausible delay
    img_t = src._images(tx[None, :])[0]
    tau_t = np.zeros((n, img_t.shape[0]))
    tau_t[:, 0] = np.hypot(sx, sy) / 1500.0 + 2.0 / 1500.0
    amp_t = np.zeros((n, img_t.shape[0]), dtype=complex)
    amp_t[:, 0] = 1.0
    img_r = src._images(rx)
    allowed = np.zeros_like(src.allowed)
    allowed[0, 0] = True
    wide = np.ones(64)                          # gain 1 for cos(off-axis) in [-1, 1]
    m, p = src.media, src.pulses
    p2 = Pass2(Points(sx, sy, sz, med), TransmitLegs(tau_t, amp_t),
               Paths(img_r, allowed, np.full(allowed.shape, 1e300)), src.medium_bundle(),
               Beam(g.bore, wide, np.zeros(0), -1.0, 1.0), p.window())
    ref = p.buffer(img_r.shape[0])
    n_ref = accumulate(p2, ref)
    fast, n_fast = accumulate_fast(p2, p.n_buf, 2)
    assert n_fast.sum() == n_ref.sum() > 0.9 * n * img_r.shape[0]
    assert rel(fast, ref) < 1e-6


def _transmit_pair(src, x, y, z, med, amp, img):
    """The transmit legs of the scatterers (x, y, z, med, strength amp) from the
    projector images ``img`` by the scalar kernel and by the vectorised one."""
    beam = beam_of(src.tx_beam, src.frame(PING).bore)
    out = []
    for fast in (False, True):
        legs = TransmitLegs(np.empty((x.size, img.shape[0])),
                            np.empty((x.size, img.shape[0]), dtype=np.complex128))
        transmit_legs(Points(x, y, z, med), amp, img, src.medium_bundle(), beam, legs, fast)
        out.append(legs)
    return out


def test_vectorised_transmit_legs_agree_with_the_scalar_leg(hardware):
    """The fast path's transmit legs (vectorised across scatterers: table s, its residual
    check and Newton's method where the table is poor, beam, 1 + R, seabed bounces)
    against the scalar leg of the reference, on a sand ping's scatterers with the scene's
    projector images (direct, surface and surface-seabed), moved 5 km from the tile's
    origin, plus a grid of edge cases: directly below an image (zero offset), grazing
    legs near the sand's critical angle (shallow scatterers far out), depths from 0.1 mm
    to 3 m, interface scatterers and points in the water (the scalar leg's cases).
    Delays within 1e-15 s, amplitudes within 1e-9 of each leg's (plus 1e-12 of the
    largest: on the beam's taper edge, where the gain falls to zero, the gain table's
    position rounds differently; measured 6e-10 at 2e-11 of the peak), the same legs
    zero."""
    src = EnvironmentSource(hardware, sand())
    g = src.frame(PING)
    s = src.scatterers(PING)
    far = np.array([5000.0, -5000.0, 0.0])
    tx = g.tx - [g.tx[0], g.tx[1], 0.0] + far
    img = src._images(tx[None, :])[0]
    assert img.shape[0] == 3 and img[:, 5].max() == 1          # a seabed bounce
    # edge cases about the projector: offsets 0 .. 40 m at three azimuths, depths
    # 0.1 mm .. 3 m in the sand, and a few on the interface and in the water
    r, az, zz = np.meshgrid([0.0, 0.01, 0.5, 2.0, 3.3, 3.5, 5.0, 10.0, 40.0],
                            [0.3, 1.9, 3.6], [1e-4, 0.01, 0.3, 3.0], indexing="ij")
    ex = np.concatenate([far[0] + r.ravel() * np.cos(az.ravel()), far[:1] + [0.3, 1.0]])
    ey = np.concatenate([far[1] + r.ravel() * np.sin(az.ravel()), far[1:2] + [0.2, -0.4]])
    ez = np.concatenate([zz.ravel(), [0.0, -0.5]])
    emed = np.concatenate([np.ones(zz.size, dtype=np.int64), [-1, 0]])
    x = np.concatenate([s.x - g.tx[0] + far[0], ex])
    y = np.concatenate([s.y - g.tx[1] + far[1], ey])
    z = np.concatenate([s.z, ez])
    med = np.concatenate([s.med, emed])
    amp = np.concatenate([s.amp, np.full(ex.size, 1.0 + 0.5j)])
    assert (med == 1).sum() > 10000 and (med == -1).sum() > 100
    (tau0, a0), (tau1, a1) = _transmit_pair(src, x, y, z, med, amp, img)
    assert np.abs(tau1 - tau0).max() < 1e-15
    assert np.array_equal(a1 == 0, a0 == 0)
    assert np.count_nonzero(a0) > 10000
    scale = np.abs(a0).max(axis=0)
    assert np.all(np.abs(a1 - a0) <= 1e-9 * np.abs(a0) + 1e-12 * scale)
