"""Epipolar geometry: the paper's M21 construction (eqs. 3-4) and the fundamental matrix agree."""
import numpy as np
import pytest

from devices.sim.stereo_rig import (
    StereoRig,
    convergent_rig,
    intrinsics,
    random_points_in_grid_volume,
    two_plane_object,
)
from vision.dlt import calibrate_camera
from vision.epipolar import (
    epipolar_directions,
    epipolar_lines,
    epipolar_lines_m21,
    epipoles,
    fundamental_from_projections,
    paper_m21,
)
from vision.triangulation import camera_centre, project

RIG = convergent_rig()
POINTS = random_points_in_grid_volume(two_plane_object(), 200, np.random.default_rng(4))


def _homog(p):
    return np.c_[p, np.ones(len(p))]


def _parallel_rig():
    """Parallel optical axes, baseline along x: the epipoles are at infinity."""
    K = intrinsics(1400, (1280, 960))
    R = np.eye(3)
    return StereoRig(K1=K, K2=K.copy(), R1=R, t1=np.array([0.0, 0, 1000]), R2=R,
                     t2=np.array([-300.0, 0, 1000]))


@pytest.mark.parametrize("rig", [RIG, _parallel_rig()], ids=["convergent", "parallel"])
def test_m21_lines_are_the_fundamental_matrix_lines(rig):
    world = POINTS - POINTS.mean(axis=0) if rig is not RIG else POINTS
    p1, p2 = rig.project(world)
    F = fundamental_from_projections(rig.P1, rig.P2)
    lines_f = epipolar_lines(F, p1)
    lines_m = epipolar_lines_m21(rig.P1, rig.P2, p1)
    sign = np.sign(np.einsum("ij,ij->i", lines_f[:, :2], lines_m[:, :2]))[:, None]
    scale = np.abs(lines_f[:, 2]).max()
    np.testing.assert_allclose(lines_m * sign, lines_f, atol=1e-9 * max(scale, 1.0))
    # and the true match lies on the line, to a pixel fraction of a nanometre's worth
    assert np.abs(np.einsum("ij,ij->i", lines_m, _homog(p2))).max() < 1e-6


def test_epipoles_are_images_of_the_other_centre_and_null_vectors_of_f():
    e1, e2 = epipoles(RIG.P1, RIG.P2)
    c1, c2 = RIG.centres
    np.testing.assert_allclose(e1[:2] / e1[2], project(RIG.P1, c2)[0], rtol=1e-9)
    np.testing.assert_allclose(e2[:2] / e2[2], project(RIG.P2, c1)[0], rtol=1e-9)
    F = fundamental_from_projections(RIG.P1, RIG.P2)
    assert np.linalg.norm(F @ e1) / np.linalg.norm(e1) < 1e-12
    assert np.linalg.norm(F.T @ e2) / np.linalg.norm(e2) < 1e-12
    np.testing.assert_allclose(camera_centre(RIG.P1), c1, atol=1e-9)


def test_m21_direction_points_the_way_the_match_moves_with_depth():
    p1, _ = RIG.project(POINTS)
    d = epipolar_directions(RIG.P1, RIG.P2, p1)
    c1 = RIG.centres[0]
    near = c1 + 0.95 * (POINTS - c1)           # same lines of sight, 5 % closer / farther
    far = c1 + 1.05 * (POINTS - c1)
    motion = project(RIG.P2, far) - project(RIG.P2, near)
    motion /= np.linalg.norm(motion, axis=1)[:, None]
    np.testing.assert_allclose(np.einsum("ij,ij->i", motion, d), 1.0, atol=1e-9)


def test_m21_directions_depend_on_the_scale_of_the_matrices_only_through_p1s_depth_sign():
    """Convention: P gives positive depth in front. Positive scale factors change nothing, nor does
    P2's sign; negating P1 puts "in front" behind camera 1, so "farther" turns round."""
    M = paper_m21(RIG.P1, RIG.P2)
    p1, _ = RIG.project(POINTS)
    d = epipolar_directions(RIG.P1, RIG.P2, p1)
    for a, b in ((3.0, 1.0), (1.0, 0.01), (2.0, 5.0), (0.5, -2.0)):
        np.testing.assert_allclose(epipolar_directions(a * RIG.P1, b * RIG.P2, p1), d, atol=1e-12)
    np.testing.assert_allclose(epipolar_directions(-RIG.P1, RIG.P2, p1), -d, atol=1e-12)
    # M21 itself scales with |a|^2 |b|^2 only: a positive factor
    np.testing.assert_allclose(paper_m21(-2 * RIG.P1, -3 * RIG.P2), 36 * M, atol=1e-9 * 36 * np.abs(M).max())


def test_m21_direction_in_a_left_handed_world():
    """A grid surveyed z-down: the DLT writes P with positive depths and det(P[:, :3]) < 0. The
    pixels are the same as in the right-handed frame, so must be the way "farther" goes."""
    mirror = np.diag([1.0, 1.0, -1.0])
    P1, P2 = (calibrate_camera(POINTS @ mirror, p) for p in RIG.project(POINTS))
    assert np.linalg.det(P1[:, :3]) < 0
    p1, _ = RIG.project(POINTS)
    np.testing.assert_allclose(epipolar_directions(P1, P2, p1), epipolar_directions(RIG.P1, RIG.P2, p1),
                               atol=1e-9)
    # and the paper's lines through e2 are still the fundamental matrix's lines
    lines_f = epipolar_lines(fundamental_from_projections(P1, P2), p1)
    lines_m = epipolar_lines_m21(P1, P2, p1)
    sign = np.sign(np.einsum("ij,ij->i", lines_f[:, :2], lines_m[:, :2]))[:, None]
    np.testing.assert_allclose(lines_m * sign, lines_f, atol=1e-6)


def test_epipolar_lines_keep_their_signature():
    F = fundamental_from_projections(RIG.P1, RIG.P2)
    assert F.shape == (3, 3) and np.linalg.norm(F) == pytest.approx(1.0)
    assert np.linalg.matrix_rank(F, tol=1e-9) == 2
    lines = epipolar_lines(F, np.array([[100.0, 200.0], [640.0, 480.0]]))
    assert lines.shape == (2, 3)
    np.testing.assert_allclose(np.hypot(lines[:, 0], lines[:, 1]), 1.0)
