"""The across-track aspect (issue 51; docs/contact_features.md): the along-track
measurement on the image with its along- and cross-track axes swapped, so a response
whose angular spectrum lies across-track reads there what it would read along-track."""

from __future__ import annotations

import numpy as np

from svss_proc.products.contact_features import contact_features

from .test_contact_features import ASPECT_CFG, K_W, aperture_image, axes


def test_the_across_track_aspect_is_the_along_track_one_of_the_swapped_image():
    img, row = aperture_image(np.random.default_rng(7), 0.0, 6.0, shape=(90, 90, 40),
                              at=(0.9, 0.7, 0.4))
    level = (20 * np.log10(np.abs(img) / 1e-3)).astype(np.float32)
    before = row.copy()
    f = contact_features(level, axes(img.shape), row, ASPECT_CFG, img, K_W).columns
    assert row.tobytes() == before.tobytes()          # the table is left as it was
    # the same response turned across-track
    img_t = np.ascontiguousarray(np.transpose(img, (1, 0, 2)))
    row_t = row.copy()
    row_t["along_m"], row_t["cross_m"] = row["cross_m"], row["along_m"]
    g = contact_features(np.ascontiguousarray(np.transpose(level, (1, 0, 2))),
                         axes(img_t.shape), row_t, ASPECT_CFG, img_t, K_W).columns
    assert np.isfinite(f["aspect_width_deg"][0]) and f["aspect_width_deg"][0] > 5.0
    assert g["aspect_cross_width_deg"][0] == f["aspect_width_deg"][0]
    assert g["aspect_cross_width_err_deg"][0] == f["aspect_width_err_deg"][0]
    assert g["aspect_width_deg"][0] == f["aspect_cross_width_deg"][0]
    # no complex image: not measured
    h = contact_features(level, axes(img.shape), row, ASPECT_CFG).columns
    assert np.isnan(h["aspect_cross_width_deg"][0])
