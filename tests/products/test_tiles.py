"""Tile files: xarray opens them with named dimensions and coordinates, the products and
detections round-trip, and save_tile writes the tile and its quicklook."""

from __future__ import annotations

import h5py
import matplotlib.image
import numpy as np
import pytest
import xarray as xr

from svss_daq.config import ProcessingConfig, loaded_from_text
from svss_daq.frames import TrackLine
from svss_proc.imaging.grid import tile_grid
from svss_proc.products.chain import compute_products, save_tile
from svss_proc.tiles import (DIMS, TILE_FORMAT, read_detections, read_tile,
                             read_tile_header, write_tile)

from . import VOXEL, make_tile, plant, rayleigh_median, speckle

LINE = TrackLine((10.0, 20.0), 0.5, 3.0)


def same_table(a: np.ndarray, b: np.ndarray) -> None:
    """Two detection tables equal column by column (NaN equal to NaN: features not
    measured)."""
    assert a.dtype == b.dtype
    for name in a.dtype.names:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)


@pytest.fixture(scope="module")
def planted(demo_processing):
    """A demo-sized tile (150 x 60 x 50) of speckle with two planted targets."""
    grid = tile_grid(demo_processing.value.tile, 1)
    axes = (grid.along, grid.cross, grid.depth)
    img = speckle(grid.shape, np.random.default_rng(21))
    targets = [(grid.along[40], grid.cross[15], grid.depth[12]),
               (grid.along[110], grid.cross[45], grid.depth[35])]
    for t in targets:
        plant(img, axes, t, rayleigh_median(1.0) * 10 ** (30 / 20))
    tile = make_tile(grid, LINE, img, pings=range(7, 40), updates=12345)
    tile.track = [(1_700_000_000_000_000_000 + 100_000_000 * k, 0.1 * k, 0.05 * k)
                  for k in range(len(tile.pings))]
    tile.run_id = "line3"
    return tile, targets


@pytest.fixture(scope="module")
def tile_file(planted, demo_processing, hardware, tmp_path_factory):
    tile, _ = planted
    g = tile.grid
    prods = compute_products(tile.image, (g.along, g.cross, g.depth), VOXEL,
                             demo_processing.value.products)
    path = write_tile(tmp_path_factory.mktemp("tiles") / "tile_0001.h5", tile, hardware,
                      demo_processing, prods)
    return path, tile, prods


def test_xarray_opens_the_tile_with_dimensions_and_coordinates(tile_file, demo_processing):
    path, tile, prods = tile_file
    g = tile.grid
    with xr.open_dataset(path, engine="h5netcdf") as ds:
        assert dict(ds.sizes) == {"along": 150, "cross": 60, "depth": 50,
                                  "ping_sequence": 33}
        for name, values in zip(DIMS, (g.along, g.cross, g.depth)):
            np.testing.assert_array_equal(ds[name].values, values)
            assert ds[name].attrs["units"] == "m"
        for name in ("image", "background", "drc"):
            assert ds[name].dims == DIMS, name
        np.testing.assert_array_equal(ds.image.values, tile.image)
        assert "magnitude" not in ds          # |image|, not written twice (issue 32)
        np.testing.assert_array_equal(ds.background.values, prods.background)
        # drc is stored as 8 bits with a CF scale_factor that xarray decodes
        np.testing.assert_allclose(ds.drc.values, prods.drc, atol=0.5 / 255 + 1e-7)
        assert ds.mip_depth.dims == ("along", "cross")
        assert ds.mip_cross.dims == ("along", "depth")
        assert ds.mip_along.dims == ("cross", "depth")
        np.testing.assert_array_equal(ds.mip_depth.values, prods.mips["mip_depth"])
        assert ds.depth_gain_db.dims == ("depth",)
        np.testing.assert_array_equal(ds.ping_sequence.values, np.arange(7, 40))
        # the pings' track: CF times decoded to datetime64, positions in metres
        assert ds.ping_time.dims == ("ping_sequence",)
        assert ds.ping_time.dtype == np.dtype("datetime64[ns]")
        np.testing.assert_array_equal(ds.ping_time.values.astype(np.int64),
                                      [t for t, _, _ in tile.track])
        np.testing.assert_array_equal(ds.ping_north_m.values, [n for _, n, _ in tile.track])
        assert ds.ping_east_m.attrs["units"] == "m"
        assert ds.attrs["run_id"] == "line3"
        # selecting by coordinate works in metres
        v = ds.image.sel(along=g.along[40], cross=g.cross[15], depth=g.depth[12])
        assert complex(v) == tile.image[40, 15, 12]
        assert ds.attrs["tile_index"] == 1
        assert ds.attrs["processing_config_id"] == demo_processing.id
    with xr.open_dataset(path, engine="h5netcdf", group="detections") as det:
        assert dict(det.sizes) == {"detection": len(prods.detections)}
        for name in prods.detections.dtype.names:
            np.testing.assert_array_equal(det[name].values, prods.detections[name])
        assert det.attrs["threshold_db"] == demo_processing.value.products.detection.threshold_db
    with xr.open_dataset(path, engine="h5netcdf", group="provenance") as prov:
        assert str(prov.processing_config_toml.values) == demo_processing.text


def test_read_tile_round_trip(tile_file, planted, hardware, demo_processing):
    path, tile, prods = tile_file
    t = read_tile(path)
    np.testing.assert_array_equal(t["image"], tile.image)
    np.testing.assert_array_equal(t["magnitude"], np.abs(tile.image))
    np.testing.assert_array_equal(t["background"], prods.background)
    same_table(t["detections"], prods.detections)
    assert t["hardware_config_toml"] == hardware.text
    assert t["attrs"]["n_detections"] == len(prods.detections) == 2
    _, targets = planted
    found = np.stack([t["detections"][k] for k in ("along_m", "cross_m", "depth_m")], 1)
    for target in targets:
        assert np.min(np.max(np.abs(found - target), axis=1)) <= 0.5 * VOXEL


def test_tile_header_is_the_tile_without_its_volumes(tile_file, hardware, demo_processing):
    path, tile, prods = tile_file
    full, head = read_tile(path), read_tile_header(path)
    for k in ("image", "magnitude", "background", "drc", "depth_gain_db", "mip_depth"):
        assert k in full and k not in head, k
    for k, v in head.items():
        if k in ("attrs", "background_attrs"):
            assert v.keys() == full[k].keys()
            for name, value in v.items():
                np.testing.assert_array_equal(value, full[k][name])
        elif isinstance(v, np.ndarray) and v.dtype.names:
            same_table(v, full[k])
        elif isinstance(v, np.ndarray):
            np.testing.assert_array_equal(v, full[k])
        else:
            assert v == full[k], k
    for name, values in zip(DIMS, (tile.grid.along, tile.grid.cross, tile.grid.depth)):
        np.testing.assert_array_equal(head[name], values)
    np.testing.assert_array_equal(head["ping_sequence"], np.arange(7, 40))
    assert head["products"] == ["background", "drc", "mip_depth", "mip_cross", "mip_along",
                                "detections"]
    assert list(head["background_attrs"]["background_kernel_voxels"]) == [61, 11, 5]
    assert head["processing_config_toml"] == demo_processing.text
    assert head["hardware_config_toml"] == hardware.text
    table, attrs = read_detections(path)
    same_table(table, prods.detections)
    assert attrs["tile_index"] == 1 and attrs["svss_format"] == TILE_FORMAT


def test_tile_readers_refuse_other_files_naming_them(tile_file, tmp_path):
    path, _, _ = tile_file
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"not hdf5" * 10)
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f.attrs["svss_format"] = "something-else"
    future = tmp_path / "future.h5"
    future.write_bytes(path.read_bytes())
    with h5py.File(future, "a") as f:
        f.attrs["svss_format_version"] = 999
    for read in (read_tile, read_tile_header, read_detections):
        with pytest.raises(ValueError, match="junk.h5: not a readable HDF5 file"):
            read(junk)
        with pytest.raises(ValueError, match="other.h5: root attribute 'svss_format' is "
                                             "'something-else'"):
            read(other)
        with pytest.raises(ValueError, match="future.h5: svss_format_version 999"):
            read(future)


def test_tile_without_products(planted, hardware, demo_processing, tmp_path):
    tile, _ = planted
    path = write_tile(tmp_path / "bare.h5", tile, hardware, demo_processing)
    with xr.open_dataset(path, engine="h5netcdf") as ds:
        assert ds.image.dims == DIMS and "background" not in ds
    t = read_tile(path)
    assert len(t["detections"]) == 0 and not t["attrs"]["has_products"]


def test_save_tile_writes_tile_and_quicklook(planted, hardware, demo_processing, tmp_path):
    tile, _ = planted
    h5, png = save_tile(tile, tmp_path, hardware, demo_processing)
    assert h5.name == "tile_0001.h5" and png.name == "tile_0001_mip.png"
    assert len(read_tile(h5)["detections"]) == 2
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    img = matplotlib.image.imread(png)
    assert img.ndim == 3 and img.shape[0] > 400 and img.std() > 0.05
    # without the volumes: projections and detections only
    text = demo_processing.text.replace("store_volumes = true", "store_volumes = false")
    lean = loaded_from_text(ProcessingConfig, text, "lean")
    h5, _ = save_tile(tile, tmp_path / "lean", hardware, lean)
    t = read_tile(h5)
    assert "background" not in t and "drc" not in t and "mip_depth" in t
    assert len(t["detections"]) == 2
    # a processing configuration without [products]: image only, peak-relative MIPs
    text = demo_processing.text.split("\n[products]")[0]
    bare = loaded_from_text(ProcessingConfig, text, "no-products")
    assert bare.value.products is None
    h5, png = save_tile(tile, tmp_path / "bare", hardware, bare)
    assert not read_tile(h5)["attrs"]["has_products"] and png.stat().st_size > 0
