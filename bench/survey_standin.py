"""Stand-ins for vision.survey.measure_pair in bench_survey_speed until the detectors are merged.

``budget``: the plan's per-pair budget of one core (STANDIN_MS, default 70 ms of process CPU time,
spent in OpenCV filters on the pair), then four fixed fish: a run shows what the survey around the
pipeline costs (reading, decoding, handing frames to workers, outputs) and how it scales on the
cores. ``constant``: the four fish at once, the harness alone.
"""
from __future__ import annotations

import os
import time

import cv2
import numpy as np

from vision.survey_types import FishMeasurement

BUDGET_S = float(os.environ.get("STANDIN_MS", "70")) / 1e3


def constant(left, right, calib, setup, timings=None):
    out = []
    for i in range(4):
        snout = np.array([0.0, 30.0 * i, -800.0])
        fork = snout + np.array([100.0 + 10 * i, 5.0, 0.0])
        px = np.array([[100.0 + i, 200.0], [90.0 + i, 200.0]])
        out.append(FishMeasurement(snout, fork, px, px + 50, 0.9, {"ncc": 0.9}))
    return out


def budget(left, right, calib, setup, timings=None):
    t0 = time.process_time()
    grey = left if left.ndim == 2 else cv2.cvtColor(left, cv2.COLOR_BGR2GRAY)
    while time.process_time() - t0 < BUDGET_S:
        cv2.GaussianBlur(grey, (9, 9), 2.0)
    if timings is not None:
        timings["budget"] = timings.get("budget", 0.0) + time.process_time() - t0
    return constant(left, right, calib, setup, timings)
