"""Frames from real cameras that nobody here rendered: the shared stereo chessboard set (OpenCV's
sample pairs, an office, a person holding a board, no fish). A survey of them, in either setup,
with the species' own setup, reports no fish."""
from __future__ import annotations

import cv2
import pytest

from controller.surveys.species import survey_species
from tests.vision.shared_data import SHARED_DATA, needs_data, require
from vision.chessboard import calibrate_pairs, find_corners
from vision.survey import measure_pair

DATA = SHARED_DATA / "stereo-chessboard"
IMAGES = "real chessboard images"
PATTERN = (9, 6)


@pytest.fixture(scope="module")
def real_pairs():
    require(DATA, IMAGES)
    left = [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted(DATA.glob("left*.jpg"))]
    right = [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted(DATA.glob("right*.jpg"))]
    corners = [[find_corners(img, PATTERN) for img in side] for side in (left, right)]
    calib = calibrate_pairs(*corners, left[0].shape[1::-1], PATTERN, 25.0).calibration
    return list(zip(left, right, strict=True)), calib


@needs_data(DATA, IMAGES)
@pytest.mark.parametrize("setup", ["underwater", "surface"])
def test_real_frames_without_fish_report_none(real_pairs, setup):
    pairs, calib = real_pairs
    species = survey_species("sparus_aurata").setup(setup, None)
    found = {i: [round(m.length_cm, 1) for m in measure_pair(left, right, calib, species)]
             for i, (left, right) in enumerate(pairs)}
    assert not any(found.values()), found
