"""The raster plotter of the quicklooks (svss_proc/products/raster.py): ticks on round
steps inside the axis, images placed by data coordinates the right way up, and the
contacts' circles of a real products quicklook where the layout puts them."""

from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image

from svss_daq.config import ProcessingConfig, config_path, load
from svss_proc.imaging.grid import tile_grid
from svss_proc.products import detect
from svss_proc.products.quicklook import (LEFT_IN, MARKER_PT, RIGHT_IN, SUPTITLE_IN,
                                          TITLE_IN, _panel_height, _palette, products_png)
from svss_proc.products.raster import Canvas, nice_ticks, tick_label
from svss_proc.tiles import MIPS


@pytest.mark.parametrize("lo,hi,n", [(0.0, 15.0, 8), (45.0, 60.0, 16), (-1.0, 1.0, 5),
                                     (-0.61, 0.61, 7), (0.0, 0.3, 4), (1e5, 1e5 + 3.0, 4),
                                     (-2.4e-3, 7.7e-3, 6)])
def test_ticks_round_inside_and_at_most_asked(lo, hi, n):
    values, decimals = nice_ticks(lo, hi, n)
    assert 2 <= len(values) <= n
    assert values[0] >= lo - 1e-9 * abs(hi - lo) and values[-1] <= hi + 1e-9 * abs(hi - lo)
    step = np.diff(values)
    assert np.allclose(step, step[0])
    mantissa = step[0] / 10 ** math.floor(math.log10(step[0]))
    assert min(abs(mantissa - m) for m in (1, 2, 2.5, 5)) < 1e-9
    labels = [tick_label(v, decimals) for v in values]
    assert len(set(labels)) == len(labels)            # the decimals tell them apart
    for v, text in zip(values, labels):
        assert float(text.replace("\u2212", "-")) == pytest.approx(v, abs=1e-12 + 1e-9 * abs(v))


def test_no_ticks_on_an_empty_axis():
    assert nice_ticks(2.0, 2.0, 5)[0].tolist() == [2.0]
    assert nice_ticks(float("nan"), 1.0, 5)[0].size == 0


@pytest.mark.parametrize("y_down", [False, True])
def test_a_voxel_lands_at_its_data_position(y_down):
    c = Canvas(4.0, 3.0, 100)
    nx, ny = 40, 10
    rgb = np.zeros((nx, ny, 3))
    ix, iy = 29, 2
    rgb[ix, iy] = (1.0, 1.0, 0.0)
    v = c.view(c.box(0.5, 0.5, 3.0, 2.0), rgb, (10.0, 14.0), (0.0, 1.0), y_down)
    px = c.pixels()
    ys, xs = np.nonzero(np.all(px == (255, 255, 0), axis=-1))
    # the voxel's centre in data: x = 10 + (29.5 / 40) * 4, y = (2.5 / 10) * 1
    want = v.to_px([10.0 + (ix + 0.5) / nx * 4.0], [(iy + 0.5) / ny])[0]
    assert abs(xs.mean() - want[0]) < 1.0 and abs(ys.mean() - want[1]) < 1.0
    # y up: a shallow index low in the box; y down: high in the box
    top_half = ys.mean() < v.y0 + v.h / 2
    assert top_half == y_down
    # one voxel is w / nx by h / ny pixels
    assert abs(len(set(xs)) - v.w / nx) <= 1 and abs(len(set(ys)) - v.h / ny) <= 1


def test_contacts_are_circled_where_the_layout_puts_them(tmp_path):
    """A default tile with two contacts: on the top view (the first panel) each is
    circled at the pixel the layout constants give, computed here from them."""
    proc = load(ProcessingConfig, config_path("processing.toml"))
    grid = tile_grid(proc.tile, 2)
    level = np.full(grid.shape, -5.0, dtype=np.float32)
    gain = np.zeros(grid.shape[2], dtype=np.float32)
    mips = {k: level.max(axis=axis) for k, (axis, _) in MIPS.items()}
    det = np.zeros(2, dtype=detect.DTYPE)
    det["along_m"] = [grid.along[100], grid.along[600]]
    det["cross_m"] = [grid.cross[20], grid.cross[80]]
    det["depth_m"] = [grid.depth[10], grid.depth[90]]
    det["excess_db"] = [30.0, 20.0]
    cfg = proc.products
    path = products_png(tmp_path / "q.png", mips, level, gain, det, grid, 0.02, cfg,
                        "tile", "test")
    with Image.open(path) as im:
        assert im.mode == "P" and im.getpalette()[:768] == list(_palette())
        px = np.asarray(im.convert("RGB")).astype(int)
    dpi = cfg.quicklook.dpi
    v = grid.voxel_m
    a0, a1 = grid.along[0] - v / 2, grid.along[-1] + v / 2
    c0, c1 = grid.cross[0] - v / 2, grid.cross[-1] + v / 2
    width = float(np.clip(a1 - a0 + 1.6, 7.0, 16.0))
    axes_w = width - LEFT_IN - RIGHT_IN
    h, _ = _panel_height(c1 - c0, a1 - a0, axes_w)
    r = MARKER_PT / 2 * dpi / 72
    cyan = (px[..., 0] < 60) & (px[..., 1] > 200) & (px[..., 2] > 200)
    for a, c in zip(det["along_m"], det["cross_m"]):
        x = (LEFT_IN + (a - a0) / (a1 - a0) * axes_w) * dpi
        y = (SUPTITLE_IN + TITLE_IN + (1 - (c - c0) / (c1 - c0)) * h) * dpi
        yy, xx = np.mgrid[:px.shape[0], :px.shape[1]]
        dist = np.hypot(xx - x, yy - y)
        ring = cyan & (np.abs(dist - r) <= 1.5)
        inside = cyan & (dist < r - 2)
        assert ring.sum() >= 2 * math.pi * r * 0.6, (a, c, ring.sum())
        assert inside.sum() == 0
