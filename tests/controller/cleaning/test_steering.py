"""The path follower on an ideal differential-drive robot (kinematics written here, not the pond
physics): it drives the path to its end, never skips a lane, resumes from its saved progress,
holds its lane against a drift, and its commands stay in [-1, 1]."""
from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import LineString

from controller.cleaning.steering import CORNER_REACH_M, PathFollower

V_MAX, W_MAX, DT = 0.4, 1.0, 0.1          # m/s at full thrust both sides, rad/s full differential


def lanes(n=4, length=10.0, gap=0.5, step=0.25) -> np.ndarray:
    pts = []
    for k in range(n):
        xs = np.arange(0, length + 1e-9, step)
        xs = xs if k % 2 == 0 else xs[::-1]
        pts.extend((x, k * gap) for x in xs)
    return np.array(pts)


def drive(f: PathFollower, pose, seconds=600.0, drift=(0.0, 0.0)):
    x, y, h = pose
    trace, progress = [], []
    for _ in range(int(seconds / DT)):
        left, right = f.command(x, y, h)
        assert -1 <= left <= 1 and -1 <= right <= 1
        if f.done:
            break
        v, w = V_MAX * (left + right) / 2, W_MAX * (right - left) / 2
        x, y = x + DT * (v * math.cos(h) + drift[0]), y + DT * (v * math.sin(h) + drift[1])
        h = math.remainder(h + DT * w, 2 * math.pi)
        trace.append((x, y))
        progress.append(f.progress)
    return np.array(trace), np.array(progress)


def lateral(trace: np.ndarray, path: np.ndarray) -> np.ndarray:
    return shapely.distance(LineString(path), shapely.points(trace))


def test_drives_the_whole_path_in_order_and_close_to_it():
    path = lanes()
    f = PathFollower(path)
    trace, progress = drive(f, (0, 0, 0))
    assert f.done and f.progress == len(path) - 1
    assert np.all(np.diff(progress) >= 0)                          # progress never goes back
    assert set(f.corners[:-1]) <= set(progress)                     # every lane end was reached, none skipped
    lane = np.abs(trace[:, 1] - np.round(trace[:, 1] / 0.5) * 0.5)
    off = lateral(trace, path)
    assert np.percentile(off, 90) < 0.05 and off.max() <= CORNER_REACH_M + 0.01 and lane.max() < 0.25


def test_a_drift_across_the_lanes_is_held_off_by_the_integral():
    path = np.array([(x, 0.0) for x in np.arange(0, 30.01, 0.25)])
    held, _ = drive(PathFollower(path), (0, 0, 0), drift=(0.0, 0.03))
    loose, _ = drive(PathFollower(path, integral_gain=0.0), (0, 0, 0), drift=(0.0, 0.03))
    late = slice(len(held) // 2, None)
    assert np.abs(held[late, 1]).max() < 0.03 < np.abs(loose[len(loose) // 2:, 1]).mean()


def test_resume_takes_the_nearest_point_ahead_on_the_same_lane():
    path = lanes()
    saved = int(np.flatnonzero((path[:, 0] == 3.0) & (path[:, 1] == 0.0))[0])
    f = PathFollower(path, start_index=saved)
    f.command(6.0, 0.05, 0.0)
    assert tuple(path[f.progress]) == (6.0, 0.0)


@pytest.mark.parametrize("where", [(6.0, 0.45), (1.0, 0.5), (9.9, 1.0)])
def test_resume_never_skips_to_the_next_lane(where):
    path = lanes()
    saved = int(np.flatnonzero((path[:, 0] == 3.0) & (path[:, 1] == 0.0))[0])
    f = PathFollower(path, start_index=saved)
    f.command(*where, math.pi)
    assert path[f.progress][1] == 0.0 and f.progress >= saved       # still on the first lane
    trace, progress = drive(f, (*where, math.pi))
    assert f.done and set(f.corners[:-1]) <= {*progress, saved}


def test_slows_for_a_sharp_turn_and_spins_when_the_path_is_behind():
    path = lanes(n=2)
    mid, near = PathFollower(path, start_index=4), PathFollower(path, start_index=38)
    l1, r1 = mid.command(*path[4], 0.0)
    l2, r2 = near.command(*path[39], 0.0)                            # 0.25 m before the lane's end
    assert (l2 + r2) / 2 < 0.6 * (l1 + r1) / 2
    behind = PathFollower(path)
    left, right = behind.command(0.0, 0.0, math.pi)                  # facing away from the path
    assert left == pytest.approx(-right) and abs(left) > 0.3


@settings(max_examples=200, deadline=None)
@given(st.floats(-5, 15), st.floats(-5, 5), st.floats(-math.pi, math.pi), st.integers(0, 200))
def test_commands_stay_in_range_from_any_pose(x, y, h, start):
    f = PathFollower(lanes(), start_index=start)
    left, right = f.command(x, y, h)
    assert -1 <= left <= 1 and -1 <= right <= 1


def test_done_stops_and_bad_paths_are_refused():
    f = PathFollower([(0, 0), (1, 0)])
    assert f.command(1.0, 0.0, 0.0) == (0.0, 0.0) and f.done
    assert f.command(5.0, 5.0, 0.0) == (0.0, 0.0)
    with pytest.raises(ValueError):
        PathFollower([(0, 0), (math.nan, 1)])


def test_a_current_stronger_than_the_slowed_robot_does_not_stall_it_short_of_a_corner():
    path = lanes(n=2, length=4.0)
    f = PathFollower(path)
    _, progress = drive(f, (0, 0, 0), seconds=400, drift=(-0.09, 0.0))   # slowed near the corner: 0.07 m/s
    assert f.done and set(f.corners[:-1]) <= set(progress)


def test_a_waypoint_the_geofence_keeps_refusing_is_given_up_every_n_refusals():
    path = lanes(n=2, length=4.0)              # 0.25 m apart; the lane's end (a corner) at index 16
    f = PathFollower(path, skip_after=5, skip_max_m=10.0)
    pose = (3.0, -0.4, 0.0)                    # held off short of the corner, below the lane
    f.command(*pose)
    start = f.progress
    seen = []
    for n in range(1, 16):
        f.command(*pose, refused=n)
        seen.append(f.progress - start)
    assert seen == [0] * 4 + [1] * 5 + [2] * 5 + [3] and f.skipped == 3
    f.command(*pose, refused=0)                 # a command went through: nothing more is given up
    assert f.progress - start == 3


def test_giving_up_stops_at_skip_max_m_and_never_a_lane():
    path = lanes(n=3, length=4.0)
    f = PathFollower(path, skip_after=1, skip_max_m=1.5)
    pose = (3.8, -0.5, 0.0)
    f.command(*pose)
    for n in range(1, 200):
        f.command(*pose, refused=n)
    legs = np.diff(f.s)
    assert f.skipped == 5 and 1.25 <= sum(legs[13:16]) + legs[16] + legs[18] <= 1.5   # however long refused
    # the next lane (from index 17 on) is not given up: past the corner, the rest is to be driven
    assert 17 <= f.progress <= 17 + 4 and not f.done


def test_no_extra_thrust_while_the_geofence_refuses():
    path = lanes(n=1, length=10.0)
    stuck = (2.0, 0.0, 0.0)                    # no waypoint reached: 20 s of the same pose
    free, held = PathFollower(path), PathFollower(path, skip_after=10 ** 6)
    for n in range(200):
        a = free.command(*stuck)
        b = held.command(*stuck, refused=n + 1)
    assert a[0] == 1.0 and b[0] == pytest.approx(held.cruise, abs=0.05)   # boosted to full; held at cruise
