"""Contacts of one target seen in two tiles merge into one (the run products of a
stopped worker failed with KeyError 'lo' when they did: issue 27, item 9)."""

from __future__ import annotations

import numpy as np

from svss_proc.products.run_products import filter_contacts


def _row(tile: int, along: float, peak_db: float, half: float) -> dict:
    return {"tile": tile, "run_m": np.array([along, 0.1, 0.8]), "peak_db": peak_db,
            "excess_db": peak_db - 10.0, "coverage_pings": 0, "depth_m": 0.8,
            "half": np.array([half, 0.02, 0.02])}


def test_one_target_in_two_tiles_is_one_contact_spanning_both_extents():
    rows = [_row(1, 2.99, 20.0, 0.05), _row(2, 3.01, 17.0, 0.08)]
    out = filter_contacts(rows, None, np.linspace(0.0, 1.0, 11), 0.0, 0.1, 6.0, 0.5,
                          None)
    assert len(out) == 1 and out[0]["n_tiles"] == 2 and out[0]["tile"] == 1
    np.testing.assert_allclose(out[0]["lo"], [2.93, 0.08, 0.78])
    np.testing.assert_allclose(out[0]["hi"], [3.09, 0.12, 0.82])
