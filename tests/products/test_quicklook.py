"""Quicklooks an operator can read: on a default 15 m x 2 m x 2 m tile the 2 m axes get
at least MIN_PANEL_IN inches each, voxels no ping reached are drawn in the no-data
colour (not as low signal), and at most ``max_labels`` contacts are numbered, none on
top of another."""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest

from svss_daq.config import QuicklookConfig, omitted_default
from svss_proc.products.quicklook import (
    MAX_PANEL_IN,
    MIN_PANEL_IN,
    NO_DATA_RGBA,
    choose_labels,
    products_png,
    view_rgba,
)

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import bench_quicklook  # noqa: E402

DEFAULT_MAX_LABELS = omitted_default(QuicklookConfig, "max_labels")


@pytest.fixture(scope="module")
def default_tile():
    """Products of a default tile, made up: speckle-like levels, 39 contacts, and the
    first 1.5 m along-track imaged by no ping (bench_quicklook's tile)."""
    return bench_quicklook.default_tile()[:7]


def _count(img: np.ndarray, rgba, tol: float = 0.02) -> int:
    return int(np.all(np.abs(img[..., :3] - np.asarray(rgba[:3])) <= tol, axis=-1).sum())


def test_unimaged_voxels_get_the_no_data_colour():
    display = np.array([[-300.0, 0.0], [30.0, np.nan]])
    imaged = np.array([[True, False], [True, True]])
    rgba = view_rgba(display, imaged, -10.0, 20.0, 40.0)
    no_data = np.all(rgba == NO_DATA_RGBA, axis=-1)
    np.testing.assert_array_equal(no_data, [[False, True], [False, True]])
    assert not np.allclose(rgba[0, 0], NO_DATA_RGBA)           # low signal stays dark
    assert rgba[0, 0, :3].sum() < rgba[1, 0, :3].sum()


def test_labels_at_most_n_and_never_overlapping():
    rng = np.random.default_rng(1)
    xy = np.concatenate([rng.normal(100, 5, (20, 2)), rng.uniform(0, 1000, (19, 2))])
    chosen = choose_labels(xy, 12, min_sep_px=16.0)
    assert chosen[0] == 0 and len(chosen) <= 12
    for i in chosen:
        for j in chosen:
            if i < j:
                assert np.hypot(*(xy[i] - xy[j])) >= 16.0
    assert len(choose_labels(xy, 0)) == 0


def test_default_tile_quicklook_is_legible(default_tile, tmp_path):
    proc, grid, level, gain, mips, det, coverage = default_tile
    cfg = proc.products
    dpi = cfg.quicklook.dpi
    with_cov = products_png(tmp_path / "a.png", mips, level, gain, det, grid, 0.02, cfg,
                            "SVSS tile_0000", "test", coverage=coverage)
    img = matplotlib.image.imread(with_cov)
    n_views = 2 + sum(0.0 <= d <= 2.0 for d in cfg.quicklook.depth_slices_m)
    # stacked full-width views: each 2 m axis at least MIN_PANEL_IN high
    assert img.shape[0] >= n_views * MIN_PANEL_IN * dpi
    assert img.shape[1] >= 15.0 * dpi                 # about an inch per metre of tile
    # the unimaged 1.5 m are drawn in the no-data colour in every view along-track
    # (1.5 m of the 15 m axis, each view MIN_PANEL_IN to MAX_PANEL_IN high), and
    # nowhere else: not in the end view, every column of which was imaged
    px_per_m = (img.shape[1] - 1.6 * dpi) / 15.0
    n_no_data = _count(img, NO_DATA_RGBA)
    # (the axes take about 80 % of a panel: titles and tick labels take the rest)
    assert n_no_data >= 0.7 * n_views * (1.5 * px_per_m) * (MIN_PANEL_IN * dpi)
    assert n_no_data <= 1.1 * n_views * (1.5 * px_per_m) * (MAX_PANEL_IN * dpi)
    assert DEFAULT_MAX_LABELS < len(det)


@pytest.mark.parametrize("size_in", [(6.006, 3.337), (10.0, 9.0), (7.25, 2.995)])
def test_palette_png_has_the_size_and_the_nearest_palette_colours(tmp_path, size_in):
    # a size whose pixels are not whole (6.006 in at 100 dpi: 600.6 px) failed once the
    # pixels were taken raw (the mosaic of the demo was not written)
    from PIL import Image

    from svss_proc.products.quicklook import _palette
    from svss_proc.products.raster import Canvas
    c = Canvas(*size_in, 100)
    rng = np.random.default_rng(2)
    c.view(c.box(0.5, 0.5, size_in[0] - 1.0, size_in[1] - 1.0), rng.uniform(
        0, 1, (17, 9, 3)), (0.0, 1.0), (0.0, 1.0), False)
    c.text((10, 10), "tile 12: 3.5 m", 9)
    c.save_palette_png(tmp_path / "p.png", _palette(), 3)
    pal = np.array(_palette()).reshape(-1, 3)
    with Image.open(tmp_path / "p.png") as a:
        assert a.mode == "P"
        assert a.size == (round(size_in[0] * 100), round(size_in[1] * 100))
        got = pal[np.asarray(a)]
    want = c.pixels().astype(np.int64).reshape(-1, 3)
    got = got.reshape(-1, 3)
    # every pixel is the palette colour nearest to the drawn one (no dithering)
    colours, inverse = np.unique(want, axis=0, return_inverse=True)
    best = ((colours[:, None, :] - pal[None, :, :]) ** 2).sum(-1).min(-1)[inverse.ravel()]
    chosen = ((want - got) ** 2).sum(-1)
    assert np.all(chosen <= best + 3 * 255)            # PIL's colour cube rounds
    assert np.mean(np.sqrt(chosen) - np.sqrt(best)) < 1.0
