"""Chessboard stereo calibration: OpenCV's real sample images (goal check) and rendered boards
through a rig whose geometry we know."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from devices.sim.stereo_scene import board_session
from tests.vision.shared_data import SHARED_DATA, data_status, needs_data, require
from vision.chessboard import (
    BadFit,
    NotEnoughPairs,
    calibrate_pairs,
    consistent_order,
    epipolar_error,
    find_corners,
    reference_stereo_calib,
    square_sizes,
)
from vision.epipolar import fundamental_from_projections

DATA = SHARED_DATA / "stereo-chessboard"
IMAGES = "real chessboard images"
PATTERN = (9, 6)
SQUARE = 27.5          # the board's true size is unknown: calibrate with S, expect S back in 3-D

real_data = needs_data(DATA, IMAGES)     # skip when absent, unless CI / FISHFARM_REQUIRE_DATA: then fail


@pytest.fixture(scope="module")
def real_images():
    require(DATA, IMAGES)
    left = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted(DATA.glob("left*.jpg"))]
    right = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted(DATA.glob("right*.jpg"))]
    return left, right


@pytest.fixture(scope="module")
def real_corners(real_images):
    return [[find_corners(img, PATTERN) for img in side] for side in real_images]


@pytest.fixture(scope="module")
def opencv_figures(real_images):
    return reference_stereo_calib(*real_images, PATTERN)


@pytest.fixture(scope="module")
def ours(real_images, real_corners):
    size = real_images[0][0].shape[::-1]
    return calibrate_pairs(*real_corners, size, PATTERN, SQUARE)


@real_data
def test_reference_reproduces_opencv_sample_figures(opencv_figures):
    # the yardstick itself: the data's README quotes RMS ~0.60 px, epipolar ~0.43 px, 3.34 squares
    assert opencv_figures["pairs"] == 13
    assert opencv_figures["rms_px"] == pytest.approx(0.60, abs=0.02)
    assert opencv_figures["epipolar_px"] == pytest.approx(0.43, abs=0.02)
    assert opencv_figures["baseline_squares"] == pytest.approx(3.34, abs=0.02)


@real_data
def test_goal_epipolar_error_within_5_percent_of_opencv(ours, opencv_figures):
    assert ours.epipolar_px <= 1.05 * opencv_figures["epipolar_px"]


@real_data
def test_goal_square_size_reconstructed_in_3d_within_half_percent(ours):
    sizes = np.concatenate([square_sizes(ours.calibration, a, b, PATTERN)
                            for a, b in zip(ours.corners1, ours.corners2, strict=True)])
    assert len(sizes) == 13 * (8 * 6 + 9 * 5)
    assert abs(np.median(sizes) / SQUARE - 1) <= 0.005


@real_data
def test_all_real_pairs_used_and_agree_with_opencv_on_the_baseline(ours, opencv_figures):
    assert [p.reason for p in ours.pairs] == ["used"] * 13
    assert all(p.rms_px is not None and p.rms_px < 3 * ours.rms_px for p in ours.pairs)
    assert ours.rms_px < opencv_figures["rms_px"]
    # two different procedures on the same images must find the same rig (within 1 %)
    assert ours.baseline_squares == pytest.approx(opencv_figures["baseline_squares"], rel=0.01)


@real_data
def test_projection_matrices_are_camera_1_frame_in_mm(ours):
    c = ours.calibration
    assert np.allclose(c.P1, c.K1 @ np.c_[np.eye(3), np.zeros(3)])
    assert np.allclose(c.P2, c.K2 @ np.c_[c.R, c.T])
    assert np.allclose(c.R @ c.R.T, np.eye(3), atol=1e-9) and np.linalg.det(c.R) == pytest.approx(1)
    assert c.image_size == (640, 480) and len(c.D1) == 5 and c.rms_px == ours.rms_px
    # the written P1/P2 give back the reported epipolar error
    F = fundamental_from_projections(c.P1, c.P2)
    assert epipolar_error(ours.corners1, ours.corners2, c.K1, c.D1, c.K2, c.D2, F) == pytest.approx(
        ours.epipolar_px)


@real_data
def test_a_pair_with_bad_corners_is_rejected_as_outlier(real_images, real_corners):
    left, right = (list(side) for side in real_corners)
    rng = np.random.default_rng(5)
    right[4] = right[4] + rng.normal(0, 3.0, right[4].shape).astype(np.float32)  # a badly detected view
    result = calibrate_pairs(left, right, (640, 480), PATTERN, SQUARE)
    assert not result.pairs[4].used and result.pairs[4].reason.startswith("outlier")
    assert sum(p.used for p in result.pairs) == 12 and len(result.corners1) == 12
    assert result.epipolar_px < 0.3


@pytest.mark.parametrize("environ, expected", [
    ({}, "skip"), ({"CI": "true"}, "skip"), ({"FISHFARM_REQUIRE_DATA": "1"}, "fail"),
    ({"FISHFARM_REQUIRE_DATA": "0"}, "skip"), ({"CI": "false", "FISHFARM_REQUIRE_DATA": ""}, "skip")])
def test_missing_real_data_fails_in_ci_and_skips_elsewhere(tmp_path, environ, expected):
    status, reason = data_status(tmp_path / "absent", environ)
    assert status == expected and str(tmp_path / "absent") in reason
    assert data_status(tmp_path, {"FISHFARM_REQUIRE_DATA": "1"})[0] == "present"


def test_epipolar_error_is_opencv_sum_of_both_distances():
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    P1 = K @ np.c_[np.eye(3), np.zeros(3)]
    P2 = K @ np.c_[np.eye(3), [-100.0, 0, 0]]        # rectified: lines are rows
    F = fundamental_from_projections(P1, P2)
    x1 = np.array([[100.0, 50], [300, 200]])
    x2 = x1 + [[-40, 0.5], [-60, -1.5]]                 # off by 0.5 and 1.5 rows
    assert epipolar_error([x1], [x2], K, None, K, None, F) == pytest.approx((2 * 0.5 + 2 * 1.5) / 2)


def test_consistent_order_reverses_a_board_numbered_from_the_far_corner():
    corners = np.c_[np.tile(np.arange(9.0), 6) * 20, np.repeat(np.arange(6.0), 9) * 20]
    assert np.array_equal(consistent_order(corners, corners + 3), corners + 3)
    assert np.array_equal(consistent_order(corners, corners[::-1] + 3), corners + 3)


def test_too_few_pairs_says_why_for_each():
    c = np.zeros((54, 2), np.float32)
    with pytest.raises(NotEnoughPairs) as err:
        calibrate_pairs([c, None, c, None], [c, c, None, None], (640, 480), PATTERN, 25.0)
    assert [p.reason for p in err.value.pairs] == [
        "used", "board not found in left", "board not found in right", "board not found in both"]
    assert "only 1 of 4" in str(err.value)


# --- rendered boards: the rig is known, so the calibration can be checked against the truth ---

def test_rendered_boards_give_back_the_true_rig_in_mm():
    session = board_session(10, np.random.default_rng(3))
    corners = [[find_corners(img, PATTERN) for img in side] for side in zip(*session.pairs, strict=True)]
    result = calibrate_pairs(*corners, session.image_size, PATTERN, 25.0)
    c = result.calibration
    assert all(p.used for p in result.pairs)
    assert np.linalg.norm(c.T) == pytest.approx(80.0, rel=0.005)
    assert np.linalg.norm(c.T / np.linalg.norm(c.T) - session.T / 80.0) < 0.005
    assert np.degrees(np.linalg.norm(cv2.Rodrigues(c.R @ session.R.T)[0])) < 0.1
    assert np.allclose(c.K1, session.K, atol=3.0) and np.allclose(c.K2, session.K, atol=3.0)
    assert result.rms_px < 0.1 and result.epipolar_px < 0.1


@real_data
def test_real_pairs_fit_their_own_calibration_and_swapped_are_said_swapped(real_images, ours):
    """vision.pair_fit on real cameras: the board pairs against the calibration made from them."""
    from vision.pair_fit import pair_fit, verdict
    pairs = list(zip(*real_images, strict=True))[:5]
    fit = pair_fit(pairs, ours.calibration)
    assert fit.judged and fit.epipolar_px < 1.0 and fit.in_front > 0.9 and verdict(fit) is None
    swapped = pair_fit([(r, left) for left, r in pairs], ours.calibration)
    assert swapped.in_front < 0.1 and "look swapped" in verdict(swapped)


@pytest.mark.parametrize("mixed", [(2, 5), (1, 4, 7)])
def test_pairs_of_different_moments_are_left_out_and_the_rig_is_the_true_one(mixed):
    """Two right views put with the wrong left ones: the joint fit spread their error over every
    pair (5-26 px each), the RMS test saw no outlier, and a 300 mm baseline for a 120 mm rig was
    written at exit 0 (outside tester)."""
    session = board_session(10, np.random.default_rng(3))
    left, right = (list(side) for side in zip(*session.pairs, strict=True))
    for a, b in zip(mixed, mixed[1:] + mixed[:1], strict=True):     # each takes the next one's view
        right[a] = session.pairs[b][1]
    corners = [[find_corners(img, PATTERN) for img in side] for side in (left, right)]
    result = calibrate_pairs(*corners, session.image_size, PATTERN, 25.0)
    assert [i for i, p in enumerate(result.pairs) if not p.used] == sorted(mixed)
    assert all(result.pairs[i].reason.startswith("not one moment") for i in mixed)
    c = result.calibration
    assert np.linalg.norm(c.T) == pytest.approx(80.0, rel=0.005)
    assert np.allclose(c.K1, session.K, atol=3.0) and np.allclose(c.K2, session.K, atol=3.0)


def test_views_that_fit_no_rig_are_no_calibration():
    """Every right view a mirrored left one (another board, not the same moment seen twice)."""
    session = board_session(8, np.random.default_rng(4))
    left = [pair[0] for pair in session.pairs]
    corners = [[find_corners(img, PATTERN) for img in side] for side in (left, [img[:, ::-1] for img in left])]
    with pytest.raises((NotEnoughPairs, BadFit)):
        calibrate_pairs(*corners, session.image_size, PATTERN, 25.0)


@real_data
def test_real_pairs_mixed_up_are_left_out(real_images, real_corners, ours):
    left, right = (list(side) for side in real_corners)
    right[2], right[5] = real_corners[1][3], real_corners[1][6]     # right03, right06 -> right04, right07
    result = calibrate_pairs(left, right, (640, 480), PATTERN, SQUARE)
    assert [i for i, p in enumerate(result.pairs) if not p.used] == [2, 5]
    assert np.linalg.norm(result.calibration.T) == pytest.approx(np.linalg.norm(ours.calibration.T), rel=0.005)
