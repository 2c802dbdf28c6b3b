"""The simulated convergent rig and two-plane calibration object behave like the paper's rig."""
import numpy as np
import pytest

from devices.sim.stereo_rig import (
    convergent_rig,
    measure_grid,
    random_points_in_grid_volume,
    two_plane_object,
)
from vision.triangulation import project, undistort_pixels


def test_object_has_about_100_points_on_two_planes_at_several_heights():
    world = two_plane_object()
    assert len(world) == 100
    on_a, on_b = world[:, 1] == 0, world[:, 0] == 0
    assert on_a.sum() == 50 and on_b.sum() == 50 and not np.any(on_a & on_b)
    assert len(np.unique(world[:, 2])) >= 5
    s = np.linalg.svd(world - world.mean(axis=0), compute_uv=False)
    assert s[2] > 0.2 * s[0]                      # far from coplanar: good for the DLT


def test_optical_axes_cross_about_one_metre_ahead():
    rig = convergent_rig()
    c1, c2 = rig.centres
    # the crossing point is on both optical axes: it images at both principal points
    for P, K in ((rig.P1, rig.K1), (rig.P2, rig.K2)):
        np.testing.assert_allclose(project(P, rig.target)[0], K[:2, 2], atol=1e-9)
    middle = (c1 + c2) / 2
    assert np.linalg.norm(rig.target - middle) == pytest.approx(1000.0, rel=1e-9)
    assert np.linalg.norm(c2 - c1) == pytest.approx(400.0, rel=1e-9)
    vergence = np.degrees(np.arccos(rig.R1[2] @ rig.R2[2]))
    assert 15 < vergence < 30
    # camera 2 is to the right of camera 1 in camera 1's frame (OpenCV: x right)
    assert (rig.R1 @ c2 + rig.t1)[0] > 0


def test_whole_grid_is_in_view_of_both_cameras_and_fills_the_image():
    rig = convergent_rig()
    world = two_plane_object()
    assert rig.in_view(world, border_px=20).all()
    p1, p2 = rig.project(world)
    width, height = rig.image_size
    assert np.ptp(p1[:, 0]) > 0.6 * width and np.ptp(p2[:, 0]) > 0.6 * width
    z1, z2 = rig.depths(world)
    assert 700 < z1.min() and z1.max() < 1300 and 700 < z2.min() and z2.max() < 1300


def test_pixel_noise_is_seeded_gaussian_of_the_requested_size():
    rig = convergent_rig()
    world = random_points_in_grid_volume(two_plane_object(), 4000, np.random.default_rng(3))
    clean = np.hstack(rig.project(world))
    a = measure_grid(rig, world, 0.2, np.random.default_rng(7))
    b = measure_grid(rig, world, 0.2, np.random.default_rng(7))
    c = measure_grid(rig, world, 0.2, np.random.default_rng(8))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    noise = a[:, 3:] - clean
    assert np.std(noise) == pytest.approx(0.2, rel=0.05)
    assert abs(np.mean(noise)) < 0.01
    np.testing.assert_array_equal(a[:, :3], world)
    with pytest.raises(ValueError, match="rng"):
        rig.project(world, 0.2)


def test_distortion_moves_pixels_and_undistortion_brings_them_back():
    D = np.array([-0.12, 0.05, 0.0005, -0.0003, 0.0])
    bent = convergent_rig(distortion=D)
    straight = convergent_rig()
    world = two_plane_object()
    b1, _ = bent.project(world)
    s1, _ = straight.project(world)
    assert np.abs(b1 - s1).max() > 5.0              # real barrel distortion at the corners
    np.testing.assert_allclose(undistort_pixels(b1, bent.K1, bent.D1), s1, atol=1e-3)


def test_true_calibration_is_consistent():
    rig = convergent_rig()
    calib = rig.calibration()
    world = two_plane_object()
    np.testing.assert_allclose(calib.P1, rig.P1)
    # R, T (camera 2 <- camera 1) carry camera 1's frame onto camera 2's
    cam1 = world @ rig.R1.T + rig.t1
    cam2 = world @ rig.R2.T + rig.t2
    np.testing.assert_allclose(cam1 @ calib.R.T + calib.T, cam2, atol=1e-9)
    assert calib.image_size == (1280, 960) and not calib.has_distortion
