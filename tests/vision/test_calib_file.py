"""CALIB.json's content, decoded: every fault names its field, as vision's own ValueError."""
import json
import re

import numpy as np
import pytest

from tests.vision.calib_cases import CASES, FULL, GOOD, message_pattern
from vision.calib_file import CalibrationError, StereoCalibration, calibration_from_json

DECODED = [(case, json.loads(text), message) for case, text, message in CASES if case != "not_json"]


@pytest.mark.parametrize("case, data, message", DECODED, ids=[c[0] for c in DECODED])
def test_a_bad_calibration_is_refused_naming_its_field(case, data, message):
    with pytest.raises(CalibrationError) as err:
        calibration_from_json(data)
    assert isinstance(err.value, ValueError)
    assert re.fullmatch(message_pattern(case, message), str(err.value)), str(err.value)
    field, _, fault = message.partition(": ") if case != "not_an_object" else (None, "", message)
    assert err.value.field == field
    assert re.fullmatch(message_pattern(case, fault), err.value.fault), err.value.fault


def test_a_full_calibration_goes_through_json_unchanged():
    data = FULL | {"R": np.eye(3).tolist(), "T": [-100.0, 0.0, 0.0], "image_size": [640, 480], "rms_px": 0.25,
                   "validation": {"points": 100}}
    calib = calibration_from_json(data)
    assert calib.has_distortion and calib.image_size == (640, 480) and calib.extra == {"validation": {"points": 100}}
    again = calibration_from_json(json.loads(json.dumps(calib.to_json())))
    for name in ("P1", "P2", "K1", "K2", "D1", "R", "T"):
        np.testing.assert_array_equal(getattr(again, name), getattr(calib, name))
    assert again.D2 is None and again.rms_px == 0.25
    assert again.to_json() == calib.to_json()


def test_an_image_size_written_as_whole_floats_is_the_same_size():
    # numpy's tolist() of a float array writes [640.0, 480.0]: the same pixels, not a fault
    calib = calibration_from_json(GOOD | {"image_size": [640.0, 480.0]})
    assert calib.image_size == (640, 480) and all(type(s) is int for s in calib.image_size)
    assert calib.to_json()["image_size"] == [640, 480]


def test_only_p1_and_p2_is_enough():
    calib = calibration_from_json(GOOD)
    assert isinstance(calib, StereoCalibration) and not calib.has_distortion
    assert calib.to_json() == GOOD


def _rig(rng):
    """Two cameras of their own intrinsics in a world frame of its own (a tank's): (P1, P2, K1, K2,
    R, T) with R, T camera 2's pose from camera 1 (X2 = R X1 + T, OpenCV's)."""
    def rot(axis, deg):
        import cv2
        return cv2.Rodrigues(np.asarray(axis, float) / np.linalg.norm(axis) * np.radians(deg))[0]
    Ks = [np.array([[rng.uniform(600, 2500), rng.uniform(-2, 2), rng.uniform(300, 1000)],
                    [0.0, rng.uniform(600, 2500), rng.uniform(200, 700)], [0.0, 0.0, 1.0]]) for _ in range(2)]
    R1, t1 = rot(rng.normal(size=3), rng.uniform(0, 170)), rng.uniform(-2000, 2000, 3)
    R, T = rot(rng.normal(size=3), rng.uniform(1, 20)), np.array([-rng.uniform(50, 400), *rng.uniform(-20, 20, 2)])
    R2, t2 = R @ R1, R @ t1 + T
    s1, s2 = rng.choice([-1, 1]) * rng.uniform(0.01, 50, 2)              # a projection's free scale
    return s1 * Ks[0] @ np.c_[R1, t1], s2 * Ks[1] @ np.c_[R2, t2], Ks[0], Ks[1], R, T


@pytest.mark.parametrize("seed", range(12))
def test_k_r_and_t_agreeing_with_p1_p2_are_taken_in_any_world_frame_and_scale(seed):
    P1, P2, K1, K2, R, T = _rig(np.random.default_rng(seed))
    data = {"P1": P1.tolist(), "P2": P2.tolist(), "K1": K1.tolist(), "K2": K2.tolist(), "R": R.tolist(),
            "T": T.tolist(), "D1": [0.01, 0, 0, 0, 0]}
    calib = calibration_from_json(data)
    assert calib.has_distortion


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize(("field", "change", "said"), [
    ("K1", lambda K: K * np.array([[1.5, 1, 1], [1, 1.5, 1], [1, 1, 1]]), "K1: not P1's camera: P1 has fx "),
    ("K2", lambda K: K + np.array([[0, 0, 0], [0, 0, 60.0], [0, 0, 0]]), "K2: not P2's camera: P2 has fx "),
    ("K1", lambda K: K * np.array([[1.03, 1, 1], [1, 1, 1], [1, 1, 1]]), "K1: not P1's camera"),
    ("R", lambda R: __import__("cv2").Rodrigues(np.array([0.0, 0.05, 0.0]))[0] @ R,
     "R: 2.9 degrees from camera 2's rotation in P1, P2"),
    ("T", lambda T: T / 1000.0, "T: "),                                  # metres in a file of mm
    ("T", lambda T: -T, "T: "),
])
def test_k_r_or_t_contradicting_p1_p2_is_refused_naming_it(seed, field, change, said):
    """K1 is what undistortion uses, P1 what triangulates: a file where they disagree (K1's focal
    lengths x1.5 here, as a tester's) measured 15 of 24 fish, 1.85 % off, and was taken silently."""
    P1, P2, K1, K2, R, T = _rig(np.random.default_rng(100 + seed))
    data = {"P1": P1, "P2": P2, "K1": K1, "K2": K2, "R": R, "T": T}
    data[field] = change(data[field])
    with pytest.raises(CalibrationError) as err:
        calibration_from_json({k: np.asarray(v).tolist() for k, v in data.items()})
    assert str(err.value).startswith(said) and err.value.field == field, str(err.value)
