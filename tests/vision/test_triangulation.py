"""Triangulation by least squares of the paper's eq. (6), batched, with pixel residuals."""
import time

import cv2
import numpy as np
import pytest
from scipy.optimize import least_squares

from devices.sim.stereo_rig import (
    StereoRig,
    convergent_rig,
    intrinsics,
    look_at,
    random_points_in_grid_volume,
    two_plane_object,
)
from vision.calib_file import StereoCalibration
from vision.triangulation import normalise_projection, project, triangulate, triangulate_calibrated

RIG = convergent_rig()
WORLD = random_points_in_grid_volume(two_plane_object(), 500, np.random.default_rng(9))


def _eq6_reference(P1, P2, pts1, pts2):
    """Eq. (6) written out row by row, solved with numpy's batched pseudo-inverse."""
    rows, rhs = [], []
    for P, pts in ((normalise_projection(P1), pts1), (normalise_projection(P2), pts2)):
        for i, coord in ((0, pts[:, 0]), (1, pts[:, 1])):
            a = P[i][None, :] - coord[:, None] * P[2][None, :]       # (N, 4)
            rows.append(a[:, :3])
            rhs.append(-a[:, 3])
    A = np.stack(rows, axis=1)                                       # (N, 4, 3)
    b = np.stack(rhs, axis=1)[:, :, None]
    return (np.linalg.pinv(A) @ b)[:, :, 0]


def test_noiseless_pairs_give_the_points_and_zero_residual():
    p1, p2 = RIG.project(WORLD)
    X, residual = triangulate(RIG.P1, RIG.P2, p1, p2)
    np.testing.assert_allclose(X, WORLD, atol=1e-8)
    assert residual.max() < 1e-8


def test_solution_is_the_least_squares_of_equation_6():
    rng = np.random.default_rng(1)
    p1, p2 = RIG.project(WORLD, 2.0, rng)
    X, _ = triangulate(RIG.P1, RIG.P2, p1, p2)
    np.testing.assert_allclose(X, _eq6_reference(RIG.P1, RIG.P2, p1, p2), atol=1e-7)


def test_residual_is_rms_reprojection_distance_over_both_images():
    rng = np.random.default_rng(2)
    p1, p2 = RIG.project(WORLD, 1.0, rng)
    X, residual = triangulate(RIG.P1, RIG.P2, p1, p2)
    d1 = np.linalg.norm(project(RIG.P1, X) - p1, axis=1)
    d2 = np.linalg.norm(project(RIG.P2, X) - p2, axis=1)
    np.testing.assert_allclose(residual, np.sqrt((d1 ** 2 + d2 ** 2) / 2), rtol=1e-10)
    # one degree of freedom (along the epipolar line) of four is not absorbed by the 3-D point
    assert np.sqrt(np.mean(residual ** 2)) == pytest.approx(np.sqrt(1 / 2), rel=0.15)


def _near_and_far_rig():
    """Camera 1 ~0.3 m from the scene, camera 2 ~3 m: eq. (6)'s rows are "pixel error x depth", so
    unweighted they trust camera 2's pixels ten times less than camera 1's."""
    K = intrinsics(1400, (1280, 960))
    up = np.array([0.0, 0.0, 1.0])
    eyes = [dist * np.array([np.sin(a), -np.cos(a), 0.3]) / np.hypot(1.0, 0.3)
            for dist, a in ((300.0, np.radians(-15)), (3000.0, np.radians(15)))]
    (R1, t1), (R2, t2) = (look_at(eye, np.zeros(3), up) for eye in eyes)
    return StereoRig(K1=K, K2=K.copy(), R1=R1, t1=t1, R2=R2, t2=t2)


def _pixel_least_squares(rig, X0, p1, p2):
    """Per point, the world point minimising the reprojection error in both images (scipy)."""
    def residual(X, a, b):
        return np.r_[project(rig.P1, X)[0] - a, project(rig.P2, X)[0] - b]
    return np.array([least_squares(residual, x, args=(a, b), x_scale="jac", xtol=1e-12).x
                     for x, a, b in zip(X0, p1, p2, strict=True)])


def test_reweighting_moves_to_pixel_least_squares_when_depths_differ():
    rig = _near_and_far_rig()
    rng = np.random.default_rng(3)
    world = rng.uniform(-50, 50, (500, 3))
    assert rig.in_view(world).all()
    p1, p2 = rig.project(world, 1.0, rng)
    X0, r0 = triangulate(rig.P1, rig.P2, p1, p2, iterations=0)
    X1, r1 = triangulate(rig.P1, rig.P2, p1, p2, iterations=1)
    assert np.sum(r1 ** 2) < 0.1 * np.sum(r0 ** 2)              # measured: 0.04
    # on a few points, against the true pixel least squares
    few = slice(0, 20)
    best = _pixel_least_squares(rig, X0[few], p1[few], p2[few])
    d_best = np.linalg.norm(np.c_[project(rig.P1, best) - p1[few], project(rig.P2, best) - p2[few]], axis=1)
    best_sq = np.sum(d_best ** 2) / 2                           # on the scale of residual_px ** 2
    assert np.sum(r1[few] ** 2) <= best_sq * (1 + 1e-4)         # measured: 1 + 3e-6
    assert np.sum(r0[few] ** 2) > 10 * best_sq                  # measured: 26
    e0, e1 = (np.linalg.norm(X[few] - best, axis=1) for X in (X0, X1))
    assert np.all(e1 < 0.1 * e0)                                # measured: at most 0.014


def test_world_origin_far_away_keeps_precision():
    offset = np.array([5e6, 2e6, -1e6])                 # a grid surveyed in site coordinates, mm
    shift = np.vstack([np.c_[np.eye(3), -offset], [0, 0, 0, 1]])
    p1, p2 = RIG.project(WORLD)
    X, residual = triangulate(RIG.P1 @ shift, RIG.P2 @ shift, p1, p2)
    np.testing.assert_allclose(X - offset, WORLD, atol=1e-5)
    assert residual.max() < 1e-6


def test_distorted_pixels_are_undistorted_first():
    D = np.array([-0.15, 0.08, 0.0, 0.0, 0.0])
    rig = convergent_rig(distortion=D)
    p1, p2 = rig.project(WORLD)
    calib = rig.calibration()
    X, residual = triangulate_calibrated(calib, p1, p2)
    np.testing.assert_allclose(X, WORLD, atol=1e-3)
    assert residual.max() < 1e-3
    naive, _ = triangulate(calib.P1, calib.P2, p1, p2)
    assert np.abs(naive - WORLD).max() > 1.0             # ignoring distortion costs millimetres


@pytest.mark.parametrize("D", [[-0.32, 0.12, 0.0, 0.0, -0.02],                  # an action camera
                               [0.25, -0.1, 0.002, -0.003, 0.05],                 # pincushion
                               [-0.1, 0.02, 0.001, -0.001, 0.0, 0.0, 0.0, 0.0]])  # mild, 8 coefficients
def test_strong_distortion_is_undone_to_the_image_corners(D):
    """Pixels projected through the distortion by OpenCV itself come back where the pinhole puts
    them, out to the corners of a 1920x1080 frame at f 900 px (OpenCV's 5 default iterations leave
    the action camera's corners 1-3 px off)."""
    from vision.triangulation import undistort_pixels
    K = np.array([[900.0, 0, 959.5], [0, 900.0, 539.5], [0, 0, 1]])
    u, v = np.meshgrid(np.linspace(0, 1919, 49), np.linspace(0, 1079, 28))
    ideal = np.column_stack([u.ravel(), v.ravel()])
    rays = np.column_stack([(ideal - K[:2, 2]) / 900.0, np.ones(len(ideal))])
    seen, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, np.array(D))
    seen = seen.reshape(-1, 2)
    keep = np.all((seen >= 0) & (seen <= [1919, 1079]), axis=1)    # what the camera can see of them
    assert keep.sum() > 0.6 * len(keep)
    np.testing.assert_allclose(undistort_pixels(seen[keep], K, np.array(D)), ideal[keep], atol=1e-6)


def test_empty_and_mismatched_inputs():
    X, residual = triangulate(RIG.P1, RIG.P2, np.empty((0, 2)), np.empty((0, 2)))
    assert X.shape == (0, 3) and residual.shape == (0,)
    with pytest.raises(ValueError, match="points"):
        triangulate(RIG.P1, RIG.P2, np.zeros((3, 2)), np.zeros((2, 2)))


def test_batched_solution_is_far_faster_than_a_loop_over_points():
    """Throughput as a ratio (absolute rates are in bench/bench_stereo.py): per point, the batched
    solution must beat solving eq. (6) point by point with numpy by a wide margin."""
    world = random_points_in_grid_volume(two_plane_object(), 100_000, np.random.default_rng(0))
    p1, p2 = RIG.project(world)
    few = slice(0, 500)

    def one_by_one():
        for a, b in zip(p1[few], p2[few], strict=True):
            _eq6_reference(RIG.P1, RIG.P2, a[None], b[None])

    def per_point(fn, n):
        times = []
        for _ in range(3):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
        return np.median(times) / n

    ours = per_point(lambda: triangulate(RIG.P1, RIG.P2, p1, p2), len(world))
    looped = per_point(one_by_one, 500)
    assert looped / ours > 20


def _project_skewed(K, D, rays):
    """Pixels of camera-frame rays through OpenCV's distortion with the skew applied after it (the
    Caltech / MATLAB model), written out here, not by the code under test."""
    x, y = rays[:, 0] / rays[:, 2], rays[:, 1] / rays[:, 2]
    k1, k2, p1, p2, k3 = (list(D) + [0.0] * 5)[:5]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.column_stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]])


@pytest.mark.parametrize("D", [[0.0] * 5, [-0.12, 0.03, 0.0, 0.0, 0.0], [-0.1, 0.02, 0.001, -0.002, 0.0]])
def test_a_skewed_camera_matrix_is_undistorted_with_its_skew(D):
    """OpenCV's undistortPoints ignores K[0][1]: a skew of 20 px with D all zeros moved a pixel 7 px."""
    from vision.triangulation import undistort_pixels
    K = np.array([[1200.0, 20.0, 640.0], [0.0, 1195.0, 480.0], [0.0, 0.0, 1.0]])
    rng = np.random.default_rng(5)
    rays = np.column_stack([rng.uniform(-0.5, 0.5, (200, 2)), np.ones(200)])
    ideal = rays @ K.T
    ideal = ideal[:, :2] / ideal[:, 2:]
    np.testing.assert_allclose(undistort_pixels(_project_skewed(K, D, rays), K, np.array(D)), ideal, atol=1e-6)


def test_pixels_beyond_where_a_folding_lens_model_reaches_have_no_ray():
    """k1 -0.32, k2 0.12, k3 -0.02 at f 900: r_d = r (1 + k1 r^2 + k2 r^4 + k3 r^6) peaks at r ~1.61
    (~909 px), inside a 1920x1080 frame's corners (1101 px): beyond, no ray; within, exact."""
    from vision.triangulation import distortion_reach, reach_in_image, undistort_pixels
    D = np.array([-0.32, 0.12, 0.0, 0.0, -0.02])
    K = np.array([[900.0, 0, 960], [0, 900.0, 540], [0, 0, 1]])
    r = np.linspace(0, 3, 300001)
    peak = (r * (1 - 0.32 * r ** 2 + 0.12 * r ** 4 - 0.02 * r ** 6)).max()
    assert distortion_reach(tuple(D)) == pytest.approx(peak, rel=2e-3)
    reach_px, corner_px = reach_in_image(K, D, (1920, 1080))
    assert reach_px == pytest.approx(900 * peak, rel=2e-3) and corner_px == pytest.approx(np.hypot(960.5, 540.5))
    small = np.array([[900.0, 0, 640], [0, 900.0, 360], [0, 0, 1]])
    assert reach_in_image(small, D, (1280, 720)) is None                    # a smaller frame: inside the reach
    assert reach_in_image(K, np.array([0.25, -0.1, 0.0, 0.0, 0.05]), (1920, 1080)) is None  # pincushion: none
    far = np.array([[40.0, 40.0], [1900.0, 1060.0]])
    assert np.isnan(undistort_pixels(far, K, D)).all()
    rays = np.column_stack([np.random.default_rng(1).uniform(-1.2, 1.2, (300, 2)), np.ones(300)])
    seen = _project_skewed(K, D, rays)
    within = np.hypot(*(seen - K[:2, 2]).T) < 0.98 * reach_px
    within &= np.hypot(rays[:, 0], rays[:, 1]) < 1.5                          # before the fold
    ideal = rays[:, :2] * 900 + K[:2, 2]
    np.testing.assert_allclose(undistort_pixels(seen[within], K, D), ideal[within], atol=1e-6)
    X, residual = triangulate_calibrated(StereoCalibration(P1=K @ np.eye(3, 4), P2=K @ np.c_[np.eye(3), [-200, 0, 0]],
                                                           K1=K, D1=D, K2=K, D2=D), far, far + [-15, 0])
    assert np.isnan(X).all() and np.isnan(residual).all()
