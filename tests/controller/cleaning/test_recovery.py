"""Backing up along the trail when the float is lost (controller/cleaning/recovery.py), pure, with
the farm time given: it keeps only ``tracking`` poses, waits ``after_s`` of ``lost``, drives astern
towards the trail's older points, stops at re-acquisition and at the trail's end, and no further."""
from __future__ import annotations

import math

import numpy as np
import pytest

from controller.cleaning.geofence import Motion
from controller.cleaning.recovery import Recovery
from tests.controller.cleaning.standins import Track


def tracking(t, x, y, h=0.0):
    return Track(t, x, y, h, "tracking")


def lost(t):
    return Track(t, None, None, None, "lost")


def laid(rec, points, t0=0.0, dt=0.1):
    """The robot drove through ``points`` (x, y, heading), one fix each ``dt``; then returns the time."""
    t = t0
    for x, y, h in points:
        rec.note(tracking(t, x, y, h), lost=False)
        t += dt
    return t


def straight(x0=0.0, x1=2.0, n=41, y=1.0):
    return [(x0 + (x1 - x0) * k / (n - 1), y, 0.0) for k in range(n)]


class Robot:
    """A unicycle answering thrust as geofence.Motion says (first-order speed and turn)."""

    def __init__(self, x, y, h, motion=None):
        self.x, self.y, self.h, self.v, self.w, self.m = x, y, h, 0.0, 0.0, motion or Motion()

    def step(self, cmd, dt):
        m = self.m
        self.v += (m.top_speed_m_s * (cmd[0] + cmd[1]) / 2 - self.v) * (1 - math.exp(-dt / m.speed_tau_s))
        self.w += (m.top_turn_rad_s * (cmd[1] - cmd[0]) / 2 - self.w) * (1 - math.exp(-dt / m.turn_tau_s))
        self.h += self.w * dt
        self.x += self.v * math.cos(self.h) * dt
        self.y += self.v * math.sin(self.h) * dt


def back_up(rec, t, robot, limit_s=120.0, dt=0.1):
    """Lost frames until the recovery stops; the commands sent and the robot's positions."""
    cmds, where = [], []
    start = t
    while t - start < limit_s:
        rec.note(lost(t), lost=True)
        cmd = rec.command(t)
        if cmd is None and rec.runs and not rec.active:
            break
        cmd = cmd or (0.0, 0.0)
        cmds.append(cmd)
        robot.step(cmd, dt)
        where.append((robot.x, robot.y))
        t += dt
    return cmds, where, t


def test_the_trail_holds_only_tracking_poses_thinned_and_at_most_its_length():
    rec = Recovery(trail_m=1.0, step_m=0.05)
    t = laid(rec, [(0.01 * k, 0.0, 0.0) for k in range(301)])     # 3 m in 1 cm steps
    rec.note(Track(t, 3.5, 0.0, 0.0, "predicted"), lost=False)  # a prediction: not a place it was seen
    rec.note(Track(t + 0.1, 3.6, 0.0, 0.0, "predicted"), lost=False)
    xs = [p[0] for p in rec.trail]
    assert max(xs) == pytest.approx(3.0) and 3.5 not in xs and 3.6 not in xs
    assert 0.95 <= rec.trail_length() <= 1.0 and min(xs) >= 1.95
    assert all(b - a >= 0.05 - 1e-9 for a, b in zip(xs[:-2], xs[1:-1], strict=True))  # the newest: the last fix
    assert xs[-1] - xs[-2] < 0.05 + 1e-9
    laid(rec, [(6.0, 0.0, 0.0)], t0=t + 1)                     # seen far off: not driven in between
    assert rec.trail == [(6.0, 0.0, 0.0)]


def test_recovery_begins_only_after_recover_after_s_of_lost():
    rec = Recovery(after_s=5.0)
    t = laid(rec, straight())
    rec.note(Track(t, 2.0, 1.0, 0.0, "predicted"), lost=False)   # coasting: the cleaner is not lost yet
    assert rec.command(t) is None
    rec.note(lost(t + 3.0), lost=True)                            # lost from here
    for dt in (0.0, 2.0, 4.9):
        rec.note(lost(t + 3.0 + dt), lost=True)
        assert rec.command(t + 3.0 + dt) is None and rec.runs == 0
    rec.note(lost(t + 8.0), lost=True)
    left, right = rec.command(t + 8.0)
    assert left < 0 and right < 0 and rec.runs == 1 and rec.active


def test_it_backs_along_the_trail_to_its_oldest_point_and_no_further():
    rec = Recovery(after_s=1.0, trail_m=2.0)
    # an L: along x, then a quarter turn up; the robot drove it ending at (1.5, 0.5) facing +y
    pts = [(0.05 * k, 0.0, 0.0) for k in range(21)] + [(1.0 + 0.5 * math.sin(a), 0.5 - 0.5 * math.cos(a), a)
                                                        for a in (math.pi / 2 * k / 15 for k in range(1, 16))]
    t = laid(rec, pts)
    oldest, newest = rec.trail[0], rec.trail[-1]
    robot = Robot(*newest)
    cmds, where, t = back_up(rec, t, robot)
    assert rec.runs == 1 and rec.ended["trail_end"] == 1 and not rec.active
    driving = [c for c in cmds if c != (0.0, 0.0)]
    assert driving and all(left + right < 0 for left, right in driving)        # astern, all of it
    assert all(max(abs(left), abs(right)) <= 0.5 for left, right in driving)   # slowly
    assert math.dist(where[-1], oldest[:2]) < 0.25                              # back where the trail began
    gaps = [min(math.dist(p, q[:2]) for q in rec.trail) for p in where]
    assert max(gaps) < 0.15                                                     # along it all the way
    driven = sum(math.dist(a, b) for a, b in zip(where, where[1:], strict=False))
    assert driven <= rec.trail_length() + 0.1
    for k in range(50):                                         # still lost: it stays put
        rec.note(lost(t + 0.1 * k), lost=True)
        assert rec.command(t + 0.1 * k) is None
    assert rec.runs == 1


def test_the_float_back_ends_it_at_once_and_a_later_loss_starts_afresh():
    rec = Recovery(after_s=1.0)
    t = laid(rec, straight())
    rec.note(lost(t), lost=True)
    assert rec.command(t + 1.0) is not None and rec.active
    rec.note(tracking(t + 1.2, 1.95, 1.0), lost=False)
    assert not rec.active and rec.ended["reacquired"] == 1
    assert rec.command(t + 1.3) is None                          # tracking: nothing of ours
    t = laid(rec, straight(1.95, 4.0), t0=t + 1.3)
    rec.note(lost(t), lost=True)
    assert rec.command(t + 0.5) is None and rec.command(t + 1.0) is not None and rec.runs == 2


def test_leaving_lost_interrupts_it():
    rec = Recovery(after_s=1.0)
    t = laid(rec, straight())
    rec.note(lost(t), lost=True)
    assert rec.command(t + 1.0) is not None
    rec.note(lost(t + 1.1), lost=False)                          # e-stop, stop, a fault: not lost any more
    assert not rec.active and rec.ended["interrupted"] == 1 and rec.command(t + 1.2) is None


def test_no_trail_no_move_and_the_same_blind_spot_is_given_up_after_tries():
    rec = Recovery(after_s=1.0, tries=2)
    rec.note(tracking(0.0, 1.0, 1.0), lost=False)                # one point: nowhere known to go
    rec.note(lost(0.1), lost=True)
    assert rec.command(5.0) is None and rec.runs == 0
    t = 10.0
    for attempt in range(3):                                     # the path leads right back into the same spot
        t = laid(rec, straight(1.0, 2.0, 21), t0=t)
        rec.note(lost(t), lost=True)
        cmd = rec.command(t + 1.0)
        assert (cmd is not None) == (attempt < 2)
        rec.note(tracking(t + 2.0, 1.9, 1.0), lost=False)
        t += 3.0
    assert rec.runs == 2 and rec.ended["gave_up"] == 1
    for end, again in ((2.3, False), (2.6, True)):             # creeping on: a new spot once 0.5 m from the first
        t = laid(rec, straight(1.9, end, 5), t0=t)
        rec.note(lost(t), lost=True)
        assert (rec.command(t + 1.0) is not None) == again
        rec.note(tracking(t + 2.0, end - 0.1, 1.0), lost=False)
        t += 3.0
    assert rec.runs == 3
    loop = [(2.5 - 0.05 * k, 1.0, math.pi) for k in range(30)] + [(1.0 + 0.05 * k, 1.0, 0.0) for k in range(33)]
    t = laid(rec, loop, t0=t)                                     # 3 m driven tracked, back to the same spot
    for _ in range(3):                                            # got on in between: no streak
        rec.note(lost(t), lost=True)
        assert rec.command(t + 1.0) is not None
        rec.note(tracking(t + 2.0, 2.5, 1.0), lost=False)
        t = laid(rec, loop, t0=t + 3.0)
    assert rec.runs == 6 and rec.ended["gave_up"] == 2


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="after_s"):
        Recovery(after_s=0)
    with pytest.raises(ValueError):
        Recovery(thrust=1.5)


def test_it_stops_for_good_once_the_current_could_have_crabbed_it_near_a_keep_out():
    def gaps(xy):                                  # a keep-out below y = 0; a body of 0.35 m
        xy = np.asarray(xy, float).reshape(-1, 2)
        return np.full(len(xy), 9.0), xy[:, 1] - 0.35
    rec = Recovery(after_s=1.0, gaps=gaps, margin_m=0.05, drift_m_s=0.05)   # 0.65 m off: 12 s of drift
    t = laid(rec, straight())
    rec.note(lost(t), lost=True)
    began, end = None, None
    for k in range(400):
        now = t + 1.0 + 0.1 * k
        rec.note(lost(now), lost=True)
        cmd = rec.command(now)
        if cmd is not None and began is None:
            began = now
        if cmd is None and began is not None:
            end = now
            break
    assert rec.ended["fenced"] == 1 and rec.ended["trail_end"] == 0
    assert end - began == pytest.approx(12.0, abs=0.15)
    assert rec.command(end + 1.0) is None
