"""DLT calibration (paper eqs. 1-2) with normalisation and refinement, and its validation report."""
import numpy as np
import pytest

from devices.sim.stereo_rig import (
    convergent_rig,
    measure_grid,
    random_points_in_grid_volume,
    two_plane_object,
)
from vision.dlt import (
    CalibrationInputError,
    calibrate_camera,
    calibrate_stereo,
    distance_errors_pct,
    dlt_projection,
    refine_projection,
    reprojection_errors,
    validation_report,
)
from vision.triangulation import normalise_projection, triangulate

RIG = convergent_rig()
WORLD = two_plane_object()


def _same_matrix(P, Q):
    P, Q = normalise_projection(P), normalise_projection(Q)
    return np.abs(P - Q).max() / np.abs(Q).max()


def test_noiseless_grid_gives_the_true_matrices():
    p1, p2 = RIG.project(WORLD)
    assert _same_matrix(dlt_projection(WORLD, p1), RIG.P1) < 1e-9
    assert _same_matrix(dlt_projection(WORLD, p2), RIG.P2) < 1e-9


def test_six_points_are_enough():
    idx = [0, 9, 45, 50, 59, 95]                 # corners of both plates
    p1, _ = RIG.project(WORLD[idx])
    P = dlt_projection(WORLD[idx], p1)
    assert _same_matrix(P, RIG.P1) < 1e-7
    # and it predicts the points it never saw
    assert reprojection_errors(P, WORLD, RIG.project(WORLD)[0]).max() < 1e-5


def test_far_world_origin_does_not_lose_digits():
    """Without Hartley normalisation a grid 10 km from the origin ruins the linear system."""
    offset = np.array([1e7, -3e6, 2e5])
    P_far = RIG.P1 @ np.vstack([np.c_[np.eye(3), -offset], [0, 0, 0, 1]])
    p1, _ = RIG.project(WORLD)
    P = dlt_projection(WORLD + offset, p1)
    assert reprojection_errors(P, WORLD + offset, p1).max() < 1e-4
    assert _same_matrix(P, P_far) < 1e-6


def test_refinement_lowers_reprojection_error_and_keeps_depth_positive():
    rng = np.random.default_rng(11)
    grid = measure_grid(RIG, WORLD, 0.5, rng)
    world, pix = grid[:, :3], grid[:, 3:5]
    linear = dlt_projection(world, pix)
    refined = refine_projection(linear, world, pix)
    e_lin, e_ref = reprojection_errors(linear, world, pix), reprojection_errors(refined, world, pix)
    assert np.sum(e_ref ** 2) < np.sum(e_lin ** 2)
    # refining the exact answer on noiseless data leaves it where it is
    clean = RIG.project(WORLD)[0]
    assert _same_matrix(refine_projection(RIG.P1, WORLD, clean), RIG.P1) < 1e-9
    depth = np.c_[world, np.ones(len(world))] @ refined[2]
    assert np.all(depth > 0) and np.linalg.norm(refined[2, :3]) == pytest.approx(1.0)


def test_left_handed_world_still_gets_positive_depths():
    mirrored = WORLD * [1, 1, -1]
    p1, _ = RIG.project(WORLD)
    P = calibrate_camera(mirrored, p1)
    assert np.all(np.c_[mirrored, np.ones(len(WORLD))] @ P[2] > 0)
    assert reprojection_errors(P, mirrored, p1).max() < 1e-6


@pytest.mark.parametrize("world, fault", [
    (WORLD[:5], "at least 6"),
    (np.c_[WORLD[:50, 0], WORLD[:50, 2], np.zeros(50)], "coplanar"),
    (np.outer(np.arange(10.0), [1.0, 2.0, 3.0]), "line"),
    (np.vstack([WORLD[:3]] * 3), "line|coplanar|distinct"),
])
def test_degenerate_grids_are_refused(world, fault):
    pixels = RIG.project(world)[0]
    with pytest.raises(CalibrationInputError, match=fault):
        dlt_projection(world, pixels)


def test_nearly_flat_but_measured_plate_is_still_coplanar():
    rng = np.random.default_rng(2)
    plate = WORLD[:50] + rng.normal(0, 0.05, (50, 3))     # 0.05 mm measurement noise on a flat plate
    with pytest.raises(CalibrationInputError, match="coplanar"):
        dlt_projection(plate, RIG.project(plate)[0])


def test_nan_pixel_is_refused():
    p1 = RIG.project(WORLD)[0]
    p1[4, 1] = np.nan
    with pytest.raises(CalibrationInputError, match="NaN"):
        dlt_projection(WORLD, p1)


def test_report_measures_a_known_scale_error():
    """True matrices, grid distances claimed 0.1 % too long: every distance is off by 0.1 %."""
    p1, p2 = RIG.project(WORLD)
    report = validation_report(RIG.P1, RIG.P2, WORLD * 1.001, p1, p2)
    d = report.distance_error_pct
    expected = 100 * 0.001 / 1.001
    assert d["median"] == pytest.approx(expected, rel=1e-6)
    assert d["max"] == pytest.approx(expected, rel=1e-6)
    assert report.pairs == 100 * 99 // 2 and report.points == 100
    assert max(report.rms_px) > 0.1     # the scaled points no longer reproject onto the pixels


def test_report_rms_matches_the_noise():
    rng = np.random.default_rng(5)
    grid = measure_grid(RIG, WORLD, 0.3, rng)
    _, _, report = calibrate_stereo(grid[:, :3], grid[:, 3:5], grid[:, 5:7])
    # distance RMS of 2-D noise of 0.3 px per axis is 0.3*sqrt(2), less the 11 fitted parameters
    expected = 0.3 * np.sqrt(2) * np.sqrt((200 - 11) / 200)
    assert report.rms_px[0] == pytest.approx(expected, rel=0.15)
    assert report.rms_px[1] == pytest.approx(expected, rel=0.15)
    d = report.distance_error_pct
    assert d["median"] < d["p95"] < d["max"]


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4])
def test_accuracy_goal_on_validation_points(seed):
    """Goal: ~100 grid points at 0.2 px -> distances between validation points (0.02 px) with median
    <= 0.05 % and p95 <= 0.2 % relative error. Validation points: 100 random points in the grid's
    volume, never used by the calibration; all 4950 pairwise distances."""
    rng = np.random.default_rng(seed)
    grid = measure_grid(RIG, WORLD, 0.2, rng)
    P1, P2, _ = calibrate_stereo(grid[:, :3], grid[:, 3:5], grid[:, 5:7])
    check = random_points_in_grid_volume(WORLD, 100, rng)
    v1, v2 = RIG.project(check, 0.02, rng)
    errors = distance_errors_pct(check, triangulate(P1, P2, v1, v2)[0])
    assert np.median(errors) <= 0.05
    assert np.percentile(errors, 95) <= 0.2
