"""The geofence: a command whose predicted footprint enters a keep-out never goes through; far
from everything, commands pass unchanged; no fresh tracked pose, no drive."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from shapely.geometry import Point, Polygon

from controller.cleaning.geofence import STOP, Geofence
from vision.float_track import FloatTrack

POND = Polygon([(0, 0), (20, 0), (20, 10), (0, 10)])
DRAIN = Polygon([(5, 3), (6, 3), (6, 4), (5, 4)])
FEEDER = Point(14, 6).buffer(0.75)
BODY = 0.35


def fence(**kw):
    return Geofence(POND, (DRAIN, FEEDER), BODY, **kw)


def track(x, y, h, *, speed=0.0, std=0.02, t=10.0, state="tracking"):
    return FloatTrack(t, x, y, h, state, std, speed)


def into_keepout(f, x, y, h, speed, cmd, lead):
    """Independent of check(): does the predicted footprint ever touch a keep-out?"""
    path = f.predict(x, y, h, speed, cmd, lead)
    return min(min(DRAIN.distance(Point(p)), FEEDER.distance(Point(p))) for p in path) < BODY


commands = st.tuples(st.floats(-1, 1), st.floats(-1, 1))
headings = st.floats(-math.pi, math.pi)


@settings(max_examples=150, deadline=None)
@given(x=st.floats(3.5, 7.5), y=st.floats(1.5, 5.5), h=headings, speed=st.floats(0, 0.4), cmd=commands,
       std=st.floats(0, 0.06))
# found by random search: in the band, coming in fast, the away command's turn swung the body in
# (straight back or stopping did not), and among replacements that all gave up the margin the one
# ending farthest off still entered
@example(x=6.1586, y=4.3468, h=-0.8375, speed=0.2819, cmd=(-0.0887, 0.7831), std=0.0131)
@example(x=6.4225, y=4.0846, h=2.3977, speed=0.3668, cmd=(0.1555, -0.8862), std=0.0505)
@example(x=4.6414, y=3.8140, h=-0.5526, speed=0.0606, cmd=(0.9442, -0.9117), std=0.0379)
@example(x=5.4957, y=2.5971, h=0.5709, speed=0.2031, cmd=(-0.8010, -0.1148), std=0.0504)
def test_a_command_that_would_enter_the_drain_never_passes(x, y, h, speed, cmd, std):
    f = fence()
    if min(DRAIN.distance(Point(x, y)), POND.exterior.distance(Point(x, y))) < BODY:
        return                                      # the pose itself is not one the robot can be in
    out = f.check(track(x, y, h, speed=speed, std=std), cmd, 10.0)
    lead = f.latency_s
    if into_keepout(f, x, y, h, speed, cmd, lead):
        assert out != (float(cmd[0]), float(cmd[1]))
        assert f.refused == 1
    if out != (float(cmd[0]), float(cmd[1])) and into_keepout(f, x, y, h, speed, out, lead):
        # a replacement that enters too: only when every replacement would (too fast, too near)
        spin = ((cmd[0] - cmd[1]) / 2, (cmd[1] - cmd[0]) / 2)
        assert all(into_keepout(f, x, y, h, speed, o, lead) for o in (spin, (-f.backoff, -f.backoff), STOP))


@settings(max_examples=100, deadline=None)
@given(x=st.floats(8.5, 11.5), y=st.floats(3.5, 6.5), h=headings, speed=st.floats(0, 0.4), cmd=commands)
def test_far_from_every_keepout_commands_pass_unchanged(x, y, h, speed, cmd):
    # 0.4 m/s at most, ~2 s predicted: under a metre; the nearest keep-out or wall is >= 2 m away
    f = fence()
    assert f.check(track(x, y, h, speed=speed), cmd, 10.0) == (float(cmd[0]), float(cmd[1]))
    assert f.refused == 0


@pytest.mark.parametrize("state", ["predicted", "lost"])
def test_no_drive_without_a_tracked_pose(state):
    f = fence()
    t = track(10, 5, 0, state=state, std=f.blind_std_m + 0.01) if state == "predicted" else \
        FloatTrack(10.0, None, None, None, "lost", None, None)
    assert f.check(t, (0.5, 0.5), 10.0) == STOP
    assert f.check(None, (0.5, 0.5), 10.0) == STOP
    assert f.blind == 2


@settings(max_examples=60, deadline=None)
@given(cmd=commands, std=st.floats(0.0, 0.1))
def test_a_predicted_pose_known_to_a_few_cm_creeps_no_faster_than_blind_thrust(cmd, std):
    f = fence()
    out = f.check(track(10, 5, 0, std=std, state="predicted"), cmd, 10.0)
    assert max(abs(out[0]), abs(out[1])) <= f.blind_thrust + 1e-9
    most = max(abs(cmd[0]), abs(cmd[1]))
    if most > 1e-6:                               # the same turn and way, only slower
        k = min(1.0, f.blind_thrust / most)
        assert out == pytest.approx((cmd[0] * k, cmd[1] * k))


def test_a_stale_pose_stops():
    f = fence(max_age_s=0.5)
    assert f.check(track(10, 5, 0, t=10.0), (0.5, 0.5), 10.4) == (0.5, 0.5)
    assert f.check(track(10, 5, 0, t=10.0), (0.5, 0.5), 10.6) == STOP


def test_full_ahead_at_the_drain_turns_on_the_spot_instead():
    f = fence()
    # 0.15 m west of the drain's west side, facing it, moving: full ahead is refused
    out = f.check(track(5 - BODY - 0.15, 3.5, 0.0, speed=0.2), (1.0, 1.0), 10.0)
    assert out != (1.0, 1.0) and f.refused == 1
    # facing away: full ahead goes
    assert f.check(track(5 - BODY - 0.15, 3.5, math.pi, speed=0.2), (1.0, 1.0), 10.0) == (1.0, 1.0)


def test_running_along_the_wall_is_allowed_ramming_it_is_not():
    f = fence()
    along = f.check(track(10, BODY + 0.005, 0.0, speed=0.24), (0.6, 0.6), 10.0)
    assert along == (0.6, 0.6)
    ram = f.check(track(10, BODY + 0.05, -math.pi / 2, speed=0.4), (1.0, 1.0), 10.0)
    assert ram != (1.0, 1.0)


def test_the_uncertainty_widens_the_band():
    # 0.12 m from the drain, heading along it: fine when sure, refused when the pose is 10 cm unsure
    y = 3 - BODY - 0.12
    assert fence().check(track(5.5, y, 0.0, std=0.01), (0.4, 0.4), 10.0) == (0.4, 0.4)
    assert fence().check(track(5.5, y, math.radians(20), std=0.10), (0.4, 0.4), 10.0) != (0.4, 0.4)


def test_gaps_are_signed():
    edge, keep = fence().gaps(np.array([[5.5, 3.5], [10, 5], [-1, 5]]))
    assert keep[0] == pytest.approx(-0.5 - BODY)
    assert edge[1] == pytest.approx(5 - BODY) and edge[2] == pytest.approx(-1 - BODY)


@pytest.mark.parametrize("heading", [0.0, math.pi / 2, math.pi, -math.pi / 2, 0.7])
def test_inside_the_band_it_gets_off_the_keepout_whichever_way_it_faces(heading):
    f = fence()
    x, y = 5 - BODY - 0.02, 3.5                      # 2 cm west of the drain, inside the band
    out = f.check(track(x, y, heading), (0.6, 0.6), 10.0)
    assert out != (0.6, 0.6) or heading == math.pi
    path = f.predict(x, y, heading, 0.0, out, f.latency_s)
    assert f.gaps(path[-1:])[1][0] > f.gaps(path[:1])[1][0]    # it ends farther off than it is


def test_in_the_band_it_backs_out_first_even_when_asked_to_run_along_it():
    f = fence()
    x, y = 5.5, 3 - BODY - 0.03                      # 3 cm south of the drain, in the band (0.03 + 2 x 0.02)
    out = f.check(track(x, y, 0.0), (0.6, 0.6), 10.0)    # along the drain's side: fine out of the band
    assert out != (0.6, 0.6) and f.backed_off == 1
    assert abs(out[0] + out[1]) / 2 <= f.backoff + 1e-9     # slowly
    h, t = 0.0, 10.0
    while f.gaps(np.array([[x, y]]))[1][0] < f.margin_m + f.k_std * 0.02:   # a robot as the fence models it
        t += 0.1
        left, right = f.check(track(x, y, h, t=t), (0.6, 0.6), t)
        v, w = 0.4 * (left + right) / 2, 1.0 * (right - left) / 2
        x, y, h = x + 0.1 * v * math.cos(h), y + 0.1 * v * math.sin(h), h + 0.1 * w
        assert t < 15.0
    assert abs(x - 5.5) < 0.15                              # off along the outward normal (south), not along it
    # out of the band, the same command goes as asked
    assert f.check(track(x, 3 - BODY - 0.12, 0.0, t=10.1), (0.6, 0.6), 10.1) == (0.6, 0.6)


def test_streak_counts_refusals_in_a_row_and_a_command_let_through_ends_it():
    f = fence()
    near = track(5 - BODY - 0.15, 3.5, 0.0, speed=0.2)
    for k in range(1, 4):
        f.check(near, (1.0, 1.0), 10.0)
        assert f.streak == k
    f.check(track(10, 5, 0.0), (0.5, 0.5), 10.0)
    assert f.streak == 0 and f.refused == 3
    f.check(track(10, 5, 0.0, state="predicted", std=0.5), (0.5, 0.5), 10.0)   # blind: no news either way
    assert f.streak == 0 and f.blind == 1


def crabbing_run(f, *, crab=0.1, until=5.5, y_end=2.53, speed=0.2, seconds=8.0, rate=10.0):
    """Fixes of a robot driving along +x that a current pushes +y (towards the drain) at ``crab``,
    arriving at (``until``, ``y_end``); the fence checks a forward command at each."""
    out = None
    for i in range(int(seconds * rate) + 1):
        t = 10.0 + i / rate
        left = seconds - i / rate
        out = f.check(track(until - speed * left, y_end - crab * left, 0.0, speed=speed, t=t), (0.5, 0.5), t)
    return out


def test_the_current_crabbing_is_learned_and_keeps_the_body_off_a_keepout_beside_the_lane():
    fresh = fence()
    here = track(5.5, 2.53, 0.0, speed=0.2, t=18.0)                    # 0.12 m under the drain
    assert fresh.check(here, (0.5, 0.5), 18.0) == (0.5, 0.5)            # along the lane: clear
    f = fence()
    out = crabbing_run(f)
    assert f.drift == pytest.approx([0.0, 0.1], abs=0.01)              # learned across the heading
    assert out != (0.5, 0.5) and f.refused >= 1                        # the current would carry it in


def test_a_robot_held_by_a_wall_learns_no_current_holding_it_back():
    f = fence()
    for i in range(90):                                                # commanded ahead, not moving
        t = 10.0 + i / 10
        f.check(track(19.0 - BODY, 5.0, 0.0, speed=0.0, t=t), (0.6, 0.6), t)
    assert f.drift == pytest.approx([0.0, 0.0], abs=1e-9)
