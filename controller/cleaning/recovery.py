"""Getting the float back: the robot backs up along the way it came.

A robot that stops where the tower camera cannot make it out (a far wall, a distractor under the
float) stays there: its tracks grip the floor. ``Recovery`` keeps a trail of its recent
``tracking`` poses (the last ``trail_m`` of path, points ``step_m`` apart; a jump of more than
``jump_m`` between fixes starts a new trail: only ground it drove over is on it). These are
places the robot has just been, clear of keep-outs. After ``after_s`` of ``lost`` it backs up
along that trail, slowly (``thrust``, astern), by dead reckoning from the last good pose: the
commands it gave, run through the robot's response to thrust (geofence.Motion). It stops the
moment a ``tracking`` pose comes (``ended["reacquired"]``), and when the trail is used up —
the oldest point reached, or the trail's length driven — without one (``ended["trail_end"]``):
it never drives beyond the trail. A recovery cut short by the cleaner leaving ``lost`` (e-stop,
stop, a fault) is ``ended["interrupted"]``. A robot that keeps losing the float within
``same_spot_m`` of where it did last (the path leads into the blind spot again), with less than
``trail_m`` driven tracked in between, backs up at most ``tries`` times there; then it stays
``lost`` (``ended["gave_up"]``).

The trail is clear, but a robot driven blind also crabs with the current: given the geofence's
``gaps`` (the body's gap to the nearest keep-out at a centre), the recovery stops for good
(``ended["fenced"]``) once the dead-reckoned pose comes within ``margin_m`` + ``drift_m_s`` x the
time it has backed up of a keep-out.

Pure: no devices, no clock of its own; the cleaner (cleaner.py) sends what ``command`` returns, and
only in ``lost``, with the e-stop clear.
"""
from __future__ import annotations

import logging
import math

import numpy as np

from controller.cleaning.geofence import Motion

log = logging.getLogger("fishfarm.cleaner")


class Recovery:
    def __init__(self, *, after_s: float = 5.0, thrust: float = 0.25, trail_m: float = 2.0, step_m: float = 0.05,
                 jump_m: float = 0.5, reach_m: float = 0.1, aim_m: float = 0.3, turn_gain: float = 1.0, tries: int = 3,
                 same_spot_m: float = 0.5, motion: Motion | None = None, gaps=None, margin_m: float = 0.05,
                 drift_m_s: float = 0.05):
        if not (after_s > 0 and 0 < thrust <= 1 and trail_m > 0 and 0 < step_m < trail_m):
            raise ValueError(f"after_s > 0, thrust in (0, 1], 0 < step_m < trail_m: {after_s}, {thrust}, "
                             f"{step_m}, {trail_m}")
        self.after_s, self.thrust, self.trail_m, self.step_m = after_s, thrust, trail_m, step_m
        self.jump_m, self.reach_m, self.aim_m, self.turn_gain = jump_m, reach_m, aim_m, turn_gain
        self.tries, self.same_spot_m = tries, same_spot_m
        self.motion = motion or Motion()
        self.gaps, self.margin_m, self.drift_m_s = gaps, margin_m, drift_m_s   # gaps: Geofence.gaps
        self.trail: list[tuple[float, float, float]] = []     # (x, y, heading), oldest first
        self.runs = 0                          # recoveries begun
        self.ended = {"reacquired": 0, "trail_end": 0, "interrupted": 0, "gave_up": 0, "fenced": 0}
        self._lost_since: float | None = None
        self._active = False
        self._spent = False                    # this loss: the trail is used up (or given up)
        self._spot: tuple[float, float] | None = None   # where the last recovery began
        self._at_spot = 0                      # recoveries begun there in a row
        self._since_m = 0.0                    # driven tracked since the last recovery began

    @property
    def active(self) -> bool:
        return self._active

    def trail_length(self) -> float:
        return sum(math.dist(a[:2], b[:2]) for a, b in zip(self.trail, self.trail[1:], strict=False))

    def note(self, track, lost: bool) -> None:
        """Every track, after the cleaner's state has followed it; ``lost``: the cleaner is in ``lost``."""
        if track.state == "tracking" and track.x_m is not None:
            self._end("reacquired")
            self._lost_since, self._spent = None, False
            self._add(float(track.x_m), float(track.y_m), float(track.heading_rad))
        elif not lost:
            self._end("interrupted")
            self._lost_since = None
        elif self._lost_since is None:
            self._lost_since = float(track.t_s)

    def _add(self, x: float, y: float, h: float) -> None:
        step = math.dist(self.trail[-1][:2], (x, y)) if self.trail else 0.0
        if step > self.jump_m:
            self.trail.clear()                 # not driven in between (or not seen): a new trail
        else:
            self._since_m += step
        if len(self.trail) >= 2 and math.dist(self.trail[-2][:2], self.trail[-1][:2]) < self.step_m:
            self.trail[-1] = (x, y, h)         # thinned: the newest is always the last good pose
        else:
            self.trail.append((x, y, h))
        if self._since_m > self.trail_m:       # it got on: a loss here again is no streak
            self._spot, self._at_spot = None, 0
        while len(self.trail) > 2 and self.trail_length() > self.trail_m:
            self.trail.pop(0)

    def _end(self, how: str) -> None:
        if self._active:
            self._active = False
            self.ended[how] += 1
            log.info("cleaner: recovery ended: %s after %.2f m", how, self._driven)

    def command(self, now_s: float) -> tuple[float, float] | None:
        """(left, right) astern along the trail while a recovery runs; None: stop."""
        if self._lost_since is None or self._spent or now_s - self._lost_since < self.after_s:
            return None
        if not self._active and not self._begin(now_s):
            return None
        m, dt = self.motion, min(0.5, max(0.0, now_s - self._t))
        left, right = self._sent
        self._v += (m.top_speed_m_s * (left + right) / 2 - self._v) * (1 - math.exp(-dt / m.speed_tau_s))
        self._w += (m.top_turn_rad_s * (right - left) / 2 - self._w) * (1 - math.exp(-dt / m.turn_tau_s))
        self._h += self._w * dt
        self._x += self._v * math.cos(self._h) * dt
        self._y += self._v * math.sin(self._h) * dt
        self._driven += abs(self._v) * dt
        self._t = now_s
        while self._k > 0 and math.dist((self._x, self._y), self.trail[self._k][:2]) < self.aim_m:
            self._k -= 1                       # aim ``aim_m`` on, at an older point (pure pursuit astern)
        if self._driven >= self._budget or (self._k == 0 and math.dist((self._x, self._y), self.trail[0][:2])
                                             < self.reach_m):
            self._spent = True
            self._end("trail_end")
            return None
        if self.gaps is not None:
            keep = float(self.gaps(np.array([[self._x, self._y]]))[1][0])
            if keep < self.margin_m + self.drift_m_s * (now_s - self._began):
                self._spent = True
                self._end("fenced")
                return None
        tx, ty = self.trail[self._k][:2]
        alpha = math.remainder(math.atan2(ty - self._y, tx - self._x) - (self._h + math.pi), 2 * math.pi)
        turn = max(-self.thrust, min(self.thrust, self.turn_gain * alpha))
        self._sent = (-self.thrust - turn, -self.thrust + turn)
        return self._sent

    def _begin(self, now_s: float) -> bool:
        if len(self.trail) < 2:
            self._spent = True
            return False
        x, y, h = self.trail[-1]
        same = self._spot is not None and math.dist(self._spot, (x, y)) <= self.same_spot_m
        self._at_spot = self._at_spot + 1 if same else 1
        self._spot = self._spot if same else (x, y)   # the streak's first: a robot creeping on is elsewhere
        if self._at_spot > self.tries:
            self._spent = True
            self.ended["gave_up"] += 1
            log.warning("cleaner: lost at (%.1f, %.1f) again: no more backing up there", x, y)
            return False
        self.runs += 1
        self._active, self._since_m = True, 0.0
        log.warning("cleaner: lost %.0f s at (%.1f, %.1f): backing up along the last %.1f m driven",
                    now_s - self._lost_since, x, y, self.trail_length())
        self._x, self._y, self._h, self._v, self._w, self._t, self._began = x, y, h, 0.0, 0.0, now_s, now_s
        self._sent, self._driven, self._budget = (0.0, 0.0), 0.0, self.trail_length()
        self._k = len(self.trail) - 2
        return True
