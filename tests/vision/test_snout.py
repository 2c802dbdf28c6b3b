"""Snouts: found from the fork's position and axis along drawn fish (edge profile, then the tip across
the axis), compared with the simpler profile rules it replaced."""
from __future__ import annotations

import numpy as np
import pytest

from tests.vision.fish_drawing import draw_fish_2d, water
from vision.fork import pyramid
from vision.snout import find_snouts, refine_tips


def drawn(rng, fish, size=(700, 1000)):
    img = water(*size, rng)
    snouts = [draw_fish_2d(img, xy, a, L, v) for xy, a, L, v in fish]
    return np.clip(img, 0, 255).astype(np.uint8), np.array(snouts)


FISH = [((150, 200), 0.05, 400, 40.0), ((800, 500), np.pi - 0.1, 300, 220.0), ((200, 560), -0.15, 250, 200.0)]


def levels(img, fish):
    """Water and fish grey levels as the fork location measures them: behind and just ahead of it."""
    water_lv, fish_lv = [], []
    for (x, y), a, L, _ in fish:
        ax = np.array([np.cos(a), np.sin(a)])
        w = np.round(np.array([x, y]) - 0.1 * L * ax).astype(int)
        f = np.round(np.array([x, y]) + 0.05 * L * ax).astype(int)
        water_lv.append([float(img[w[1], w[0]])])
        fish_lv.append([float(img[f[1], f[0]])])
    return np.array(fish_lv), np.array(water_lv)


@pytest.mark.parametrize("angle_error_deg", [0.0, 4.0, -4.0])
def test_snout_tip_within_one_percent_of_the_length(angle_error_deg):
    """The fin's axis is a few degrees off in practice: the tip must still be found, across the axis
    as well as along it."""
    rng = np.random.default_rng(1)
    img, truth = drawn(rng, FISH)
    xy = np.array([f[0] for f in FISH], float)
    L = np.array([f[2] for f in FISH], float)
    angle = np.array([f[1] for f in FISH]) + np.radians(angle_error_deg)
    fish_lv, water_lv = levels(img, FISH)
    sn = find_snouts(pyramid(img), xy, angle, 0.025 * L, fish_lv, water_lv, 0.3 * L, 2.0 * L)
    best = sn.xy[:, 0]
    err = np.linalg.norm(best - truth, axis=1) / L
    assert err.max() < 0.01, err


def test_no_snout_where_the_fish_runs_out_of_the_frame():
    rng = np.random.default_rng(2)
    img, truth = drawn(rng, [((700, 300), 0.0, 500, 40.0)])        # snout at u = 1200: off a 1000 px frame
    fish_lv, water_lv = levels(img, [((700, 300), 0.0, 500, 40.0)])
    sn = find_snouts(pyramid(img), np.array([[700.0, 300.0]]), np.array([0.0]), np.array([12.0]), fish_lv,
                     water_lv, np.array([150.0]), np.array([1000.0]))
    assert np.isnan(sn.dist_px[0, 0]) or sn.xy[0, 0, 0] < 990 - 0.5 * 500   # never the frame's edge


def test_candidates_are_ranked_and_apart():
    rng = np.random.default_rng(3)
    # a second fish right ahead of the first: its snout is a later candidate, not the first
    fish = [((100, 300), 0.0, 300, 40.0), ((480, 300), 0.0, 300, 40.0)]
    img, truth = drawn(rng, fish)
    fish_lv, water_lv = levels(img, fish[:1])
    sn = find_snouts(pyramid(img), np.array([[100.0, 300.0]]), np.array([0.0]), np.array([8.0]), fish_lv, water_lv,
                     np.array([90.0]), np.array([800.0]))
    assert np.linalg.norm(sn.xy[0, 0] - truth[0]) < 3
    assert np.all(np.diff(sn.strength[0][sn.strength[0] > 0]) <= 0)
    assert np.nanmin(np.abs(np.diff(sn.dist_px[0]))) > 20


def test_refine_tips_moves_an_off_axis_point_onto_the_tip():
    rng = np.random.default_rng(4)
    img, truth = drawn(rng, FISH[:1])
    start = truth[0] + np.array([-3.0, 12.0])                      # on the body's front edge, below the tip
    tips, ok = refine_tips(pyramid(img), start[None], np.array([0.05]), np.array([400.0]),
                           np.array([[float(img[200, 60])]]), np.array([100.0]))
    assert ok[0]
    assert np.linalg.norm(tips[0] - truth[0]) < 2.0


def test_a_dark_band_across_the_body_stops_the_first_crossing_rule_but_not_ours():
    """The alternative measured against: the first fish-to-water crossing after the fork stops at any
    band across the body (bars, a shade); the fraction score keeps going to the real end."""
    rng = np.random.default_rng(5)
    img = water(400, 800, rng, top=100, bottom=100)
    snout = draw_fish_2d(img, (100, 200), 0.0, 400, 200.0)
    img[150:250, 300:312] = 100.0                                  # a water-coloured bar across the body
    img = np.clip(img, 0, 255).astype(np.uint8)
    fish_lv, water_lv = np.array([[200.0]]), np.array([[100.0]])
    sn = find_snouts(pyramid(img), np.array([[100.0, 200.0]]), np.array([0.0]), np.array([10.0]), fish_lv,
                     water_lv, np.array([120.0]), np.array([800.0]))
    assert np.linalg.norm(sn.xy[0, 0] - snout) < 4
    profile = img[200, 100 + 40:].astype(float)                    # past the fin
    first_crossing = 100 + 40 + int(np.argmax(profile < 150))
    assert abs(first_crossing - 300) < 3                           # the rule we did not use stops at the bar


def test_median_across_five_rows_is_numpys_median_with_nan_where_any_is_nan():
    from vision.snout import median_across
    rng = np.random.default_rng(4)
    band = rng.integers(0, 5, (40, 5, 30, 3)).astype(np.float32)       # many ties
    band[3, 2, 7, 1] = np.nan
    want = np.median(band, axis=1)
    assert np.array_equal(median_across(band), want, equal_nan=True)
    assert np.array_equal(median_across(band[:, :3]), np.median(band[:, :3], axis=1), equal_nan=True)
