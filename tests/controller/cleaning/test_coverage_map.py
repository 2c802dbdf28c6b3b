"""The coverage map: what a sweep cleans (cells whose centre the brush passed), coverage of the
reachable floor, the overlap measure, the bytes for the store, the image."""
from __future__ import annotations

import math

import numpy as np
import pytest

from controller.cleaning.coverage_map import CLEAN, DIRTY, OUT_OF_REACH, CoverageMap
from controller.cleaning.geometry import disc, pond_geometry

POND = [(0, 0), (20, 0), (20, 10), (0, 10)]
R, B, CELL = 0.35, 0.5, 0.1
GEOM = pond_geometry(POND, [disc(14, 6, 0.75)])


def fresh(**kw) -> CoverageMap:
    return CoverageMap(GEOM, cell_m=CELL, brush_m=B, body_radius_m=R, **kw)


def centres():
    x, y = np.meshgrid((np.arange(200) + 0.5) * CELL, (np.arange(100) + 0.5) * CELL)
    return x, y


@pytest.mark.parametrize(("y", "h"), [(5.0, 0.0), (5.03, 0.0), (4.97, 0.4), (3.21, -1.1)])
def test_a_sweep_cleans_the_cells_whose_centre_the_brush_passed(y, h):
    m = fresh()
    x0, y0 = 3.0, y
    x1, y1 = x0 + 6 * math.cos(h), y0 + 6 * math.sin(h)
    m.sweep(x0, y0, x1, y1)
    x, yy = centres()
    along = (x - x0) * math.cos(h) + (yy - y0) * math.sin(h)
    across = -(x - x0) * math.sin(h) + (yy - y0) * math.cos(h)
    inside = (along >= -1e-9) & (along <= 6 + 1e-9) & (np.abs(across) <= B / 2 + 1e-9)
    assert np.array_equal(m.cleaned(), inside)


def test_a_crabbing_brush_cleans_the_parallelogram_its_bar_traces():
    m, h = fresh(), math.radians(40)                                  # faces 40 deg off its course (+x)
    m.sweep(2, 5.02, 10, 5.02, h, h)
    x, y = centres()
    b = (y - 5.02) / (B * math.cos(h))                                # along the bar, in brush widths
    a = (x - 2 + b * B * math.sin(h)) / 8                             # along the travel
    inside = (np.abs(b) <= 0.5 + 1e-9) & (a >= -1e-9) & (a <= 1 + 1e-9)
    assert np.array_equal(m.cleaned(), inside)
    assert inside.sum() < 0.85 * 8 * B / CELL**2                      # narrower than heading where it goes


def test_turning_on_the_spot_sweeps_the_brush_round():
    m = fresh()
    m.sweep(5, 5, 5, 5, 0.0, math.pi / 2)
    assert m.cleaned().sum() > 0 and m.odometer_m == 0.0
    assert fresh().sweep(5, 5, 5, 5) == 0.0                           # no motion, no heading: nothing


def test_overlap_counts_sweeps_over_floor_cleaned_before_not_the_brush_under_itself():
    m = fresh()
    xs = np.arange(2, 12.001, 0.03)                                  # a lane in small steps, at 10 Hz
    for a, b in zip(xs, xs[1:], strict=False):
        assert m.sweep(a, 5, b, 5) <= 0.5
    assert m.overlap() == 0.0
    for a, b in zip(xs[::-1], xs[::-1][1:], strict=False):           # the same lane back
        m.sweep(a, 5, b, 5)
    assert m.overlap() == pytest.approx((10 - B) / 20, abs=0.01)      # all but its first brush width
    for a, b in zip(xs, xs[1:], strict=False):                       # the next lane, 5 % overlapping
        m.sweep(a, 5 + B * 0.95, b, 5 + B * 0.95)
    assert m.overlap() == pytest.approx((10 - B) / 30, abs=0.01)


@pytest.mark.parametrize("askew_deg", [0.0, 5.0, -5.0])
def test_a_crabbing_robot_in_small_steps_beside_the_last_lane_is_not_overlap(askew_deg):
    # 8 mm steps (50 Hz at 0.4 m/s), the bar a few degrees askew, 0.463 m below the last lane: judged
    # one step at a time, the one row of five shared with that lane made most of this lane "overlap"
    m = fresh()
    h = math.pi + math.radians(askew_deg)
    xs = np.arange(2, 12.001, 0.008)
    for a, b in zip(xs, xs[1:], strict=False):
        m.sweep(a, 7.779, b, 7.779, 0.0, 0.0)
    for a, b in zip(xs[::-1], xs[::-1][1:], strict=False):
        m.sweep(a, 7.316, b, 7.316, h, h)
    assert m.overlap() < 0.01


def test_coverage_is_of_the_reachable_floor_only():
    m = fresh()
    reach = GEOM.reachable(R, B)
    x, y = centres()
    assert m.reachable.sum() == pytest.approx(reach.area / CELL**2, rel=0.01)
    assert m.coverage() == 0.0
    for yy in np.arange(0.2, 10, 0.4):                               # mow everything, walls and keep-out too
        m.sweep(-1, yy, 21, yy)
    assert m.coverage() == 1.0
    half = fresh()
    for yy in np.arange(0.2, 5, 0.4):
        half.sweep(-1, yy, 21, yy)
    expected = np.count_nonzero(m.reachable & (y <= 4.6 + B / 2)) / np.count_nonzero(m.reachable)
    assert half.coverage() == pytest.approx(expected, abs=0.01)


def test_bytes_carry_the_whole_map_and_refuse_another_pond():
    m = fresh()
    m.sweep(2, 5, 9, 5)
    m.sweep(9, 5, 2, 5)
    back = CoverageMap.from_bytes(GEOM, m.to_bytes(), cell_m=CELL, brush_m=B, body_radius_m=R)
    assert np.array_equal(back.first_m, m.first_m)
    assert (back.coverage(), back.overlap(), back.odometer_m) == (m.coverage(), m.overlap(), m.odometer_m)
    other = pond_geometry([(0, 0), (21, 0), (21, 10), (0, 10)])
    with pytest.raises(ValueError, match="another pond"):
        CoverageMap.from_bytes(other, m.to_bytes(), cell_m=CELL, brush_m=B, body_radius_m=R)
    with pytest.raises(ValueError, match="another pond"):
        CoverageMap.from_bytes(GEOM, m.to_bytes(), cell_m=CELL, brush_m=0.6, body_radius_m=R)
    for junk in (b"", b"hello", m.to_bytes()[:-10], m.to_bytes()[:20]):
        with pytest.raises(ValueError):
            CoverageMap.from_bytes(GEOM, junk, cell_m=CELL, brush_m=B, body_radius_m=R)


def test_image_has_north_up_and_says_what_each_cell_is():
    m = fresh()
    m.sweep(2, 9, 8, 9)                                              # along the north side
    img = m.image()
    assert img.shape == (100, 200) and img.dtype == np.uint8
    assert img[10, 50] == CLEAN and img[90, 50] == DIRTY             # row 10 is y = 8.95 m
    assert img[40, 140] == OUT_OF_REACH or img[40, 140] == 0         # the feeder's foot at (14, 6)
    assert img[99, 0] == OUT_OF_REACH                                # the corner no brush reaches
