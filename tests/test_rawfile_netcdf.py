"""Raw runs (format version 2) open as netCDF-4 in xarray: named dimensions (no
``phony_dim_*``), CF time units decoded to datetime64, units and long names on every
variable, the run's attributes on the root; version-1 runs still read."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from svss_daq.rawfile import (FORMAT_VERSION, TIME_UNITS, RawFileError, RawRunReader,
                              RawRunWriter)
from tests.test_messages import assert_same
from tests.test_rawfile import _ping_for

xr = pytest.importorskip("xarray")
pytest.importorskip("h5netcdf")


@pytest.fixture
def run(tmp_path, hardware):
    """A real raw run of 4 pings with one record of each kind."""
    path = tmp_path / "run.h5"
    sent = [_ping_for(hardware, i) for i in range(4)]
    with RawRunWriter(path, hardware, environment={"sound_speed_indicative": 1480.0},
                      run_attrs={"run_id": "line7", "segment": 0}) as w:
        for p in sent:
            w.append(p)
        w.append_nmea(1_700_000_000_000_000_001, "$GPHDT,12.5,T*03")
        w.append_pd0(1_700_000_000_500_000_000, b"\x7f\x7f\x06\x00ab")
        w.append_clock_reference(1_700_000_000_600_000_000, 1_700_000_000_590_000_000)
        w.append_event(1_700_000_000_700_000_000, "digitiser.reconnect", "link back")
    return path, sent


def test_raw_run_opens_in_xarray_with_times_dimensions_and_units(run, hardware):
    path, sent = run
    tree = xr.open_datatree(path, engine="h5netcdf")
    try:
        root = tree.to_dataset()
        assert root.attrs["run_id"] == "line7" and root.attrs["svss_format_version"] == 2
        assert root.attrs["sonar_convention_name"] == "SONAR-netCDF4"
        assert root.attrs["sonar_convention_version"] == "2.0"
        assert root.attrs["hardware_config_id"] == hardware.id
        checked = 0
        for node in tree.subtree:
            ds = node.to_dataset()
            for dim in ds.dims:
                assert not str(dim).startswith("phony_dim"), (node.path, dim)
            for name, var in ds.variables.items():
                where = f"{node.path}/{name}"
                units = var.attrs.get("units", var.encoding.get("units"))
                assert units, f"{where}: no units"
                assert var.attrs.get("long_name"), f"{where}: no long_name"
                if var.dtype.kind == "M":            # decoded: CF units on the file
                    assert var.encoding["units"] == TIME_UNITS, where
                checked += 1
        assert checked > 30
        beam = tree["Sonar/Beam_group1"].to_dataset()
        assert beam["backscatter_r"].dims == ("ping_time", "beam", "sample")
        assert beam["backscatter_r"].shape == (4, 80, 1500)
        assert beam["ping_time"].dtype == np.dtype("datetime64[ns]")
        np.testing.assert_array_equal(beam["ping_time"].values.astype(np.int64),
                                      [p.transmit_time_ns for p in sent])
        np.testing.assert_array_equal(beam["backscatter_r"].values[2], sent[2].samples)
        assert beam["window_start_ns"].attrs["units"] == "ns"
        plat = tree["Platform"].to_dataset()
        assert plat["north_m"].dims == ("time1",) and plat["north_m"].attrs["units"] == "m"
        assert plat["heading_rad"].attrs["units"] == "rad"
        assert plat["latitude_deg"].attrs["units"] == "degrees_north"
        assert plat["latitude_deg"].attrs["standard_name"] == "latitude"
        assert plat["longitude_deg"].attrs["standard_name"] == "longitude"
        assert plat["roll_rad"].attrs["standard_name"] == "platform_roll"
        np.testing.assert_array_equal(plat["time1"].values.astype(np.int64),
                                      [p.nav.time_ns for p in sent])
        # every other time variable is decoded too
        for group, name, ns in (("Platform/NMEA", "time", 1_700_000_000_000_000_001),
                                ("Platform/PD0", "time", 1_700_000_000_500_000_000),
                                ("Platform/ping_clock", "receive_time",
                                 1_700_000_000_600_000_000),
                                ("Platform/ping_clock", "transmit_time",
                                 1_700_000_000_590_000_000),
                                ("Vendor_specific/events", "time",
                                 1_700_000_000_700_000_000)):
            v = tree[group].to_dataset()[name]
            assert v.dtype == np.dtype("datetime64[ns]"), (group, name)
            assert int(v.values.astype(np.int64)[0]) == ns, (group, name)
        assert tree["Platform/PD0"].to_dataset()["stream"].dims == ("stream_byte",)
        # text reads as text, not bytes
        ev = tree["Vendor_specific/events"].to_dataset()
        assert ev["kind"].values.tolist() == ["digitiser.reconnect"]
        assert ev["detail"].values.tolist() == ["link back"]
        assert tree["Platform/NMEA"].to_dataset()["sentence"].values.tolist() == \
            ["$GPHDT,12.5,T*03"]
    finally:
        tree.close()


def _as_version_1(path) -> None:
    """Make a version-2 run a version-1 one: no dimension scales, no CF attributes, the
    datasets version 1 had."""
    added = ("Sonar/Beam_group1/beam", "Sonar/Beam_group1/sample",
             "Sonar/Beam_group1/flush_count", "Platform/PD0/stream_byte")
    with h5py.File(path, "a") as f:
        names = []
        f.visititems(lambda n, o: names.append(n) if isinstance(o, h5py.Dataset) else None)
        for n in names:
            for axis, dim in enumerate(f[n].dims):
                for scale in list(dim.values()):
                    f[n].dims[axis].detach_scale(scale)
        for n in added:
            del f[n]
        for n in set(names) - set(added):
            for k in ("CLASS", "NAME", "units", "standard_name", "calendar", "axis"):
                if k in f[n].attrs:
                    del f[n].attrs[k]
        f.attrs["svss_format_version"] = 1
        f.attrs["Conventions"] = "SONAR-netCDF4-like"


def test_version_1_runs_still_read(run, hardware):
    path, sent = run
    assert FORMAT_VERSION == 2
    _as_version_1(path)
    with h5py.File(path, "r") as f:
        assert not h5py.h5ds.is_scale(f["Sonar/Beam_group1/ping_time"].id)
    with RawRunReader(path) as r:
        assert len(r) == 4 and r.run_id == "line7"
        for a, b in zip(sent, r):
            assert_same(a, b)
        assert r.nmea() == [(1_700_000_000_000_000_001, "$GPHDT,12.5,T*03")]
        assert r.pd0() == [(1_700_000_000_500_000_000, b"\x7f\x7f\x06\x00ab")]
    with h5py.File(path, "a") as f:
        f.attrs["svss_format_version"] = 3
    with pytest.raises(RawFileError, match=r"svss_format_version 3.*\[1, 2\]"):
        RawRunReader(path)
