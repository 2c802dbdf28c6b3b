"""Stereo association on projected 3-D points: fork pairing by epipolar geometry and NCC, snout
choice by residual, species length, tilt and the fin's size; the camera's image-up."""
from __future__ import annotations

import numpy as np
import pytest

from devices.sim.stereo_rig import convergent_rig
from tests.vision.fish_drawing import underwater_pair
from vision.association import View, camera_frame, match_forks, pair_snouts, tilt_deg
from vision.fins import Fins
from vision.fork import pyramid


@pytest.fixture(scope="module")
def rig():
    return convergent_rig(baseline_mm=400, crossing_mm=1200, focal_px=1400, target=np.array([0, 1200, -1500.0]),
                          forward=np.array([0, 1.0, 0]), up=np.array([0, 0, 1.0]))


def test_camera_frame_gives_focal_and_image_up(rig):
    f, up = camera_frame(rig.P1)
    assert f == pytest.approx(1400, rel=1e-9)
    assert np.allclose(up, [0, 0, 1], atol=1e-9)
    f2, up2 = camera_frame(-3.0 * rig.P1)                  # any scale or sign of P
    assert f2 == pytest.approx(1400) and np.allclose(up2, up)


def test_tilt_against_the_surface():
    up = np.array([0.0, 0.0, 1.0])
    assert tilt_deg(np.array([[1.0, 0, 0], [1.0, 0, 1.0], [0, 0, -2.0]]), up) == pytest.approx([0, 45, 90])


def fish_points(rig, rng, n, tilt=0.0, length=300.0):
    c1, c2 = rig.centres
    fork = rig.target + rng.uniform(-150, 150, (n, 3))
    yaw = rng.uniform(0, 2 * np.pi, n)
    heading = np.c_[np.cos(yaw), np.sin(yaw), np.zeros(n)]
    axis = np.cos(np.radians(tilt)) * heading + np.sin(np.radians(tilt)) * np.array([0, 0, 1.0])
    return fork, fork + length * axis


def candidates(rig, rng, fork, snout, noise=0.3):
    """Three snout candidates per fish and image along its axis: short, true, long (in that order)."""
    pts = [fork + f * (snout - fork) for f in (0.7, 1.0, 1.35)]
    px = [rig.project(p, noise, rng) for p in pts]
    left = np.stack([p[0] for p in px], axis=1)
    right = np.stack([p[1] for p in px], axis=1)
    return left, right


def test_the_true_snout_is_chosen_among_candidates_on_the_axis(rig):
    """A level fish lies along the epipolar lines: the left 'true' with the right 'long' candidate
    triangulates cleanly too (a fish turned towards the camera). The views' likeness decides: same
    rank, same structure (NCC 1); across ranks the patches differ (NCC 0.2)."""
    rng = np.random.default_rng(1)
    fork, snout = fish_points(rig, rng, 20)
    left, right = candidates(rig, rng, fork, snout)
    ones = np.ones((20, 3))
    ncc = np.broadcast_to(np.where(np.eye(3) > 0, 1.0, 0.2), (20, 3, 3))
    ch = pair_snouts(rig.calibration(), fork, left, ones, right, ones, 30, 800, 35, np.array([0, 0, 1.0]), 2.5,
                     expected_mm=np.full(20, 345.0), ncc=ncc)
    assert ch.ok.all()
    assert np.allclose(ch.length_mm, 300, rtol=0.01)
    assert np.linalg.norm(ch.mm - snout, axis=1).max() < 5


def test_out_of_range_lengths_tilted_fish_and_epipolar_misfits_are_rejected(rig):
    rng = np.random.default_rng(2)
    up = np.array([0, 0, 1.0])
    calib = rig.calibration()
    fork, snout = fish_points(rig, rng, 10, tilt=50)
    left, right = candidates(rig, rng, fork, snout)
    ones = np.ones((10, 3))
    assert not pair_snouts(calib, fork, left, ones, right, ones, 30, 800, 35, up).ok.any()       # tilt
    fork, snout = fish_points(rig, rng, 10)
    left, right = candidates(rig, rng, fork, snout)
    same = np.broadcast_to(np.eye(3), (10, 3, 3))             # only same-rank candidates are alike
    assert pair_snouts(calib, fork, left, ones, right, ones, 30, 800, 35, up, ncc=same).ok.all()
    assert not pair_snouts(calib, fork, left, ones, right, ones, 30, 150, 35, up, ncc=same).ok.any()    # too long
    right_off = right + np.array([0.0, 12.0])                                                       # off the line
    assert not pair_snouts(calib, fork, left, ones, right_off, ones, 30, 800, 35, up, 2.5, ncc=same).ok.any()


def test_forks_pair_with_their_own_fish_across_the_pair(rig):
    """Forks of drawn fish, detected in both images (truth plus 0.5 px noise) among distractors:
    each pairs with its own fish's fork in the other image, distractors with nothing of a fish."""
    rng = np.random.default_rng(3)
    left, right, truths = underwater_pair(rng, rig, n_fish=3)
    views = []
    for cam, img in enumerate((left, right)):
        fork = np.array([t[3][cam] for t in truths]) + rng.normal(0, 0.5, (3, 2))
        snout = np.array([t[2][cam] for t in truths])
        d = snout - fork
        angle = np.arctan2(d[:, 1], d[:, 0])
        span = 0.3 * np.linalg.norm(d, axis=1)
        junk = rng.uniform([100, 100], [1180, 860], (4, 2))
        xy = np.vstack([fork, junk])
        fins = Fins(xy, np.r_[angle, rng.uniform(-3, 3, 4)], np.r_[span, rng.uniform(40, 120, 4)], np.ones(7),
                    np.ones(7))
        views.append(View(pyramid(img), fins, np.zeros((7, 1)), np.zeros((7, 1)), np.zeros(7)))
    pairs = match_forks(rig.calibration(), *views)
    got = {(int(i), int(j)) for i, j in zip(pairs.i, pairs.j, strict=True)}
    for k in range(3):
        assert (k, k) in got
    assert all(i == j for i, j in got if i < 3 or j < 3)
