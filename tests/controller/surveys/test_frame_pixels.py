"""Stills made 8-bit by their own bit depth, float TIFFs, and frames refused for their size from
the header before they are decoded (controller/surveys/frame_pixels.py)."""
from pathlib import Path

import cv2
import numpy as np
import pytest

from controller.errors import BadInput
from controller.surveys import frames
from controller.surveys.frames import decode_pair, read_pair, still_source
from controller.surveys.runner import PairWork, check_header_size
from devices.sim.stereo_rig import convergent_rig
from vision.survey_types import SurveySetup


def picture(h=48, w=64, seed=0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.uniform(0, 255, (h, w, 3)).astype(np.float32), (0, 0), 2)
    img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX)
    return np.round(img).astype(np.uint8)


def pair_of(tmp_path: Path, left, right, ext=".png"):
    paths = (str(tmp_path / f"a_L{ext}"), str(tmp_path / f"a_R{ext}"))
    assert cv2.imwrite(paths[0], left) and cv2.imwrite(paths[1], right)
    return next(iter(still_source([paths]).jobs)), paths


@pytest.mark.parametrize("bits", [10, 12, 16])
def test_a_16_bit_still_is_scaled_by_its_own_bit_depth_the_same_for_both_views(tmp_path, bits):
    # a 10- or 12-bit camera's values LSB-aligned in a 16-bit PNG: shifted down by 8 bits they were
    # 0-3 / 0-15 grey, and the survey found no fish in them without a word
    top = 2 ** bits - 1
    left, right = picture(seed=1), picture(seed=2)
    wide_l = np.round(left.astype(np.float64) * top / 255).astype(np.uint16)
    wide_r = np.round(right.astype(np.float64) * top / 255 * 0.5).astype(np.uint16)   # a darker view
    job, paths = pair_of(tmp_path, wide_l, wide_r)
    got_l, got_r, _ = read_pair(job)
    assert got_l.dtype == np.uint8 and got_r.dtype == np.uint8
    assert np.abs(got_l.astype(int) - left).max() <= 1
    # the right view scaled by the pair's depth (its own maximum is ~half of it): still half as bright
    assert np.abs(got_r.astype(int) - np.round(right * 0.5)).max() <= 1
    blobs = tuple(Path(p).read_bytes() for p in paths)
    assert all(np.array_equal(a, b) for a, b in zip(decode_pair(blobs, paths)[:2], (got_l, got_r), strict=True))


def test_a_32_bit_float_tiff_is_read_from_0_to_1_and_other_values_are_refused_naming_them(tmp_path):
    left, right = picture(seed=3), picture(seed=4)
    job, _ = pair_of(tmp_path, left.astype(np.float32) / 255, right.astype(np.float32) / 255, ".tif")
    got_l, got_r, _ = read_pair(job)
    assert np.abs(got_l.astype(int) - left).max() <= 1 and np.abs(got_r.astype(int) - right).max() <= 1
    job, _ = pair_of(tmp_path, left.astype(np.float32), right.astype(np.float32), ".tif")      # 0-255 in floats
    with pytest.raises(BadInput, match=r"a_L.tif: a floating-point image with values \d+ to 255: 0 to 1 expected"):
        read_pair(job)


def test_a_frame_of_the_wrong_size_is_refused_from_its_header_before_it_is_decoded(tmp_path, monkeypatch):
    job, _ = pair_of(tmp_path, picture(960, 1200), picture(960, 1200))     # the calibration's are 1280x960
    decoded = []
    monkeypatch.setattr(frames, "_imdecode", lambda *a, **k: decoded.append(a[1]))
    work = PairWork(convergent_rig().calibration(), SurveySetup(), lambda *a: [])
    with pytest.raises(BadInput, match=r"a_L.png: does not fit the calibration: image_size: "
                                       r"calibration made for 1280x960 images, the frames are 1200x960"):
        work(job)
    assert decoded == []


def test_the_header_check_reads_bytes_as_a_worker_gets_them_and_lets_a_turned_size_through(tmp_path):
    calib = convergent_rig().calibration()                                  # 1280x960
    ok, wrong, turned = (cv2.imencode(".png", picture(h, w))[1].tobytes() for h, w in
                         ((960, 1280), (1500, 2000), (1280, 960)))
    check_header_size(calib, (ok, turned), ("ok.png", "turned.png"))       # an EXIF turn may fit: decoded, then checked
    with pytest.raises(BadInput, match=r"big.png: does not fit the calibration: .* the frames are 2000x1500"):
        check_header_size(calib, (wrong, wrong), ("big.png", "big_R.png"))
    with pytest.raises(BadInput, match=r"big.png: 2000x1500 pixels, but the left image ok.png is 1280x960"):
        check_header_size(calib, (ok, wrong), ("ok.png", "big.png"))          # as the decoded pair is told


@pytest.mark.parametrize("hot", [1, 12, 150, 400])
def test_hot_pixels_do_not_set_a_16_bit_pair_s_depth(tmp_path, hot):
    """One hot pixel at 65535 in a 10-bit frame scaled the pair to 0-4 grey: no fish, no word (an
    outside tester). The brightest 0.01 % of a pair's pixels do not set its depth; more than that is
    the picture's own light and does."""
    left, right = picture(480, 640, seed=1), picture(480, 640, seed=2)
    wide_l, wide_r = (np.round(v.astype(np.float64) * 1023 / 255).astype(np.uint16) for v in (left, right))
    spots = np.random.default_rng(hot).choice(wide_l.size, hot, replace=False)
    wide_l.ravel()[spots] = 65535
    got_l, got_r, _ = read_pair(pair_of(tmp_path, wide_l, wide_r)[0])
    bright = int(0.0001 * 2 * wide_l.size)             # 184 values of the pair may lie above its depth
    if hot <= bright:
        keep = np.ones(wide_l.size, bool)
        keep[spots] = False
        assert np.abs(got_l.ravel()[keep].astype(int) - left.ravel()[keep]).max() <= 1
        assert (got_l.ravel()[spots] == 255).all() and np.abs(got_r.astype(int) - right).max() <= 1
    else:                                               # a light of its own: the 16-bit scale
        assert got_l.ravel()[spots].min() == 255 and got_r.max() <= 5
