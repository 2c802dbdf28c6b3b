"""A geofence in the cleaner's command path that does not rest on the follower being right.

Before every drive, ``Geofence.check`` predicts where the body's footprint (a disc of the body
radius) goes if the command is held for the pose's age plus ``horizon_s`` and the thrusters are
then stopped and the robot coasts out (``coast_s``): a unicycle whose speed and turn rate follow
the thrust with the robot's time constants, the thrust ramping as the device ramps it. The
robot's speed ahead is the one the thrust sent lately gives (the tracker's when nothing was sent:
its speed from fixes a few times a second is too noisy), along its heading, plus the current's
crabbing across it, learned from the last ``drift_window_s`` of tracked fixes (``drift``).

The gap of the footprint to a keep-out must stay at least ``margin_m`` + ``k_std`` x the pose's
uncertainty (the band); a command that would bring it under that (and closer than it is now,
less ``slack_m``) or under ``k_std`` x the uncertainty at all, is refused. A body already in the
band is backed out of it first, whatever was asked: slowly, off the nearest keep-out, ahead or
astern (``backed_off`` counts these). At the pond's edge the walls hold the robot (the edge pass
runs along them, pressed on by the current, on purpose): there only a command predicted to ram
deeper than ``edge_limit_m`` past the wall, and deeper than the robot is now, is refused. A
refused command is replaced by the first safe of: the same command at half, then a quarter of its
speed ahead; a slow move off the nearest keep-out; the command's turn on the spot; a slow
back-off; a stop; if none is safe, the one that ends farthest off. ``streak`` counts the commands
replaced in a row (the path follower gives up a waypoint the fence keeps refusing, steering.py).
A track older than ``max_age_s``, or neither ``tracking`` nor a ``predicted`` one whose position
is still known within ``blind_std_m`` (the float's blue hidden by a blue tarp: its orange still
fixes the position, the heading coasts), gets a stop (and the robot, its tracks held, stays where
it is: devices/sim/pond_physics.py). On such a predicted pose the command is first slowed to
``blind_thrust`` at most, then judged as any other with the pose's std in the band: a robot
crossing a blind spot creeps on out of it instead of stopping in it.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
import shapely
import shapely.ops

STOP = (0.0, 0.0)


@dataclass(frozen=True)
class Motion:
    """The robot's response to thrust (devices/sim/pond_physics.py defaults: 2 x 12 N against
    60 N s/m, 40 kg; yaw 2 x 12 N x 0.25 m against 6 N m s, 2.5 kg m2; ramps 4/s)."""
    top_speed_m_s: float = 0.4       # at command (1, 1)
    speed_tau_s: float = 0.67        # mass / drag
    top_turn_rad_s: float = 1.0      # at command (-1, 1)
    turn_tau_s: float = 0.42         # inertia / yaw drag
    ramp_per_s: float = 4.0          # the thrusters' ramp


@dataclass
class Geofence:
    outline: object                  # shapely Polygon: the pond
    keepouts: tuple = ()             # shapely Polygons
    body_radius_m: float = 0.35
    margin_m: float = 0.03
    k_std: float = 2.0
    slack_m: float = 0.02
    edge_limit_m: float = 0.25
    horizon_s: float = 0.3
    coast_s: float = 1.5
    step_s: float = 0.05
    max_age_s: float = 0.5
    latency_s: float = 0.1           # from the frame's instant to its track (render, link, detection)
    backoff: float = 0.3
    blind_std_m: float = 0.1
    blind_thrust: float = 0.3
    drift_window_s: float = 8.0      # tracked fixes the current's crabbing is learned over
    max_drift_m_s: float = 0.2       # a larger learned crab is a bad estimate, not a current
    motion: Motion = field(default_factory=Motion)
    refused: int = 0                 # commands replaced
    streak: int = 0                  # commands replaced in a row (the follower learns of them)
    backed_off: int = 0              # drives that backed the body out of a keep-out's band
    blind: int = 0                   # drives refused for want of a fresh tracked pose

    def __post_init__(self):
        self._last = None                # (farm s, command) last let through
        self._v, self._thrust = 0.0, np.zeros(2)
        self._trail: deque = deque()     # (t, position, dead-reckoned position) of tracked fixes
        self._reckoned = np.zeros(2)
        self._fix: tuple[float, float] | None = None      # (t, heading) of the last fix learned from
        self.drift = np.zeros(2)         # the current's push across the heading, m/s (learned)
        self._edge = self.outline.exterior
        self._keep = shapely.union_all(list(self.keepouts)) if self.keepouts else None
        for g in (self.outline, self._edge, self._keep):
            if g is not None:
                shapely.prepare(g)

    # -- the gaps ---------------------------------------------------------------
    def gaps(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per centre (N, 2): the body's gap to the pond's edge and to the nearest keep-out (m;
        negative: that far over)."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        pts = shapely.points(xy)
        d = shapely.distance(self._edge, pts)
        inside = shapely.contains_xy(self.outline, xy[:, 0], xy[:, 1])
        edge = np.where(inside, d, -d) - self.body_radius_m
        if self._keep is None:
            return edge, np.full(len(xy), np.inf)
        dk = shapely.distance(self._keep, pts)        # 0 inside
        into = shapely.contains_xy(self._keep, xy[:, 0], xy[:, 1])
        if into.any():
            dk = np.where(into, -shapely.distance(self._keep.boundary, pts), dk)
        return edge, dk - self.body_radius_m

    # -- the prediction ---------------------------------------------------------
    def predict(self, x, y, heading, speed, command, lead_s, drift=(0.0, 0.0)) -> np.ndarray:
        """Centres (N, 2) from now: ``command`` held ``lead_s`` + ``horizon_s``, then coasting;
        ``drift`` (m/s) carries the body besides (the current's crabbing)."""
        m = self.motion
        dx, dy = float(drift[0]), float(drift[1])
        left, right = (max(-1.0, min(1.0, float(c))) for c in command)
        held = lead_s + self.horizon_s
        n = max(1, math.ceil((held + self.coast_s) / self.step_s))
        fl = fr = max(-1.0, min(1.0, speed / m.top_speed_m_s))   # thrust now, as the speed says
        v, w, ramp = speed, 0.0, m.ramp_per_s * self.step_s
        out = np.empty((n + 1, 2))
        out[0] = x, y
        for i in range(1, n + 1):
            tl, tr = (left, right) if i * self.step_s <= held else STOP
            fl += max(-ramp, min(ramp, tl - fl))
            fr += max(-ramp, min(ramp, tr - fr))
            v += (m.top_speed_m_s * (fl + fr) / 2 - v) * self.step_s / m.speed_tau_s
            w += (m.top_turn_rad_s * (fr - fl) / 2 - w) * self.step_s / m.turn_tau_s
            heading += w * self.step_s
            x += (v * math.cos(heading) + dx) * self.step_s
            y += (v * math.sin(heading) + dy) * self.step_s
            out[i] = x, y
        return out

    def _judge(self, now_gaps, path, std) -> tuple[bool, tuple[bool, float]]:
        """Safe or not, and a rank to choose among unsafe ones: first whether the body stays out of
        every keep-out at all (a margin given up is better than a keep-out entered), then how far
        off it ends."""
        edge, keep = self.gaps(path)
        e, k = float(edge.min()), float(keep.min())
        e0, k0 = float(now_gaps[0][0]), float(now_gaps[1][0])
        keep_ok = k >= self.k_std * std and (k >= self.margin_m + self.k_std * std or k >= k0 - self.slack_m)
        edge_ok = e >= -self.edge_limit_m or e >= e0 - self.slack_m
        return keep_ok and edge_ok, (k >= 0.0, min(float(keep[-1]), float(edge[-1]) + self.edge_limit_m))

    # -- the check --------------------------------------------------------------
    def check(self, track, command, now_s: float) -> tuple[float, float]:
        """The command to send for ``command`` given the latest track at farm time ``now_s``."""
        if not self._drivable(track, now_s):
            self.blind += 1
            return STOP
        if track.state != "tracking":          # predicted, position still known: creep
            most = max(abs(float(command[0])), abs(float(command[1])), 1e-9)
            k = min(1.0, self.blind_thrust / most)
            command = (float(command[0]) * k, float(command[1]) * k)
        std = float(track.std_m or 0.0)
        speed = self._speed(now_s, float(track.speed_m_s or 0.0))
        self._learn_drift(track, speed)
        lead = max(0.0, now_s - track.t_s) + self.latency_s
        pose = (track.x_m, track.y_m, track.heading_rad, speed)
        here = self.gaps(np.array([[track.x_m, track.y_m]]))
        if float(here[1][0]) < self.margin_m + self.k_std * std:   # in the band: out of it first
            self.refused, self.streak, self.backed_off = self.refused + 1, self.streak + 1, self.backed_off + 1
            # off the keep-out, turning away, unless coming in fast that turn swings it in: then
            # straight back, the asked turn on the spot, or stop
            turn = (float(command[1]) - float(command[0])) / 2
            options = [self._away(track), (-self.backoff, -self.backoff), (-turn, turn), STOP]
            return self._sent(now_s, self._first_safe(here, pose, lead, std, options))
        ok, _ = self._judge(here, self.predict(*pose, command, lead, self.drift), std)
        if ok:
            self.streak = 0
            return self._sent(now_s, (float(command[0]), float(command[1])))
        self.refused, self.streak = self.refused + 1, self.streak + 1
        ahead, turn = (float(command[0]) + float(command[1])) / 2, (float(command[1]) - float(command[0])) / 2
        slower = [(ahead * k - turn, ahead * k + turn) for k in (0.5, 0.25) if ahead > 0]
        options = [*slower, self._away(track), (-turn, turn), (-self.backoff, -self.backoff), STOP]
        return self._sent(now_s, self._first_safe(here, pose, lead, std, options))

    def _first_safe(self, here, pose, lead: float, std: float, options: list) -> tuple[float, float]:
        """The first of ``options`` whose prediction is safe; if none is, the one ending farthest off."""
        best, widest = STOP, (False, -math.inf)
        for option in options:
            safe, gap = self._judge(here, self.predict(*pose, option, lead, self.drift), std)
            if safe:
                return option
            if gap > widest:
                best, widest = option, gap
        return best

    def _learn_drift(self, track, speed: float) -> None:
        """The current's push across the robot's heading: over the last ``drift_window_s`` of
        tracked fixes, how far the float went across its heading beyond what the thrust's speed
        along it explains. Only the cross part: pressed on a wall (the edge pass), the part along
        the heading would read as a current holding the robot back, and the fence would then
        predict it short of a keep-out ahead."""
        if track.state != "tracking" or track.x_m is None or track.heading_rad is None:
            return
        t = float(track.t_s)
        if self._fix is not None:
            if t <= self._fix[0]:
                return                           # the same fix again
            t0, h0 = self._fix
            self._reckoned = self._reckoned + speed * (t - t0) * np.array([math.cos(h0), math.sin(h0)])
        self._fix = (t, float(track.heading_rad))
        self._trail.append((t, np.array([track.x_m, track.y_m], float), self._reckoned.copy()))
        while t - self._trail[0][0] > self.drift_window_s:
            self._trail.popleft()
        t0, p0, r0 = self._trail[0]
        if t - t0 < self.drift_window_s / 2:
            self.drift = np.zeros(2)
            return
        moved = (self._trail[-1][1] - p0) - (self._reckoned - r0)
        across = np.array([-math.sin(track.heading_rad), math.cos(track.heading_rad)])
        crab = max(-self.max_drift_m_s, min(self.max_drift_m_s, float(moved @ across) / (t - t0)))
        self.drift = crab * across

    def _drivable(self, track, now_s: float) -> bool:
        if track is None or track.x_m is None or now_s - track.t_s > self.max_age_s:
            return False
        return track.state == "tracking" or (track.state == "predicted" and track.std_m is not None
                                              and track.std_m <= self.blind_std_m)

    def _away(self, track) -> tuple[float, float]:
        """Off the nearest keep-out (the wall if there is none) at once, slowly, along the band's
        outward normal as a robot that cannot move sideways can: ahead or astern, whichever end
        faces away, turning that end onto the normal — a robot the current presses on a keep-out
        must not wait there, nor spin first."""
        here = shapely.Point(track.x_m, track.y_m)
        nearest = shapely.ops.nearest_points(self._keep if self._keep is not None else self._edge, here)[0]
        away = math.atan2(track.y_m - nearest.y, track.x_m - nearest.x)
        alpha = math.remainder(away - track.heading_rad, 2 * math.pi)
        sign = 1.0
        if abs(alpha) > math.pi / 2:       # it is ahead: back off, turning the stern away
            sign, alpha = -1.0, math.remainder(alpha - math.pi, 2 * math.pi)
        ahead = sign * self.backoff              # 0.12 m/s: slow, yet well ahead of a few cm/s of current
        turn = max(-0.5, min(0.5, alpha))
        return ahead - turn, ahead + turn

    def _speed(self, now_s: float, tracked: float) -> float:
        """The speed ahead the thrust sent so far gives (the tracker's, from 3 cm fixes at a few
        per second, wanders by +-0.15 m/s); the tracker's when nothing was sent lately."""
        if self._last is None or not 0 <= now_s - self._last[0] <= self.max_age_s:
            self._v, self._thrust = tracked, np.full(2, tracked / self.motion.top_speed_m_s)
            return tracked
        m, dt = self.motion, now_s - self._last[0]
        self._thrust += np.clip(np.asarray(self._last[1]) - self._thrust, -m.ramp_per_s * dt, m.ramp_per_s * dt)
        self._v += (m.top_speed_m_s * float(self._thrust.mean()) - self._v) * (1 - math.exp(-dt / m.speed_tau_s))
        return self._v

    def _sent(self, now_s: float, command):
        self._last = (now_s, command)
        return command

    @classmethod
    def for_pond(cls, geom, body_radius_m: float, **kw) -> Geofence:
        return cls(geom.outline, tuple(geom.keepouts), body_radius_m, **kw)
