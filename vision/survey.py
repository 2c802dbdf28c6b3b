"""One stereo pair in, the fish measured in it out: the survey's per-pair pipeline, dispatched by
setup. Pure computation; reading frames, config and writing results is the command line's job."""
from __future__ import annotations

import cv2
import numpy as np

from vision.calib_file import StereoCalibration
from vision.survey_types import FishMeasurement, SurveySetup, plain_image


def measure_pair(left: np.ndarray, right: np.ndarray, calib: StereoCalibration, setup: SurveySetup,
                 timings: dict[str, float] | None = None) -> list[FishMeasurement]:
    """Fish measured in one synchronised pair (grey (H, W) or BGR (H, W, 3) uint8, same size).

    ``timings``, if given, receives seconds spent per stage (added to what it holds)."""
    if left.shape[:2] != right.shape[:2]:
        raise ValueError(f"left and right images differ in size: {left.shape[:2]} vs {right.shape[:2]}")
    left, right = same_kind(left, right)
    if setup.setup == "underwater":
        from vision.underwater import measure_underwater
        return measure_underwater(left, right, calib, setup, timings)
    if setup.setup == "surface":
        from vision.surface import measure_surface
        return measure_surface(left, right, calib, setup, timings)
    raise ValueError(f"unknown setup {setup.setup!r}")


def same_kind(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pair as two images of one kind: where one camera gives grey and the other colour (a mono
    and a colour camera, or one view saved as grey), both are measured grey -- patches compared
    across the views must have the same channels."""
    left, right = plain_image(left), plain_image(right)
    if left.ndim == right.ndim:
        return left, right
    return _grey(left), _grey(right)


def _grey(img: np.ndarray) -> np.ndarray:
    return img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
