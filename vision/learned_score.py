"""The chance an underwater report is right, from the figures its measurement rests on.

The hand-made score (``vision.underwater_score``: a product of terms, each 0..1) weighs every
figure by a guess. This is a logistic model over the same figures, fitted on rendered scenes the
benches never see (seeds 300000+, ``tools/score_data.py``, ``tools/fit_score.py``), each report
labelled right or wrong by the bench's rule (snout and fork within 3 % of a true fish's length
across the line of sight, 10 % along it). Its answer is a probability: a farmer's "keep reports
above 0.5" means what it says on scenes like those.

``FEATURES`` (``features``) documents the inputs: raw figures of ``FishMeasurement.quality`` and the
measured length, each transformed so that a linear model can use it (logs of residuals and of
distances as shares of the length). Shapes: every input (N,), the result (N,).

A richer model gains nothing measurable (2026-12-04, issue 7): on reports of today's pipeline with
its post-filters off (tools/score_data.py, fitted on seeds 300000-300599, 1,265 reports; judged on
300600-300899, 681 reports of 615 fully visible fish), the share of fully visible fish found at
precision 0.95 is 0.472 refitted logistic, 0.46-0.51 gradient-boosted trees (scikit-learn's
HistGradientBoostingClassifier, 7-31 leaves, with and without monotone constraints), and at 0.97
0.35 against 0.22-0.43: within the ~0.03 the 615 fish allow. The ceiling is elsewhere: right
reports of fully visible fish there, kept or not, cover 0.654 of them, so no score reaches recall
0.8; the losses are before it (bench/diag_underwater.py).
"""
from __future__ import annotations

from functools import lru_cache
from importlib import import_module

import numpy as np

MODEL = "vision.models.fish_score"      # written by tools/fit_score.py


def _share(px: np.ndarray, length_px: np.ndarray) -> np.ndarray:
    return np.log1p(50.0 * px / np.maximum(length_px, 1.0))


# name -> transform of the figures (dict of (N,) arrays); a model names the ones it uses
FEATURES = {
    "stereo_ncc": lambda q: q["stereo_ncc"],
    "fork_residual": lambda q: np.log1p(q["fork_residual_px"]),
    "snout_residual": lambda q: np.log1p(q["snout_residual_px"]),
    "tilt": lambda q: q["tilt_deg"] / 10.0,
    "range": lambda q: q["range_mm"] / 1000.0,
    "length_px": lambda q: np.log(np.maximum(q["length_px"], 1.0) / 100.0),
    "fin_ncc": lambda q: q["fin_ncc"],
    "snout_edge": lambda q: np.clip(q["snout_edge"], 0.0, 2.0),
    "body_fill": lambda q: q["body_fill"],
    "fork_epi": lambda q: _share(q["fork_epi_px"], q["length_px"]),
    "snout_epi": lambda q: _share(q["snout_epi_px"], q["length_px"]),
    # the length against the one the fin's size suggests (a snout past the real one, or short of it)
    "body_ratio": lambda q: np.abs(np.log(np.maximum(q["length_mm"], 1e-3) / np.maximum(q["body_length_mm"], 1e-3))),
    "fork_net_conf": lambda q: q["fork_net_conf"],
    "kp_fork_conf": lambda q: q["kp_fork_conf"],
    "kp_snout_agree": lambda q: q["kp_snout_agree"],
    "snout_net_conf": lambda q: q["snout_net_conf"],
    "snout_view": lambda q: q["t_snout_view"],
}


@lru_cache(maxsize=4)
def load(name: str = MODEL) -> dict:
    """The fitted model (a module's ``MODEL``): names, mean, sd, weights, bias, and how it was fitted."""
    return import_module(name).MODEL


def chance(q: dict[str, np.ndarray], model: dict | None = None) -> np.ndarray:
    """(N,) 0..1: the chance each report is right (``q``: its figures, each (N,))."""
    return fitted_chance(q, FEATURES, MODEL if model is None else model)


def features(q: dict[str, np.ndarray], names: list[str], table: dict = FEATURES) -> np.ndarray:
    """(N, len(names)) float64: the named features of ``table`` (name -> transform) of the figures ``q``."""
    return np.stack([np.asarray(table[n](q), float) for n in names], axis=1)


def fitted_chance(q: dict[str, np.ndarray], table: dict, model: dict | str) -> np.ndarray:
    """A logistic model's answer: ``model`` (or the module naming it) over the named features of
    ``table`` (name -> transform of the figures ``q``)."""
    m = load(model) if isinstance(model, str) else model
    x = (features(q, m["names"], table) - np.asarray(m["mean"])) / np.asarray(m["sd"])
    z = x @ np.asarray(m["weights"]) + m["bias"]
    return 1.0 / (1.0 + np.exp(-np.clip(z, -40, 40)))
