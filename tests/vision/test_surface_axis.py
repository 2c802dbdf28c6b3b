"""The fish triangulated as a whole: a 3-D line through its points, the ends placed on it."""
from __future__ import annotations

import numpy as np
import pytest

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


def _views_of(snout, fork, calib, k=15):
    """Both views' [snout, fork, midline...] pixels (2 + k, 2) of a straight fish, and F."""
    from vision.epipolar import fundamental_from_projections
    P1, P2 = np.asarray(calib.P1, float), np.asarray(calib.P2, float)
    pts = np.vstack([snout, fork, snout + np.linspace(0.15, 0.85, k)[:, None] * (fork - snout)])
    return project(P1, pts), project(P2, pts), fundamental_from_projections(P1, P2)


def _slid(px, end, share):
    """``px`` with one end (0 snout, 1 fork) moved ``share`` of the pixel length towards the other."""
    out = px.copy()
    out[end] += share * (px[1 - end] - px[end])
    return out


def test_each_view_gives_the_snout_the_other_lost_and_close_forks_are_averaged():
    from vision.surface_stereo import ends_from_both_views
    rig = top_rig()
    calib = rig.calibration()
    # heading across the baseline, so epipolar lines cross the body well
    snout, fork = np.array([-20.0, -60.0, -150.0]), np.array([10.0, 70.0, -155.0])
    t1, t2, F = _views_of(snout, fork, calib)
    L1, L2 = np.linalg.norm(t1[0] - t1[1]), np.linalg.norm(t2[0] - t2[1])
    for short_view in (0, 1):                         # one view's snout 8 % short, the other's right
        v = [t1.copy(), t2.copy()]
        v[short_view] = _slid(v[short_view], 0, 0.08)
        p1, p2, gap = ends_from_both_views(F, v[0], v[1])
        assert np.linalg.norm(p1[0] - t1[0]) < 0.005 * L1 and np.linalg.norm(p2[0] - t2[0]) < 0.005 * L2
        assert gap < 1e-6
    # forks 1 % short in the left, 1 % long in the right: within the gap averaged, both right
    p1, p2, gap = ends_from_both_views(F, _slid(t1, 1, 0.01), _slid(t2, 1, -0.01))
    assert 0.015 < gap < 0.025
    assert np.linalg.norm(p1[1] - t1[1]) < 0.003 * L1 and np.linalg.norm(p2[1] - t2[1]) < 0.003 * L2
    # 6 % apart: neither is trusted, the left's is kept and the gap says so
    p1, p2, gap = ends_from_both_views(F, _slid(t1, 1, 0.06), t2)
    assert 0.05 < gap < 0.07 and np.allclose(p1[1], _slid(t1, 1, 0.06)[1])


def _solid_of(calib, pts1, pts2):
    from vision.surface import _solids
    from vision.survey_types import FishGeometry, SurveySetup
    setup = SurveySetup(setup="surface", up_world=(0.0, 0.0, 1.0), geometry=FishGeometry(max_tilt_deg=90.0))
    return _solids(calib, setup, np.array([0.0, 0.0, 1.0]), [(pts1, pts2)])[0]


@pytest.mark.parametrize("heading_deg", [0, 30, 60, 90, 120, 150])
def test_a_line_gone_astray_gives_way_to_the_ends_own_points(heading_deg):
    """Midline points matched with a disparity that grows along the body (matched on the wrong part
    of it) tilt the fitted line; the ends, seen right in both views, are then kept where they are."""
    from vision.surface import AXIS_TILT_EXCESS, _on_axis
    calib = top_rig().calibration()
    h = np.radians(heading_deg)
    centre, half = np.array([30.0, -20.0, -180.0]), 60.0 * np.array([np.cos(h), np.sin(h), 0.0])
    snout, fork = centre + half, centre - half                         # a level fish, 120 mm
    p1, p2, _ = _views_of(snout, fork, calib)
    astray = p2.copy()
    astray[2:, 0] += np.linspace(-4.0, 4.0, len(p2) - 2)               # +-4 px of disparity along it
    solid = _solid_of(calib, p1, astray)
    X, _, length_mm, tilt = _on_axis(calib, np.array([0.0, 0.0, 1.0]), solid, p1, astray, np.ones(len(p1), bool))
    c, d = fit_axis(solid[0])
    assert np.degrees(np.arcsin(abs(d[2]))) > AXIS_TILT_EXCESS + 5        # the line did go astray
    assert np.allclose(X[0], snout, atol=0.5) and np.allclose(X[1], fork, atol=0.5)
    assert tilt < 0.5 and abs(length_mm - 120.0) < 1.0


@pytest.mark.parametrize("heading_deg", [0, 45, 90, 135])
def test_a_sound_line_keeps_an_end_whose_own_disparity_is_off(heading_deg):
    """The other way round: the midline right, one end's right pixel 1 px off along x (~5 mm of
    depth at 1.2 m): the line is kept and places that end within a millimetre."""
    from vision.surface import _on_axis
    calib = top_rig().calibration()
    h = np.radians(heading_deg)
    centre, half = np.array([-40.0, 10.0, -150.0]), 60.0 * np.array([np.cos(h), np.sin(h), 0.0])
    snout, fork = centre + half, centre - half
    p1, p2, _ = _views_of(snout, fork, calib)
    off = p2.copy()
    off[0, 0] += 1.0
    solid = _solid_of(calib, p1, off)
    assert np.linalg.norm(solid[0][0] - snout) > 3.0                  # the end's own point is off
    X, _, length_mm, tilt = _on_axis(calib, np.array([0.0, 0.0, 1.0]), solid, p1, off, np.ones(len(p1), bool))
    assert np.linalg.norm(X[0] - snout) < 1.0 and np.allclose(X[1], fork, atol=0.5)
    assert tilt < 0.5


@pytest.mark.parametrize("heading_deg", [60, 90, 120])
def test_a_placed_fork_one_view_misplaces_is_not_taken_whole(monkeypatch, heading_deg):
    """A fork placed from the fin base (no notch seen) is no feature both views see. The left view's
    is put 5 % of the length short of the truth (over FORK_MEAN_GAP: the views are not averaged) and
    the right's left true: the 3-D fork lies between them along the fish, not at the left's."""
    import dataclasses

    import vision.surface as surface
    from tests.vision.test_surface_drawing import stereo_tank
    from vision.survey_types import SurveySetup
    left, right, rig, truths = stereo_tank(np.random.default_rng(4), [dict(
        length_mm=130.0, snout_xy=(-40.0, 30.0), heading=np.radians(heading_deg), depth_mm=150.0)])
    snout_mm, fork_mm, snout_px, fork_px = truths[0]
    found = surface._fish_in
    views = []

    def placed(img, c, params, ratio):
        fish = [dataclasses.replace(f, fork_seen=False) for f in found(img, c, params, ratio)]
        side = len(views)
        views.append(fish)
        for f in fish:
            f.fork = fork_px[side] + (0.05 * (snout_px[side] - fork_px[side]) if side == 0 else 0.0)
        return fish

    monkeypatch.setattr(surface, "_fish_in", placed)
    measured = surface.surface_stages(left, right, rig.calibration(), SurveySetup(setup="surface",
                                      up_world=(0.0, 0.0, 1.0)))["measured"]
    assert len(measured) == 1
    L = np.linalg.norm(snout_mm - fork_mm)
    along = (measured[0].fork_mm - fork_mm) @ (snout_mm - fork_mm) / L / L
    assert 0.01 < along < 0.035, along           # the left's alone: 0.05
