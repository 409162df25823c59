"""Hypothesis settings of the stability suite.

The default run keeps every sweep small (the whole suite in about 20 s);
``test_extended.py`` (``-m extended``) reruns the suite in a subprocess with
``SVSS_STABILITY_SCALE`` times as many examples. Examples are derandomised so that a
failure is reproducible from the test name alone.
"""

from __future__ import annotations

import os

from hypothesis import HealthCheck, settings

SCALE = max(1, int(os.environ.get("SVSS_STABILITY_SCALE", "1")))


def sweep(n: int) -> settings:
    """Settings for a sweep of ``n`` examples (times the scale), no deadline."""
    return settings(max_examples=n * SCALE, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow])
