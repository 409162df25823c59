"""The seed's simulation results, measured from simulated images (issue 18; PHYSICS.md
section 8; docs/reproduce.md).

One session-scoped simulation per sediment, of only the pings whose projector cone
reaches the buried cylinder (its full synthetic aperture: 42 pings in sand, 38 in silt),
with the paper-era array (32 channels) and the cylinder's axis along the track: the
configuration the report argues is the seed's (svss.reproduce.run.SEED_CONFIG). Both at
1 scatterer per resolution cell (the command's --quick setting; the scene files have 2,
docs/simulator_speed.md: level, profile and background at the target within the statistical
floor of another seabed) to keep the default run within its time budget. The sand case
runs through the command's own ``measure_case``; the silt case images its target region
only.
"""

from __future__ import annotations

import pytest

from svss.reproduce import image, measures, run, scenes
from svss.reproduce.scenes import Variant

SEED = run.SEED_CONFIG


@pytest.fixture(scope="session")
def sand():
    res, _ = run.measure_case(run.Case(SEED["array"], "sand",
                                       Variant(axis=SEED["axis"], per_cell=1.0)), quick=True)
    return res


@pytest.fixture(scope="session")
def silt():
    src = scenes.source(SEED["array"], "silt", Variant(axis=SEED["axis"], per_cell=1.0))
    tgt = src.scene.targets[0]
    region = run.regions(tgt, quick=True, figure=False)["target"]
    vols, _ = image.image_regions(src, run.case_pings(src, tgt), {"target": region}, "silt")
    v = vols["target"]
    centre = (tgt.along_m, tgt.cross_m, tgt.depth_m)
    return {"excess_db": measures.target_excess(v.image, v.axes, v.voxel, centre).excess_db,
            "surround_excess_db": measures.surround_excess(v.image, v.axes,
                                                           centre).excess_db}


@pytest.mark.slow
def test_sand_first_order_multipath_from_the_image(sand):
    assert sand["first"] is not None, sand["features"]
    assert abs(sand["first"]["depth"] - 0.6) <= 0.05


def test_sand_second_order_multipath_from_the_image(sand):
    assert sand["second"] is not None, sand["features"]
    # the feature found in the image is the 5 m path's: where the path arithmetic
    # (PHYSICS.md section 8, 2.945 m), which the imaging never used, puts it
    expected = measures.multipath_depth_expected(5.0, sand["water_speed"],
                                                 sand["sediment_speed"])
    assert abs(sand["second"]["depth"] - expected) <= 0.02
    # and within the 5 cm of the seed's "2.9 m" the issue asks for: on this fixed seabed
    # 2.945 m; over other seabeds the feature spreads over 2.944-2.953 m, up to 5.3 cm
    # from 2.9 m, i.e. the seed's figure reads as 2.945 m rounded (docs/reproduce.md)
    assert abs(sand["second"]["depth"] - 2.9) <= 0.05


def test_sand_excess_as_the_seed(sand):
    lo, hi = 10.0, 11.0
    x = sand["excess_db"]
    assert lo - 2.0 <= x <= hi + 2.0, x
    # the peak is the cylinder's: its top, within a voxel plus its radius of its centre
    assert abs(sand["peak"][2] - (1.0 - 0.1575)) <= 0.05


@pytest.mark.slow
def test_silt_excess_higher_than_sand(sand, silt):
    assert silt["excess_db"] > sand["excess_db"], (silt, sand["excess_db"])
    # over the surroundings (which the products' window does not guarantee for a
    # cylinder along the track) silt's target stands far clearer, as the seed says
    assert silt["surround_excess_db"] > sand["surround_excess_db"] + 10.0, (
        silt, sand["surround_excess_db"])
