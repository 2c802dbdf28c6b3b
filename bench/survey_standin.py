"""Stand-ins for vision.survey.measure_pair in bench_survey_speed until the detectors are merged.

``budget``: the plan's per-pair budget of one core (STANDIN_MS, default 70 ms of process CPU time,
spent in OpenCV filters on the pair) plus the dot reader of the tests, so a run shows what the
survey around the pipeline costs and how it scales on the cores. ``dots`` alone: the harness cost.
"""
from __future__ import annotations

import os
import time

import cv2

from tests.controller.surveys.standin import dots

BUDGET_S = float(os.environ.get("STANDIN_MS", "70")) / 1e3


def budget(left, right, calib, setup, timings=None):
    t0 = time.process_time()
    grey = left if left.ndim == 2 else cv2.cvtColor(left, cv2.COLOR_BGR2GRAY)
    while time.process_time() - t0 < BUDGET_S:
        cv2.GaussianBlur(grey, (9, 9), 2.0)
    if timings is not None:
        timings["budget"] = timings.get("budget", 0.0) + time.process_time() - t0
    return dots(left, right, calib, setup, timings)


__all__ = ["budget", "dots"]
