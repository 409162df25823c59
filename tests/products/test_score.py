"""Scoring detections against ground truth (:func:`svss.score.score`, the ``svss`` tool's;
the ``svss score`` command on tile files is tested in test_cli.py)."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from svss.score import Score, score

ROOT = Path(__file__).resolve().parents[2]


def test_score_counts_hits_misses_false_alarms_and_duplicates():
    truth = np.array([[0.0, 0.0, 0.5], [2.0, 0.1, 0.3], [4.0, -0.2, 0.7]])
    dets = np.array([[0.05, 0.0, 0.5],     # hits truth 0
                     [2.0, 0.12, 0.35],    # hits truth 1
                     [2.1, 0.1, 0.3],      # near truth 1, already taken: duplicate
                     [3.0, 0.0, 0.5]])     # near nothing: false alarm
    s = score(dets, truth, radius_m=0.3)
    assert sorted((t, d) for t, d, _ in s.pairs) == [(0, 0), (1, 1)]
    assert s.missed == [2] and s.false_alarms == [3] and s.duplicates == [2]
    assert s.summary() == {"truth": 3, "detections": 4, "hits": 2, "misses": 1,
                           "false_alarms": 1, "duplicates": 1,
                           "probability_of_detection": pytest.approx(2 / 3)}
    # one detection between two targets detects only the nearer one
    s = score(np.array([[1.0, 0.0, 0.0]]), np.array([[0.8, 0, 0], [1.25, 0, 0]]), 0.3)
    assert [(t, d) for t, d, _ in s.pairs] == [(0, 0)] and s.missed == [1]
    s = score(np.zeros((0, 3)), np.zeros((0, 3)), 0.3)
    assert s.hits == 0 and s.summary()["probability_of_detection"] is None


def test_a_contact_on_an_objects_extent_is_that_object():
    """A cylinder 61 cm long, 31.5 cm across: its top and its end are that cylinder, not
    false alarms; a point's radius stays the radius."""
    truth = np.array([[10.0, 0.0, 1.0], [14.0, 0.0, 0.6]])
    extents = np.array([0.305, 0.0])
    dets = np.array([[10.0, -0.1, 0.71],    # the cylinder's top, 0.31 m from its centre
                     [10.0, 0.33, 1.0],     # its end
                     [14.0, 0.0, 1.0]])     # 0.4 m under the point
    s = score(dets, truth, 0.3, extents)
    assert [(t, d) for t, d, _ in s.pairs] == [(0, 0)] and s.duplicates == [1]
    assert s.missed == [1] and s.false_alarms == [2]
    s = score(dets, truth, 0.3)                       # as points: the top is too far
    assert [(t, d) for t, d, _ in s.pairs] == [] and s.false_alarms == [0, 1, 2]


def test_scoring_lives_with_the_truth_not_in_the_imager():
    """``svss_proc`` compares nothing with ground truth: no module of it defines a
    score (the ``svss`` tool, which reads the truth, does)."""
    assert Score.__module__ == score.__module__ == "svss.score"
    for f in sorted((ROOT / "svss_proc").rglob("*.py")):
        names = {n.name.lower() for n in ast.walk(ast.parse(f.read_text()))
                 if isinstance(n, (ast.FunctionDef, ast.ClassDef))}
        assert "score" not in names, f.relative_to(ROOT)
