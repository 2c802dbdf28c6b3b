"""The renderer's fill against a polygon's exact area: OpenCV's fill covers ~0.5 px beyond every
edge (what makes rendered fish read long: issues 7 and 10); ``fish_render.COVERAGE`` (diagnostics)
draws a fish's area coverage instead, its own fill's half sub-pixel taken back
(``fish_render.EXACT_EDGES``)."""
from __future__ import annotations

import cv2
import numpy as np

from devices.sim import fish_render
from devices.sim.fish_render import SHIFT, _coverage


def _squares(rng: np.random.Generator, n: int = 20):
    """(x0, y0, side) of squares at random sub-pixel places, and their vertices in fixed point."""
    for _ in range(n):
        x0, y0 = rng.uniform(5, 15, 2)
        side = rng.uniform(6, 12)
        pts = np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]])
        fixed = np.rint(pts * (1 << SHIFT)).astype(np.int32)
        exact = fixed / (1 << SHIFT)                  # the square the fixed-point vertices draw
        yield exact[0, 0], exact[0, 1], exact[1, 0] - exact[0, 0], fixed[None]


def test_opencv_fill_overshoots_by_half_a_pixel_all_round():
    rng = np.random.default_rng(3)
    grown = []
    for _, _, side, tri in _squares(rng):
        img = np.zeros((32, 32), np.uint8)
        cv2.fillPoly(img, tri, 255, lineType=cv2.LINE_8, shift=SHIFT)
        grown.append(np.count_nonzero(img) ** 0.5 - side)
    assert 0.8 < np.mean(grown) < 1.2          # the side reads ~1 px long: 0.5 px each edge


def _rotated_squares(rng: np.random.Generator, n: int = 60):
    """(exact area, perimeter, vertices in fixed point) of squares turned to any angle."""
    for _ in range(n):
        centre, side, turn = rng.uniform(12, 20, 2), rng.uniform(4, 12), rng.uniform(0, np.pi / 2)
        rot = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
        pts = centre + (np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * side / 2) @ rot.T
        fixed = np.rint(pts * (1 << SHIFT)).astype(np.int32)
        x, y = (fixed / (1 << SHIFT)).T
        area = 0.5 * abs(x @ np.roll(y, 1) - y @ np.roll(x, 1))
        yield area, float(np.hypot(x - np.roll(x, 1), y - np.roll(y, 1)).sum()), fixed[None]


def _edge_offsets(monkeypatch, s: int, exact: bool) -> np.ndarray:
    """Per square, how far out of its true outline the coverage's edges lie on average (px)."""
    monkeypatch.setattr(fish_render, "EXACT_EDGES", exact)
    return np.array([(_coverage((32, 32), tri, s).sum() - area) / perimeter
                     for area, perimeter, tri in _rotated_squares(np.random.default_rng(5))])


def test_coverage_is_the_area_and_the_edges_where_they_are():
    rng = np.random.default_rng(4)
    for s in (4, 8):
        for x0, y0, side, tri in _squares(rng):
            cov = _coverage((32, 32), tri, s)
            # the area: each side within the half sub-pixel the fill rounds vertices to
            assert abs(cov.sum() - side * side) < 2 * side * 0.55 / s
            # the left edge: the row through the middle, pixel centres at integers
            row = cov[int(round(y0 + side / 2))]
            left = np.flatnonzero(row > 0)[0]
            edge = left + 0.5 - row[left]                                  # where coverage starts
            assert abs(edge - x0) < 1.0 / s


def test_coverage_edges_are_where_they_are_at_every_angle(monkeypatch):
    # the fill alone lies half a sub-pixel along the edge's major axis outside it (0.09-0.125 px at
    # 4x4, what read small fish long); with the overshoot taken back, within ~0.005 px at any angle
    for s in (4, 8):
        raw, exact = _edge_offsets(monkeypatch, s, False), _edge_offsets(monkeypatch, s, True)
        assert 0.35 / s < raw.mean() < 0.5 / s + 0.01
        assert abs(exact.mean()) < 0.01
        assert np.abs(exact).max() < 0.3 / s


def test_coverage_switch_draws_fish_no_bigger_than_their_outline():
    # the same scene drawn both ways: with coverage, each fish's drawn area is smaller by about
    # half a pixel times its outline (OpenCV's overshoot), never larger
    from devices.sim.fish_scene import underwater_rig, underwater_scene
    rig = underwater_rig(image_size=(320, 240), focal_px=350.0)
    cond = dict(n_fish=1, blur_gain=0.0, noise_sd=0.0, jpeg_quality=None, clutter="none", bubbles=0,
                particles=0, vignette=0.0, sun_rays=0.0, fish_gain=2.0)
    dark, default = [], fish_render.COVERAGE
    try:
        for cov in (1, 8):
            fish_render.COVERAGE = cov
            sc = underwater_scene(np.random.default_rng(11), rig, **cond)
            dark.append(sc.left.astype(float))
    finally:
        fish_render.COVERAGE = default
    empty = underwater_scene(np.random.default_rng(11), rig, **(cond | {"n_fish": 0})).left.astype(float)
    drawn = [np.abs(d - empty).sum() for d in dark]
    assert drawn[1] < drawn[0]
