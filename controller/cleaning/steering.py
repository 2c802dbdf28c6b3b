"""Pure pursuit along the coverage path, for a robot steered by two thrusters (left, right).

``progress`` is the index of the last waypoint reached. It only moves forward, and never past a
sharp corner (a lane's end) before the robot has come round it, nor more than ``window_m`` of path
at a time: a robot drifting towards the next lane does not skip the end of this one. A restarted
controller builds the follower with ``start_index`` = the saved progress and carries on from the
point nearest to the robot ahead of it, inside the same limits, so no lane is skipped on resume.

Steering aims at a point ``lookahead_m`` ahead along the path (at the next sharp corner if one
comes sooner, so corners are driven, not cut), shifted against the robot's accumulated sideways
error: a current makes the robot crab, and without that integral it would run a steady offset
downstream of every lane. It turns on the spot when the aim is far off its heading, and slows for
sharp turns and curves; when no waypoint has been reached for a while (a current stronger than the
slowed robot) it thrusts harder until one is.

The geofence (geofence.py) may refuse what it asks: ``command(..., refused=n)`` says the last
``n`` commands in a row were not sent as asked. While that lasts there is no extra thrust (it
would only push harder at what is refused), and after every ``skip_after`` refusals in a row the
aim moves one waypoint on, past a corner too (a corner in the keep-out's band is never reached),
but never more than ``skip_max_m`` of path before a waypoint is reached again: a stretch the fence
will not let it near is given up, never a lane.
"""
from __future__ import annotations

import math

import numpy as np

CORNER_RAD = math.radians(45)      # a turn sharper than this is a corner (a lane's end)
STALL_S, STALL_GAIN = 4.0, 0.1      # no waypoint for STALL_S: forward thrust + STALL_GAIN per s beyond
CORNER_REACH_M = 0.15             # a corner this near counts as reached
SAG_M = 0.02                       # how far a look-ahead chord may cut inside a curve (sagitta ~ chord^2 k / 8)
CURVE_SLOW_M = 0.6                 # on a curve of k rad/m, speed / (1 + CURVE_SLOW_M k)


def _wrap(a: float) -> float:
    return math.remainder(a, 2 * math.pi)


class PathFollower:
    def __init__(self, path, *, lookahead_m: float = 1.0, cruise: float = 0.6, track_m: float = 0.5,
                 start_index: int = 0, period_s: float = 0.1, window_m: float = 3.0, reach_m: float = 0.25,
                 turn_gain: float = 1.2, spin_above_rad: float = math.radians(45), slow_m: float = 0.8,
                 integral_gain: float = 0.4, integral_max_m: float = 0.25, skip_after: int = 10,
                 skip_max_m: float = 1.0):
        self.path = np.asarray(path, dtype=float).reshape(-1, 2)
        if len(self.path) < 1 or not np.isfinite(self.path).all():
            raise ValueError("path must be finite (N, 2) waypoints, N >= 1")
        if not (0 <= cruise <= 1 and lookahead_m > 0 and period_s > 0):
            raise ValueError(f"cruise in [0, 1], lookahead_m and period_s > 0: {cruise}, {lookahead_m}, {period_s}")
        self.lookahead_m, self.cruise, self.track_m, self.period_s = lookahead_m, cruise, track_m, period_s
        self.window_m, self.reach_m, self.turn_gain, self.spin_above = window_m, reach_m, turn_gain, spin_above_rad
        self.slow_m, self.ki, self.imax = slow_m, integral_gain, integral_max_m
        self.skip_after, self.skip_max_m = max(1, int(skip_after)), skip_max_m
        self.skipped = 0                  # waypoints given up to the geofence, over the run
        self._skipped_m = 0.0             # path given up since a waypoint was last reached
        legs = np.diff(self.path, axis=0)
        self.s = np.r_[0.0, np.cumsum(np.hypot(*legs.T))]
        heading = np.arctan2(legs[:, 1], legs[:, 0]) if len(legs) else np.zeros(0)
        bend = np.abs(np.angle(np.exp(1j * np.diff(heading)))) if len(legs) > 1 else np.zeros(0)
        self.corners = np.r_[np.flatnonzero(bend > CORNER_RAD) + 1, len(self.path) - 1].astype(int)
        gentle = np.where(bend > CORNER_RAD, 0.0, bend)
        self.turning = np.r_[0.0, 0.0, np.cumsum(gentle)][:len(self.path)]   # bends before each waypoint
        self.progress = int(min(max(start_index, 0), len(self.path) - 1))
        self.done = False
        self._push = np.zeros(2)          # the integral of the sideways error, pond metres
        self._stalled_s = 0.0             # time since a waypoint was last reached

    def _next_corner(self, i: int) -> int:
        return int(self.corners[np.searchsorted(self.corners, i, side="right")]) if i < len(self.path) - 1 else i

    def _advance(self, p: np.ndarray) -> None:
        i = self.progress
        end = min(self._next_corner(i), int(np.searchsorted(self.s, self.s[i] + self.window_m, side="right")))
        d = np.hypot(*(self.path[i:end + 1] - p).T)
        self.progress = i + int(np.argmin(d))
        corner = self._next_corner(self.progress)
        if corner == end and d[-1] <= CORNER_REACH_M:       # close enough to come round (at a wall's corner,
            self.progress = corner                        # say, where the body cannot get any nearer)

    def _point_at(self, s: float) -> np.ndarray:
        return np.array([np.interp(s, self.s, self.path[:, 0]), np.interp(s, self.s, self.path[:, 1])])

    def _aim(self, p: np.ndarray, heading: float, dt: float) -> tuple[np.ndarray, float]:
        """The point to steer at (on a curve, near enough that the chord cuts in <= SAG_M; never past
        the next corner) and the fraction of cruise speed the path ahead allows."""
        i = self.progress
        corner = self._next_corner(i)
        a, b = self.path[i], self.path[min(i + 1, len(self.path) - 1)]
        ab = b - a
        t = float(np.clip(np.dot(p - a, ab) / max(np.dot(ab, ab), 1e-12), 0.0, 1.0))
        on = self.s[i] + t * (self.s[min(i + 1, len(self.s) - 1)] - self.s[i])
        self._integrate(p - a, ab, heading, dt)
        far = min(on + self.lookahead_m, self.s[corner])
        bends = np.interp([on, far], self.s, self.turning)
        curve = (bends[1] - bends[0]) / max(far - on, 1e-9)         # rad per metre ahead
        ahead = far if curve < 1e-6 else min(far, on + max(0.25, math.sqrt(8 * SAG_M / curve)))
        slow = min(1.0 / (1.0 + CURVE_SLOW_M * curve), max(0.3, (self.s[corner] - on) / self.slow_m))
        return self._point_at(ahead) + self.ki * self._push, slow

    def _integrate(self, ap: np.ndarray, ab: np.ndarray, heading: float, dt: float) -> None:
        """Sideways error, summed while the robot runs along a straight stretch (no wind-up in turns)."""
        length = math.hypot(*ab)
        if length < 1e-9:
            return
        normal = np.array([-ab[1], ab[0]]) / length
        off = float(np.dot(ap, normal))
        if abs(off) > 0.3 or abs(_wrap(math.atan2(ab[1], ab[0]) - heading)) > math.radians(30):
            return
        self._push -= normal * off * dt
        size = math.hypot(*self._push) * self.ki
        if size > self.imax:
            self._push *= self.imax / size

    def _skip(self, refused: int) -> None:
        """Every ``skip_after`` refusals in a row: the aim one waypoint on, within ``skip_max_m``."""
        i = self.progress
        if refused <= 0 or refused % self.skip_after or i >= len(self.path) - 1:
            return
        leg = float(self.s[i + 1] - self.s[i])
        if self._skipped_m + leg <= self.skip_max_m:
            self.progress, self._skipped_m, self.skipped = i + 1, self._skipped_m + leg, self.skipped + 1

    def skip_to(self, index: int) -> None:
        """Give the path up to ``index`` (a stretch its owner has given up: the mop-up's stalled
        pass): progress there, with no stall, skip or sideways account carried over."""
        self.progress = int(min(max(index, self.progress), len(self.path) - 1))
        self._stalled_s, self._skipped_m = 0.0, 0.0
        self._push[:] = 0.0

    def command(self, x: float, y: float, heading: float, dt_s: float | None = None,
                refused: int = 0) -> tuple[float, float]:
        """Thrust (left, right) in [-1, 1] for the measured pose; (0, 0) once done. ``refused``: how
        many commands in a row the geofence has not sent as asked (module docstring)."""
        if self.done:
            return 0.0, 0.0
        p = np.array([x, y], dtype=float)
        dt = self.period_s if dt_s is None else dt_s
        before = self.progress
        self._advance(p)
        if self.progress > before:
            self._stalled_s = 0.0
            if math.hypot(*(self.path[self.progress] - p)) <= self.reach_m:   # reached, not only nearest
                self._skipped_m = 0.0
        else:
            self._stalled_s = 0.0 if refused > 0 else self._stalled_s + dt
        self._skip(refused)
        last = len(self.path) - 1
        if self.progress >= last - 1 and math.hypot(*(self.path[-1] - p)) <= self.reach_m:
            self.progress, self.done = last, True
            return 0.0, 0.0
        target, slow = self._aim(p, heading, dt)
        alpha = _wrap(math.atan2(target[1] - y, target[0] - x) - heading)
        turn = max(-1.0, min(1.0, self.turn_gain * alpha))
        if abs(alpha) > self.spin_above:
            forward = 0.0
        else:
            # against a current stronger than the slowed speed the robot would stall short of a
            # corner: thrust grows while no waypoint is reached
            headway = min(1.0, max(0.0, self._stalled_s - STALL_S) * STALL_GAIN)
            forward = min(1.0, self.cruise * math.cos(alpha) ** 2 * min(1.0, slow) + headway)
        left, right = forward - turn, forward + turn
        scale = max(1.0, abs(left), abs(right))
        return left / scale, right / scale
