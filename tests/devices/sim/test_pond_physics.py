"""The cleaning robot's physics: thrust and drag, turning, a current that crabs it, a floor that grips
its held tracks, walls that hold it."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from shapely.geometry import Point, Polygon

from devices.sim.pond_physics import CleanerParams, PondRobot

POND = [(0, 0), (20, 0), (20, 10), (0, 10)]
CALM = CleanerParams(slip=0.0, force_noise_n=0.0)


def run(robot: PondRobot, seconds: float, left: float, right: float, dt: float = 0.1) -> None:
    for _ in range(round(seconds / dt)):
        robot.step(dt, left, right)


def test_equal_thrust_in_still_water_runs_straight_at_thrust_over_drag():
    r = PondRobot(CALM, POND, 2, 5, 0.0)
    run(r, 20, 0.5, 0.5)
    speed = 2 * CALM.max_thrust_n * 0.5 / CALM.drag
    assert math.hypot(r.vx, r.vy) == pytest.approx(speed, rel=1e-3)
    assert r.y == pytest.approx(5) and r.heading == pytest.approx(0) and r.x > 2 + 0.9 * 20 * speed


@pytest.mark.parametrize(("left", "right", "sign"), [(0.0, 0.6, 1), (0.6, 0.0, -1), (-0.5, 0.5, 1), (0.5, -0.5, -1)])
def test_more_thrust_on_the_right_turns_it_left(left, right, sign):
    r = PondRobot(CALM, POND, 10, 5, 0.0)
    run(r, 1.0, left, right)
    assert sign * r.heading > 0.1 and sign * r.omega > 0


def test_spinning_on_the_spot_settles_at_torque_over_yaw_drag():
    r = PondRobot(CALM, POND, 10, 5, 0.0)
    run(r, 5.0, -1.0, 1.0)
    assert r.omega == pytest.approx(CALM.max_thrust_n * CALM.track_m / CALM.yaw_drag, rel=1e-3)
    assert math.hypot(r.x - 10, r.y - 5) < 1e-9                    # no translation


def test_a_cross_current_crabs_it_heading_one_way_moving_another():
    current = (0.0, 0.06)
    r = PondRobot(replace(CALM, current_m_s=current), POND, 2, 3, 0.0)
    run(r, 30, 0.6, 0.6)
    course = math.atan2(r.vy, r.vx)
    assert abs(r.heading) < 1e-9                                      # no torque: it still faces +x
    surge = 2 * CALM.max_thrust_n * 0.6 / CALM.drag
    assert course == pytest.approx(math.atan2(current[1], surge), abs=1e-3)   # but travels up-stream-skewed
    assert r.y > 3 + 0.8 * 30 * current[1]


@pytest.mark.parametrize("heading", [0.0, 1.0, math.pi / 2, -2.5])
def test_with_its_drive_off_the_floor_holds_it_in_the_current(heading):
    # the old model let it go with the water at the current's full speed: that drift is what the grip removes
    r = PondRobot(replace(CleanerParams(), current_m_s=(0.04, 0.02)), POND, 10, 5, heading, seed=2)
    run(r, 120, 0.0, 0.0)
    assert (r.x, r.y, r.heading) == (10, 5, pytest.approx(heading)) and (r.vx, r.vy, r.omega) == (0, 0, 0)


def test_commands_inside_the_deadband_leave_the_tracks_held():
    r = PondRobot(replace(CALM, current_m_s=(0.0, 0.04)), POND, 10, 5, 0.0)
    run(r, 30, 0.04, -0.04)
    assert (r.x, r.y, r.heading) == (10, 5, 0.0)


def test_a_current_stronger_than_the_grip_still_drags_it_slower_than_the_water():
    water = (0.0, 0.5)              # 0.5 m/s across: 120 N on the body against 50 N of grip
    r = PondRobot(replace(CALM, current_m_s=water), POND, 10, 2, 0.0)
    run(r, 5, 0.0, 0.0)
    held = CALM.grip_kinetic * CALM.submerged_weight_n
    assert r.vx == pytest.approx(0, abs=1e-9) and r.vy == pytest.approx(water[1] - held / CALM.sway_drag, rel=1e-2)


def test_stopped_from_cruise_it_skids_to_a_halt_and_stays():
    r = PondRobot(replace(CALM, current_m_s=(0.04, 0.02)), POND, 5, 5, 0.3)
    run(r, 10, 1.0, 1.0)
    x, y = r.x, r.y
    run(r, 2, 0.0, 0.0)
    skid = math.hypot(r.x - x, r.y - y)
    assert 0.02 < skid < 0.2 and (r.vx, r.vy) == (0, 0)
    run(r, 60, 0.0, 0.0)
    assert math.hypot(r.x - x, r.y - y) == pytest.approx(skid, abs=1e-12)


def test_a_held_robot_stops_turning():
    r = PondRobot(CALM, POND, 10, 5, 0.0)
    run(r, 3, -1.0, 1.0)
    run(r, 1, 0.0, 0.0)
    h = r.heading
    run(r, 5, 0.0, 0.0)
    assert r.omega == 0 and r.heading == h


@pytest.mark.parametrize(("x", "y", "heading"), [(18, 5, 0.0), (10, 1, -math.pi / 2), (1.5, 8, 2.6), (19, 9, 0.7)])
def test_walls_hold_the_whole_body_inside_the_pond(x, y, heading):
    params = CleanerParams(current_m_s=(0.05, 0.05))
    r = PondRobot(params, POND, x, y, heading, seed=3)
    pond, bumped = Polygon(POND), False
    for _ in range(600):
        r.step(0.1, 1.0, 0.9)
        bumped |= r.bumped
        assert pond.contains(Point(r.x, r.y).buffer(params.body_radius_m - 1e-9))
    assert bumped and r.bumps > 0


def test_at_a_wall_it_slides_along_it():
    r = PondRobot(CALM, POND, 10, 9.6, math.radians(60))           # 5 cm from the wall, pushing into it
    run(r, 10, 1.0, 1.0)
    assert r.bumps > 0 and r.x > 10 + 0.3                           # it went on along the wall
    assert 10 - r.y >= CALM.body_radius_m - 1e-9


def test_same_seed_same_run_other_seed_other_run():
    def trace(seed):
        r = PondRobot(CleanerParams(), POND, 5, 5, 0.3, seed=seed)
        out = []
        for _ in range(100):
            r.step(0.1, 0.7, 0.5)
            out.append((r.x, r.y, r.heading))
        return np.array(out)
    assert np.array_equal(trace(4), trace(4)) and not np.allclose(trace(4), trace(5))


def test_slip_loses_thrust_never_gains_it():
    r = PondRobot(replace(CALM, slip=0.2), POND, 2, 5, 0.0, seed=1)
    run(r, 20, 0.5, 0.5)
    assert math.hypot(r.vx, r.vy) < 2 * CALM.max_thrust_n * 0.5 / CALM.drag


def test_commands_are_clipped_and_a_robot_outside_the_pond_is_refused():
    a, b = PondRobot(CALM, POND, 5, 5, 0.0), PondRobot(CALM, POND, 5, 5, 0.0)
    run(a, 5, 3.0, 3.0)
    run(b, 5, 1.0, 1.0)
    assert (a.x, a.y) == (b.x, b.y)
    with pytest.raises(ValueError):
        PondRobot(CALM, POND, 0.1, 5, 0.0)
