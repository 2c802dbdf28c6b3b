"""The chance a surface-setup report is right, from the figures its measurement rests on.

The surface pipeline's hand-made score (``vision.surface``: a product of terms) hardly ranks its
reports: on rendered tanks its precision is ~0.8 whatever the cut. This is a logistic model over
the same figures (``FishMeasurement.quality``), fitted on rendered tanks the benches never see
(seeds 8000+, ``tools/surface_score_data.py``, ``tools/fit_score.py --setup surface``), each report
labelled right or wrong by the bench's rule (each end within 3 % of the true length across camera
1's line of sight, 10 % along it). Its answer is a probability. Lengths in mm are left out: a model
of which fish are right must not prefer a size.

Shapes: every input (N,), the result (N,).
"""
from __future__ import annotations

import numpy as np

from vision.learned_score import fitted_chance

MODEL = "vision.models.surface_score"      # written by tools/fit_score.py --setup surface

# name -> transform of the figures (dict of (N,) arrays); a model names the ones it uses
FEATURES = {
    "q_epipolar": lambda q: q["q_epipolar"],
    "q_tilt": lambda q: q["q_tilt"],
    "q_straight": lambda q: q["q_straight"],
    "q_head": lambda q: q["q_head"],
    "q_fork": lambda q: q["q_fork"],
    "q_fork_views": lambda q: q["q_fork_views"],
    "q_glare": lambda q: q["q_glare"],
    "q_views": lambda q: q["q_views"],
    "q_match": lambda q: q["q_match"],
    "epipolar": lambda q: np.log1p(q["epipolar_px"]),
    "mid_epipolar": lambda q: np.log1p(q["mid_epipolar_px"]),
    "tilt": lambda q: np.log1p(np.abs(q["tilt_deg"])),
    "straightness": lambda q: q["straightness"],
    "head_conf": lambda q: q["head_conf"],
    "ncc_snout": lambda q: q["ncc_snout"],
    "ncc_fork": lambda q: q["ncc_fork"],
    "fork_depth": lambda q: q["fork_depth"],
    "length_px": lambda q: np.log(np.maximum(q["length_px"], 1.0) / 100.0),
    "fork_gap": lambda q: np.log1p(50.0 * q["fork_gap"]),
}


def chance(q: dict[str, np.ndarray], model: dict | None = None) -> np.ndarray:
    """(N,) 0..1: the chance each report is right (``q``: its figures, each (N,))."""
    return fitted_chance(q, FEATURES, MODEL if model is None else model)
