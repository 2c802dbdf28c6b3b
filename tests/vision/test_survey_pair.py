"""vision.survey.measure_pair takes the pair in any mix of grey, single-channel, colour and alpha."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.vision.fish_drawing import underwater_pair
from tests.vision.test_underwater import SETUP, rig_of
from vision.survey import measure_pair, same_kind


def _forms(grey: np.ndarray) -> dict[str, np.ndarray]:
    colour = cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)
    return {"grey": grey, "one channel": grey[..., None], "colour": colour,
            "colour with alpha": cv2.cvtColor(colour, cv2.COLOR_BGR2BGRA)}


@pytest.fixture(scope="module")
def drawn():
    rig = rig_of()
    left, right, _ = underwater_pair(np.random.default_rng(3), rig, n_fish=3)
    calib = rig.calibration()
    as_grey = measure_pair(left, right, calib, SETUP)
    as_colour = measure_pair(_forms(left)["colour"], _forms(right)["colour"], calib, SETUP)
    return calib, left, right, as_grey, as_colour


def _lengths(fish) -> list[float]:
    return sorted(round(f.length_cm, 2) for f in fish)


@pytest.mark.parametrize("left_form", ["grey", "one channel", "colour", "colour with alpha"])
@pytest.mark.parametrize("right_form", ["grey", "one channel", "colour", "colour with alpha"])
def test_any_mix_of_grey_and_colour_views_is_measured(drawn, left_form, right_form):
    """Two colour views are measured in colour (alpha dropped); a grey one with anything, grey."""
    calib, left, right, as_grey, as_colour = drawn
    assert as_grey and as_colour                               # the scene has fish to compare
    fish = measure_pair(_forms(left)[left_form], _forms(right)[right_form], calib, SETUP)
    both_colour = left_form.startswith("colour") and right_form.startswith("colour")
    assert _lengths(fish) == _lengths(as_colour if both_colour else as_grey)


def test_same_kind_turns_the_colour_view_grey_only_when_the_other_is_grey():
    grey = np.arange(12, dtype=np.uint8).reshape(3, 4)
    colour = np.dstack([grey, grey // 2, grey // 3])
    l2, r2 = same_kind(grey, colour)
    assert l2.ndim == r2.ndim == 2 and np.array_equal(r2, cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY))
    l3, r3 = same_kind(colour, colour[..., ::-1])
    assert l3.shape == r3.shape == (3, 4, 3)
    with pytest.raises(ValueError, match="grey .* or colour"):
        same_kind(np.zeros((3, 4, 2), np.uint8), grey)


@pytest.mark.parametrize("s1, s2", [(-1.0, -1.0), (-1.0, 1.0), (1.0, -3.0), (-0.002, 250.0)])
def test_projection_matrices_of_any_sign_and_scale_measure_the_same_fish(drawn, s1, s2):
    """P is defined up to scale, sign included (DLT and SVD tools give either): a negated P had its
    camera read as looking backwards, and the survey found no fish, silently. Through CALIB.json
    too, with K, R and T beside the negated P."""
    from vision.calib_file import StereoCalibration, calibration_from_json
    calib, left, right, as_grey, _ = drawn
    assert as_grey
    scaled = StereoCalibration(P1=calib.P1 * s1, P2=calib.P2 * s2)
    assert _lengths(measure_pair(left, right, scaled, SETUP)) == _lengths(as_grey)
    data = {**calib.to_json(), "P1": (calib.P1 * s1).tolist(), "P2": (calib.P2 * s2).tolist()}
    read = calibration_from_json(data)
    for P, want in ((read.P1, calib.P1), (read.P2, calib.P2)):
        assert np.linalg.det(P[:, :3]) > 0
        np.testing.assert_allclose(P / np.abs(P).max(), want / np.abs(want).max(), atol=1e-12)
    assert _lengths(measure_pair(left, right, read, SETUP)) == _lengths(as_grey)
