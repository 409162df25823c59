"""Each contact called man-made, natural or undecided from its features (issue 51;
docs/classification.md).

The model is a logistic regression on a few of the contact's features
(:mod:`.contact_features`), each standardised by the mean and standard deviation of the
training contacts::

    z_i = (x_i - mean_i) / scale_i
    p_manmade = 1 / (1 + exp(-(intercept + sum_i coefficients_i z_i)))

so each coefficient is the change in the log-odds of man-made per standard deviation of
its feature, readable as it stands: a positive weight on ``aspect_width_deg`` says that a
response seen over more of the aperture (a sphere, a cylinder's round side) is more
likely man-made than one seen only near a face's normal (a flat rock). Every number is
in the configuration (``[products.classify]``), fitted by
``benchmarks/fit_classifier.py`` on simulated training fields apart from the test
fields.

A contact is **man-made** where ``p_manmade > manmade_above``, **natural** where
``p_manmade < natural_below``, **undecided** between them, and undecided too (its
probability NaN) where one of its features is not a number or its ``feature_flags``
carry one of ``undecided_flags`` (or are -1: features not measured).

A run's contacts are called again at its end (:func:`call_with_pings`) where the
recorded pings' own features were measured (``svss process``;
:mod:`.contact_spectra`), by a second model of the same form that may use them
(``[products.classify_pings]``); the others keep the image's call.

Pure functions of arrays; ``cfg`` is a :class:`svss_daq.config.ClassifyConfig` (or its
:class:`~svss_daq.config.PingClassifyConfig`).
"""

from __future__ import annotations

import numpy as np

from svss_daq.config_processing import PING_FEATURES

#: the ``class`` column's codes
MANMADE, NATURAL, UNDECIDED, NOT_CLASSIFIED = 1, 0, -1, -2
CLASS_TEXT = {MANMADE: "man-made", NATURAL: "natural", UNDECIDED: "undecided",
              NOT_CLASSIFIED: ""}

#: detection-table columns of the classification: (name, dtype, units, meaning), as
#: :data:`svss_proc.products.detect.FIELDS`
CLASS_FIELDS = (
    ("class", "i1", "1", ("1 man-made, 0 natural, -1 undecided (probability between the "
                          "thresholds, a feature missing or flagged), -2 not classified")),
    ("p_manmade", "f4", "1", ("probability that the contact is man-made, from its features "
                              "(logistic regression, [products.classify]; NaN: not "
                              "classified, or a feature missing)")),
)
CLASS_NAMES = tuple(name for name, *_ in CLASS_FIELDS)
#: fill values (a tile written before the columns, or without ``[products.classify]``)
CLASS_FILL = {"class": NOT_CLASSIFIED, "p_manmade": np.nan}


def class_text(code: int) -> str:
    """A ``class`` code in words ('' for not classified)."""
    return CLASS_TEXT.get(int(code), "")


def logistic(t: np.ndarray) -> np.ndarray:
    """1 / (1 + exp(-t)), without overflow for large |t|."""
    t = np.asarray(t, dtype=np.float64)
    out = np.empty_like(t)
    pos = t >= 0
    out[pos] = 1.0 / (1.0 + np.exp(-t[pos]))
    e = np.exp(t[~pos])
    out[~pos] = e / (1.0 + e)
    return out


def probability(x: np.ndarray, cfg) -> np.ndarray:
    """p_manmade of feature rows ``x`` (n, k: ``cfg.features`` in order); NaN where a
    feature is NaN."""
    x = np.asarray(x, dtype=np.float64).reshape(-1, len(cfg.features))
    z = (x - np.asarray(cfg.mean)) / np.asarray(cfg.scale)
    return logistic(cfg.intercept + z @ np.asarray(cfg.coefficients, dtype=np.float64))


def decide(p: np.ndarray, cfg) -> np.ndarray:
    """``class`` codes of probabilities ``p``: man-made above ``manmade_above``,
    natural below ``natural_below``, undecided between them or where p is NaN."""
    p = np.asarray(p, dtype=np.float64)
    out = np.full(p.shape, UNDECIDED, dtype=np.int8)
    with np.errstate(invalid="ignore"):
        out[p > cfg.manmade_above] = MANMADE
        out[p < cfg.natural_below] = NATURAL
    return out


def feature_matrix(detections: np.ndarray, cfg) -> np.ndarray:
    """The model's features of each detection (n, k), NaN where a detection's
    ``feature_flags`` are -1 (not measured) or carry one of ``cfg.undecided_flags``."""
    n = len(detections)
    names = detections.dtype.names or ()
    x = np.full((n, len(cfg.features)), np.nan)
    for j, name in enumerate(cfg.features):
        if name in names:
            x[:, j] = detections[name]
    if "feature_flags" in names:
        flags = np.asarray(detections["feature_flags"], dtype=np.int64)
        mask = 0
        for bit in cfg.undecided_flags:
            mask |= int(bit)
        x[(flags < 0) | ((flags & mask) != 0)] = np.nan
    else:
        x[:] = np.nan
    return x


def classify(detections: np.ndarray, cfg) -> tuple[np.ndarray, np.ndarray]:
    """(``class`` codes int8, ``p_manmade`` float32) of each detection of a table with
    the feature columns (:data:`svss_proc.products.detect.DTYPE`)."""
    x = feature_matrix(detections, cfg)
    p = probability(x, cfg) if len(x) else np.zeros(0)
    p[~np.all(np.isfinite(x), axis=1)] = np.nan
    return decide(p, cfg), p.astype(np.float32)


def with_class(detections: np.ndarray, cfg) -> np.ndarray:
    """A copy of ``detections`` with its ``class`` and ``p_manmade`` columns set."""
    out = detections.copy()
    cls, p = classify(out, cfg)
    out["class"], out["p_manmade"] = cls, p
    return out


#: ``class_from`` of a contact: which model called it
FROM_IMAGE, FROM_PINGS = "image", "image and pings"


def call_with_pings(contacts: list[dict], cfg) -> int:
    """Call again, in place, each run contact (a dict with the feature columns,
    ``feature_flags``, ``class`` as text, ``p_manmade``) whose ping features
    (those of ``cfg.features`` in ``PING_FEATURES``) were all measured: its ``class``,
    ``p_manmade`` and ``class_from`` from the run-level model ``cfg``. Returns how many
    were called."""
    ping = [n for n in cfg.features if n in PING_FEATURES]
    chosen = [c for c in contacts if ping and all(np.isfinite(_number(c.get(n)))
                                                  for n in ping)]
    if not chosen:
        return 0
    table = np.zeros(len(chosen), dtype=[(n, "f8") for n in cfg.features]
                     + [("feature_flags", "i8")])
    for i, c in enumerate(chosen):
        for n in cfg.features:
            table[n][i] = _number(c.get(n))
        table["feature_flags"][i] = int(c.get("feature_flags", -1))
    codes, p = classify(table, cfg)
    for c, code, pi in zip(chosen, codes, p):
        c.update({"class": class_text(code), "class_from": FROM_PINGS,
                  "p_manmade": round(float(pi), 3) if np.isfinite(pi) else float("nan")})
    return len(chosen)


def _number(v) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return float("nan")


#: ``class`` codes by their text (the contacts files')
CLASS_CODE = {text: code for code, text in CLASS_TEXT.items()}
