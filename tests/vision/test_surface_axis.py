"""The fish triangulated as a whole: a 3-D line through its points, the ends placed on it."""
from __future__ import annotations

import numpy as np

from tests.vision.test_surface_drawing import top_rig
from vision.surface_stereo import ends_on_axis, fit_axis
from vision.triangulation import project


def test_ends_on_the_fitted_line_keep_their_place_along_it_with_noisy_depths():
    rig = top_rig()
    calib = rig.calibration()
    P1, P2 = np.asarray(calib.P1, float), np.asarray(calib.P2, float)
    snout, fork = np.array([-60.0, 20.0, -150.0]), np.array([70.0, -10.0, -160.0])   # tilted ~4 deg
    line = snout + np.linspace(0, 1, 7)[:, None] * (fork - snout)
    rng = np.random.default_rng(3)
    noisy = line + rng.normal(0, 1.0, line.shape) + np.array([0, 0, 1.0]) * rng.normal(0, 4.0, (7, 1))
    c, d = fit_axis(noisy)
    ends = np.array([snout, fork])
    got = ends_on_axis(calib, c, d, project(P1, ends), project(P2, ends))
    # the length barely moves with the line's depth: the rays fix the ends along the fish
    assert abs(np.linalg.norm(got[0] - got[1]) - np.linalg.norm(snout - fork)) < 0.02 * np.linalg.norm(snout - fork)
    # exact points give the exact ends
    c, d = fit_axis(line)
    got = ends_on_axis(calib, c, d, project(P1, ends), project(P2, ends))
    assert np.allclose(got, ends, atol=1e-6)


def test_a_dark_fin_joined_to_the_body_keeps_its_notch_as_the_fork():
    from vision.surface_shape import _fork
    snout, tail = np.array([0.0, 0.0]), np.array([1.0, 0.0])
    # the body's outline runs out to the fin's tip (1.10), past the notch (1.00): no base was seen
    fork = _fork(snout, base=np.array([108.0, 0]), tip=np.array([110.0, 0]), notch=np.array([100.0, 0]),
                 base_ratio=0.86, tail=tail)
    assert np.allclose(fork, [100.0, 0])
    # a pale fin past a body that ends at its base: a notch near the base is a bite, not the fork
    fork = _fork(snout, base=np.array([86.0, 0]), tip=np.array([110.0, 0]), notch=np.array([87.0, 0]),
                 base_ratio=0.86, tail=tail)
    assert np.allclose(fork, [100.0, 0])


def test_a_midline_point_matched_off_the_body_does_not_tilt_the_line():
    from vision.surface_stereo import fit_axis_robust
    rng = np.random.default_rng(5)
    line = np.c_[np.linspace(0, 150, 17), np.zeros(17), np.full(17, -200.0)] + rng.normal(0, 0.5, (17, 3))
    line[8, 2] += 40.0                       # one point 40 mm too high
    c, d = fit_axis_robust(line)
    assert abs(d[2]) < 0.01 and abs(c[2] + 200) < 1.0
    _, d0 = fit_axis(line)
    assert abs(d0[2]) < abs(d[2]) or abs(c[2] + 200) < 1.0      # (the plain fit is pulled up: 40/17 mm)
