"""The pond's geometry: bad outlines and keep-outs refused by name; the reachable floor as defined."""
from __future__ import annotations

import math

import pytest
from shapely.geometry import Point

from controller.cleaning.geometry import disc, pond_geometry
from controller.errors import BadInput

POND = [(0, 0), (20, 0), (20, 10), (0, 10)]
R, B = 0.35, 0.5


@pytest.mark.parametrize(("outline", "fault"), [
    ([(0, 0), (5, 0)], "at least 3"),
    ([(0, 0), (5, 0), (5, 0), (0, 0)], "at least 3"),
    ([(0, 0), (5, 5), (5, 0), (0, 5)], "crosses itself"),                 # a bow tie
    ([(0, 0), (10, 0), (10, 5), (4, -2), (0, 5)], "crosses itself"),
    ([(0, 0), (1, 1), (2, 2), (3, 3)], "zero area"),
    ([(0, 0), (5, 0), (2, 0), (2, 2)], "crosses itself"),                 # doubles back on its edge
    ([(0, 0), (5, 0), (math.nan, 5)], "finite"),
    ([(0, 0), (math.inf, 0), (5, 5)], "finite"),
    ([(0, 0, 0), (5, 0, 0), (5, 5, 0)], "[x, y] points"),
    ("pond", "[x, y] points"),
])
def test_bad_outlines_are_refused_by_name(outline, fault):
    with pytest.raises(BadInput) as err:
        pond_geometry(outline, where="farm.toml", key="cleaning.outline")
    assert str(err.value).startswith("farm.toml: cleaning.outline: ") and fault in str(err.value)


@pytest.mark.parametrize(("keepouts", "index", "fault"), [
    ([[(25, 2), (26, 2), (26, 3)]], 0, "outside the pond"),
    ([[(20, 2), (21, 2), (21, 3), (20, 3)]], 0, "outside the pond"),      # touches the wall from outside
    ([[(19, 2), (21, 2), (21, 3), (19, 3)]], 0, "crosses the pond's edge"),
    ([disc(5, 5, 1), disc(5.5, 5, 1)], 1, "overlaps cleaning.keepouts[0]"),
    ([disc(5, 5, 1), disc(15, 5, 1), [(14, 4), (16, 4), (15, 6)]], 2, "overlaps cleaning.keepouts[1]"),
    ([disc(5, 5, 1), [(1, 1), (2, 1), (1, 1)]], 1, "at least 3"),
])
def test_bad_keepouts_are_refused_by_name(keepouts, index, fault):
    with pytest.raises(BadInput) as err:
        pond_geometry(POND, keepouts, where="farm.toml")
    assert str(err.value).startswith(f"farm.toml: cleaning.keepouts[{index}]: ") and fault in str(err.value)


def test_keepouts_touching_the_wall_from_inside_or_each_other_are_accepted():
    g = pond_geometry(POND, [[(0, 0), (1, 0), (1, 1), (0, 1)], [(1, 0), (2, 0), (2, 1), (1, 1)]])
    assert len(g.keepouts) == 2
    closed = pond_geometry([*POND, POND[0]])                             # a closed ring is fine
    assert closed.outline.area == pytest.approx(200)


def test_reachable_floor_of_a_rectangle_is_the_inset_rectangle_with_rounded_corners():
    w, h = 20 - 2 * R, 10 - 2 * R                                        # where the centre may be
    expected = w * h + B * (w + h) + math.pi * (B / 2) ** 2              # grown by B/2 all round
    assert pond_geometry(POND).reachable(R, B).area == pytest.approx(expected, rel=2e-3)


def test_reachable_floor_keeps_the_brush_off_the_keepouts_and_out_of_the_robots_way():
    g = pond_geometry(POND, [disc(10, 5, 1.0, points=128)])
    reach = g.reachable(R, B)
    ring = 1.0 + R - B / 2                          # nearest the brush's edge gets to the disc's centre
    for a in range(0, 360, 30):
        c, s = math.cos(math.radians(a)), math.sin(math.radians(a))
        assert not reach.contains(Point(10 + (ring - 0.03) * c, 5 + (ring - 0.03) * s))
        assert reach.contains(Point(10 + (ring + 0.03) * c, 5 + (ring + 0.03) * s))
    assert not reach.contains(Point(R - B / 2 - 0.03, 5)) and reach.contains(Point(R - B / 2 + 0.03, 5))


def test_only_the_largest_piece_counts_when_a_keepout_cuts_the_pond():
    # a keep-out leaving a 0.5 m gap at the wall: too narrow for a 0.7 m robot to pass
    g = pond_geometry(POND, [[(6, 0.5), (7, 0.5), (7, 10), (6, 10)]])
    free, reach = g.free(R), g.reachable(R, B)
    assert free.geom_type == "Polygon" and free.contains(Point(15, 5)) and not free.contains(Point(3, 5))
    assert not reach.contains(Point(3, 5))


def test_a_robot_too_big_for_the_pond_reaches_nothing():
    g = pond_geometry([(0, 0), (0.6, 0), (0.6, 0.6), (0, 0.6)])
    assert g.free(R).is_empty and g.reachable(R, B).is_empty


@pytest.mark.parametrize("corners", [3, 5, 8, 12, 16, 23, 24, 25, 31, 40, 64, 100])
@pytest.mark.parametrize("r", [0.2, 0.35, 0.6])
def test_the_free_space_keeps_the_body_r_clear_of_every_keepout_and_wall_whatever_its_corners(corners, r):
    """Round keep-outs come as polygons of any corner count; their corners' angles are anything
    (hypothesis found a 24-sided disc whose 15 degree corners let the body 1.3 mm in)."""
    from shapely.geometry import Polygon
    keep = Polygon([(6 + 0.84 * math.cos(a), 5 + 0.84 * math.sin(a))
                    for a in (2 * math.pi * k / corners + 0.1 for k in range(corners))])
    # a star-shaped wall: reflex corners of every angle, where the body's arc is drawn inward
    n = max(corners, 6) // 2 * 2
    wall = [(6 + (4.5 if k % 2 else 3.2) * math.cos(2 * math.pi * k / n), 5 + (4.5 if k % 2 else 3.2)
             * math.sin(2 * math.pi * k / n)) for k in range(n)]
    outline = Polygon(wall)
    geom = pond_geometry(list(outline.exterior.coords), [list(keep.exterior.coords)])
    free = geom.free(r)
    assert not free.is_empty
    assert free.distance(keep) >= r - 1e-9
    assert outline.exterior.distance(free) >= r - 1e-9 and outline.covers(free)
