"""The live imaging method (svss_proc.imaging.factorised) against the exact method on a
realistic workload: the full 80-channel array over the demo's points buried in very fine
silt (refraction-table delays at 1475 m/s), imaged into the demo's tiles by the same
imager; and its parts against independent calculations (the Lanczos interpolator, the
lattice's interface surface), and where the worker says which method made a tile."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from scipy import ndimage

from sim_device.environment_source import EnvironmentSource
from sim_device.scene import load_scene
from svss_daq.config import (ConfigError, HardwareConfig, ProcessingConfig, config_path,
                             load, load_with_text)
from svss_proc.imaging.factorised import coarse_axis, coarse_surface, lanczos_weights
from svss_proc.imaging.imager import TileImager, imaging_method
from svss_proc.imaging.kernel_args import VoxelAxes
from svss_proc.run_folder import MANIFEST
from svss_proc.run_worker import Worker
from svss_proc.tiles import read_tile, read_tile_header

#: the demo's pings over its first three buried points (along 4.6, 5.4, 6.2 m)
PINGS = range(22, 70)


@pytest.fixture(scope="module")
def hw():
    return load_with_text(HardwareConfig, config_path("hardware.toml"))


@pytest.fixture(scope="module")
def pings(hw):
    scene = load_scene(config_path("scenes/demo_seabed.toml"))
    src = EnvironmentSource(hw, scene)
    return [src.ping(i) for i in PINGS]


def _proc(**imaging) -> ProcessingConfig:
    p = load(ProcessingConfig, config_path("processing-demo.toml"))
    return dataclasses.replace(p, products=None,
                               imaging=dataclasses.replace(p.imaging, **imaging))


def _tiles(hw, proc, pings, method):
    imager = TileImager(hw, proc, method=method)
    tiles = []
    for p in pings:
        tiles += imager.add(p)
    tiles += imager.finish()
    return {t.grid.index: t for t in tiles}


def _compare(exact, fact):
    """Image error over the voxels within 40 dB of the tile's peak, and each point
    response's peak change and -3 dB widths (voxels along each axis); the points: local
    maxima within 10 dB of the brightest voxel of all tiles (the scene's points stand
    that far above its speckle)."""
    out = []
    top = max(float(np.abs(t.re + 1j * t.im).max()) for t in exact.values())
    for k, te in exact.items():
        a = te.re + 1j * te.im.astype(np.complex128)
        b = fact[k].re + 1j * fact[k].im.astype(np.complex128)
        mag = np.abs(a)
        lit = mag > mag.max() * 0.01
        err = 20 * math.log10(np.sqrt(np.mean(np.abs(b - a)[lit] ** 2) /
                                      np.mean(mag[lit] ** 2)))
        peaks = np.argwhere((mag == ndimage.maximum_filter(mag, size=9))
                            & (mag > 0.3 * top))
        levels, widths = [], []
        for p in map(tuple, peaks):
            levels.append(20 * math.log10(abs(b[p]) / mag[p]))
            widths.append([(_width(np.abs(a), p, ax), _width(np.abs(b), p, ax))
                           for ax in range(3)])
        out.append((k, err, levels, widths))
    return out


def _width(mag, p, axis):
    """-3 dB width (voxels) of the response through voxel ``p`` along ``axis``."""
    idx = list(p)
    idx[axis] = slice(None)
    line = mag[tuple(idx)]
    half = line[p[axis]] / math.sqrt(2)
    lo = p[axis]
    while lo > 0 and line[lo - 1] >= half:
        lo -= 1
    hi = p[axis]
    while hi < line.size - 1 and line[hi + 1] >= half:
        hi += 1
    # linear crossings at both ends
    left = lo - (line[lo] - half) / (line[lo] - line[lo - 1]) if lo > 0 else lo
    right = hi + (line[hi] - half) / (line[hi] - line[hi + 1]) if hi < line.size - 1 else hi
    return right - left


@pytest.mark.slow
def test_factorised_method_keeps_the_buried_points(hw, pings):
    """Live method against exact, same pings and tiles: image error at most -30 dB,
    no point's peak more than 0.5 dB lower, -3 dB widths within a quarter voxel (5 mm)."""
    proc = _proc()
    assert proc.imaging.delays == "table" and proc.imaging.sediment_sound_speed_m_s < 1500
    exact = _tiles(hw, proc, pings, "exact")
    fact = _tiles(hw, proc, pings, "factorised")
    assert sorted(exact) == sorted(fact) and exact
    rows = _compare(exact, fact)
    n_points = 0
    for k, err, levels, widths in rows:
        assert err <= -30.0, (k, err)
        for lev in levels:
            assert abs(lev) <= 0.5, (k, levels)
        for w in widths:
            for we, wf in w:
                assert abs(wf - we) <= 0.25, (k, widths)
        n_points += len(levels)
        assert fact[k].method == "factorised" and exact[k].method == "exact"
        # the first stage's channel sums are the work: fewer, even on a tile this
        # narrow (1.2 m, with the lattice's halo beyond both edges)
        assert fact[k].updates * 1.5 < exact[k].updates
    assert n_points >= 3


@pytest.mark.slow
def test_factorised_over_a_sloping_interface_and_at_tile_edges(hw, pings):
    """A sloping interface (each lattice column's own interface depth, extended beyond
    the tile) and the tile's cross-track edges (the lattice's halo): the same bounds,
    on a tile whose edge cuts through the cone."""
    proc = _proc(interface_slope_deg=(3.0, -4.0))
    proc = dataclasses.replace(proc, tile=dataclasses.replace(proc.tile, width_m=0.6))
    exact = _tiles(hw, proc, pings, "exact")
    fact = _tiles(hw, proc, pings, "factorised")
    for k, err, levels, _ in _compare(exact, fact):
        assert err <= -30.0, (k, err)
        assert all(abs(v) <= 0.5 for v in levels), levels
        # the outermost columns (read through the lattice's halo) no worse than the
        # worst of the interior columns (each column's error re its own image; a missing
        # or misplaced halo column makes an edge tens of dB worse)
        a = exact[k].re + 1j * exact[k].im.astype(np.complex128)
        b = fact[k].re + 1j * fact[k].im.astype(np.complex128)
        n = a.shape[1]

        def rel(c):
            return np.linalg.norm((b - a)[:, c]) / np.linalg.norm(a[:, c])
        worst_inside = max(rel(c) for c in range(3, n - 3))
        assert max(rel(0), rel(n - 1)) <= worst_inside * 10 ** (1 / 20), k


def test_lanczos_interpolates_a_band_limited_signal():
    """Complex tones up to 0.3 cycles per lattice step, interpolated to fine positions:
    within 3 % (-30 dB) of the exact values with 3 lobes, closer with more; exact at the
    nodes; a stencil beyond the lattice refused."""
    axis = coarse_axis(0.0, 1.0, 0.08, 4)
    x = np.linspace(0.0, 1.0, 51)
    at_nodes = np.isin(np.round(x / 0.08, 9), np.round(axis / 0.08, 9))
    for cycles in (0.05, 0.15, 0.3):
        f = cycles / 0.08
        vals = np.exp(2j * np.pi * f * axis)
        err = {}
        for lobes in (2, 3, 4):
            first, w = lanczos_weights(x, axis, lobes)
            assert np.allclose(w.sum(axis=1), 1.0)
            got = np.array([w[i] @ vals[first[i]:first[i] + 2 * lobes]
                            for i in range(x.size)])
            err[lobes] = np.max(np.abs(got - np.exp(2j * np.pi * f * x)))
            assert np.allclose(got[at_nodes], np.exp(2j * np.pi * f * x[at_nodes]))
        assert err[3] < 0.03 and err[4] <= err[2], (cycles, err)
    with pytest.raises(ValueError, match="lattice"):
        lanczos_weights(np.array([axis[-1]]), axis, 3)


def test_lattice_surface_extends_a_plane_exactly():
    """The interface's depth at lattice columns beyond the tile: a plane continued."""
    along = np.arange(10) * 0.02 + 100.0
    cross = np.arange(6) * 0.02 - 0.05
    plane = 0.3 + 0.05 * (along[:, None] - 100.0) - 0.02 * cross[None, :]
    axes = VoxelAxes(along, cross, np.arange(3) * 0.02, plane)
    ca = coarse_axis(along[0], along[-1], 0.08, 4)
    cc = coarse_axis(cross[0], cross[-1], 0.08, 4)
    got = coarse_surface(axes, ca, cc)
    want = 0.3 + 0.05 * (ca[:, None] - 100.0) - 0.02 * cc[None, :]
    assert np.allclose(got, want, atol=1e-12)
    assert coarse_surface(axes._replace(surface=None), ca, cc) is None


def test_factorised_lattice_finer_than_a_voxel_is_refused(tmp_path):
    text = (config_path("processing.toml").read_text()
            .replace("factorised_step_m = [0.085, 0.07]", "factorised_step_m = [0.085, 0.01]"))
    p = tmp_path / "p.toml"
    p.write_text(text)
    with pytest.raises(ConfigError, match="imaging.factorised_step_m"):
        load(ProcessingConfig, p)


def test_the_shipped_methods():
    """Live: factorised on the CPU, exact on the GPU; ashore (process, batch): exact."""
    proc = load(ProcessingConfig, config_path("processing.toml"))
    assert imaging_method(proc) == "exact"
    assert imaging_method(proc, live=True) == "factorised"
    gpu = dataclasses.replace(proc, imaging=dataclasses.replace(proc.imaging, device="cuda"))
    assert imaging_method(gpu, live=True) == "exact"


@pytest.mark.slow
def test_the_tiles_and_manifest_name_the_method(hw, pings, tmp_path):
    """A live worker's tiles and manifest say factorised; `svss process`'s say exact."""
    text = config_path("processing-demo.toml").read_text()
    text = text.replace('delays = "table"', 'delays = "table"\nlive_method = "factorised"', 1)
    assert "live_method" in text
    cfg = tmp_path / "p.toml"
    cfg.write_text(text)
    proc = load_with_text(ProcessingConfig, cfg)
    for live, want in ((True, "factorised"), (False, "exact")):
        out = tmp_path / want
        w = Worker(hw, proc, out, live=live)
        files = w.run(pings[:30])
        tiles = [f for f in files if f.suffix == ".h5"]
        assert tiles
        for f in tiles:
            assert read_tile_header(f)["imaging_method"] == want
        assert read_tile(tiles[0])["imaging_method"] == want
        assert json.loads((out / MANIFEST).read_text())["imaging_method"] == want
