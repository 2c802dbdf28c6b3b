"""vision.pair_fit: a rig's pairs against their calibration, from the pairs' own texture."""
import numpy as np
import pytest

from devices.sim.stereo_scene import textured_plane
from vision.calib_file import StereoCalibration
from vision.pair_fit import MIN_MATCHES, pair_fit, verdict

K = np.array([[1200.0, 0, 640], [0, 1200.0, 480], [0, 0, 1]])
SIZE = (1280, 960)


def parallel(baseline_mm: float = 200.0, world_is_camera1: bool = True) -> StereoCalibration:
    """P1 = K [I | 0], P2 = K [I | (-b, 0, 0)]: a parallel rig, world = camera 1 (OpenCV's); or the
    same cameras in a world moved 1 m aside (a DLT's)."""
    P1 = K @ np.eye(3, 4)
    P2 = K @ np.c_[np.eye(3), [-baseline_mm, 0, 0]]
    if not world_is_camera1:
        move = np.vstack([np.c_[np.eye(3), [1000.0, 0, 0]], [0, 0, 0, 1]])
        P1, P2 = P1 @ move, P2 @ move
    return StereoCalibration(P1=P1, P2=P2)


def views(calib: StereoCalibration, n: int = 2, seed: int = 0, shift=(0.0, 0.0, 0.0)) -> list:
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        centre = np.array([0.0, 0.0, 1500.0 + 200 * k]) + shift
        scene = textured_plane(calib.P1, calib.P2, SIZE, centre, np.array([0.1 * k, 0.05, 1.0]), rng, texel_mm=1.5)
        out.append((scene.img1, scene.img2))
    return out


def test_pairs_that_fit_their_calibration_pass_and_in_front_of_both_cameras():
    calib = parallel()
    fit = pair_fit(views(calib), calib)
    assert fit.judged and fit.epipolar_px < 1.0 and fit.in_front > 0.9
    assert verdict(fit) is None


def test_views_swapped_against_a_parallel_rig_put_the_points_behind_and_are_said():
    """Swapping a parallel rig's views leaves the epipolar lines as they were: only depth tells."""
    calib = parallel()
    fit = pair_fit([(r, left) for left, r in views(calib)], calib)
    assert fit.epipolar_px < 1.0 and fit.in_front < 0.1 and fit.in_front_swapped > 0.9
    assert "look swapped" in verdict(fit)


def test_another_rig_s_calibration_is_said_not_to_fit():
    taken = parallel()
    other = StereoCalibration(P1=K @ np.eye(3, 4),
                              P2=K @ np.c_[np.array([[0.99, 0, 0.14], [0, 1, 0], [-0.14, 0, 0.99]]), [-150, 20, 0]])
    fit = pair_fit(views(taken), other)
    assert fit.epipolar_px > 8.0
    assert "do not fit the calibration" in verdict(fit)


def test_in_a_world_not_camera1_s_depth_is_not_judged_but_the_epipolar_misses_are():
    calib = parallel(world_is_camera1=False)
    fit = pair_fit(views(calib, shift=(-1000.0, 0, 0)), calib)
    assert fit.judged and np.isnan(fit.in_front) and fit.epipolar_px < 1.0 and verdict(fit) is None


@pytest.mark.parametrize("image", [np.zeros((960, 1280), np.uint8), np.full((960, 1280, 3), 255, np.uint8)])
def test_pairs_without_texture_give_no_verdict(image):
    fit = pair_fit([(image, image)] * 3, parallel())
    assert not fit.judged and fit.matches < MIN_MATCHES and verdict(fit) is None


def test_sixteen_bit_views_are_judged_as_their_eight_bit_selves():
    calib = parallel()
    pairs = views(calib, n=2)
    deep = [(left.astype(np.uint16) * 257, right.astype(np.uint16) * 257) for left, right in pairs]
    assert pair_fit(deep, calib).matches == pytest.approx(pair_fit(pairs, calib).matches, rel=0.1)
