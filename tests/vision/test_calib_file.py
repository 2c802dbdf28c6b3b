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


def test_only_p1_and_p2_is_enough():
    calib = calibration_from_json(GOOD)
    assert isinstance(calib, StereoCalibration) and not calib.has_distortion
    assert calib.to_json() == GOOD
