"""Tracking the cleaner's float over time: a filterpy Kalman filter over position, heading and
their rates, fed by ``detect_float`` one frame at a time, at whatever (irregular) times the frames
carry.

State ``[x, vx, y, vy, heading, heading_rate]``: the velocity turning at the heading's rate
(coordinated turn), white-noise acceleration. The heading lives on the circle: the innovation is
wrapped to (-pi, pi] before the update and the state's heading wrapped after, so a float turning
through +-pi is one smooth motion. A fix whose position is far from the prediction (squared
Mahalanobis distance over ``gate``) is held out: a sun glint paired with a blue ball must not drag
the track; a fix in place whose heading jumped (a spin the model did not foresee) restarts the
heading there. Gating cannot lock the tracker out: ``reinit_after`` held-out fixes in a row that
agree with each other (a speed the float can do between them) restart the track there, and so does
a fix once the position is this uncertain (``reinit_std_m``); the gate also widens by itself as the
position's uncertainty grows while coasting. Either restart takes only a fix the float could have
reached since its last fix taken (``max_speed_m_s``, ``MAX_SPEED_M_S``; a run of held-out fixes
judged by its first, at its own time): a spare float lying still 11 m off, seen while ours was
hidden for 0.3 s, agreed with itself and took the track for good, and so did one 1 m off at 2 m/s
(ours hidden 0.3 s, the spare seen from then on). Beyond that reach
the track coasts to "lost", after which the first good fix anywhere starts it again.

A fix that gives the position alone (``heading_known`` False: the orange disc seen, its blue not
made out — a blue tarp under it) updates position and speed only; the heading coasts on its rate
and its uncertainty grows. Such fixes never start a track, and once the heading's 1-sigma passes
``max_heading_std_rad`` they no longer count as "tracking": the pose is then "predicted".

States: "tracking" (this frame's fix was taken), "predicted" (coasting on the model through a
dropout), "lost" (no fix taken for longer than ``lost_after_s``: no position is given). The
first good fix after "lost" starts the track again at once.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter
from scipy.linalg import block_diag

from vision.float_detect import FloatFix, FloatParams, detect_float

State = Literal["tracking", "predicted", "lost"]
_MEASURE = np.array([[1.0, 0, 0, 0, 0, 0], [0, 0, 1, 0, 0, 0], [0, 0, 0, 0, 1, 0]])


@dataclass(frozen=True)
class FloatTrack:
    t_s: float
    x_m: float | None
    y_m: float | None
    heading_rad: float | None
    state: State
    std_m: float | None
    speed_m_s: float | None


def _wrap(a: float) -> float:
    return math.pi - (math.pi - a) % (2 * math.pi)


# The cleaner's top speed (0.4 m/s: two 12 N thrusters against 60 N per m/s of drag, the simulated
# pond's too) with a current's 0.1 m/s and a margin. At 2 m/s (before 2026-12-05) a second float
# 1 m off, seen while ours was hidden for 0.3 s, was in reach and took the track for good.
MAX_SPEED_M_S = 0.6


class FloatTracker:
    """One float's track from fixes (or None: a dropout) at increasing times.

    ``pos_std_m``, ``heading_std_rad``: a fix's error at confidence 1 (it grows as 1/confidence);
    ``accel_std`` (m/s^2), ``yaw_accel_std`` (rad/s^2): how briskly the float may change course;
    ``turn``: the share of the heading's rate the velocity turns at (1: goes where it faces, 0:
    straight on); ``gate``: squared Mahalanobis distance (2 dof) past which a fix is held out;
    ``reach_m``: the marker's extent around the robot, for the search region; ``slack_m``: how far
    beyond ``max_speed_m_s`` x the time since its last fix the float may be found (a fix's own
    error, the orange disc's radius): no fix farther is taken, however wide the gate has grown."""

    def __init__(self, *, lost_after_s: float = 4.0, pos_std_m: float = 0.02, heading_std_rad: float = 0.03,
                 accel_std: float = 1.5, yaw_accel_std: float = 0.6, gate: float = 13.8,
                 reinit_after: int = 3, max_speed_m_s: float = MAX_SPEED_M_S, reinit_std_m: float = 1.0,
                 min_confidence: float = 0.15, reach_m: float = 0.6, turn: float = 1.0,
                 max_heading_std_rad: float = 0.12, slack_m: float = 0.25, scan_every_s: float = 2.0,
                 spare_radius_m: float = 0.5, spare_memory_s: float = 120.0):
        if not lost_after_s > 0:
            raise ValueError("lost_after_s must be > 0")
        if reinit_after < 1:
            raise ValueError("reinit_after must be >= 1")
        self.lost_after_s = lost_after_s
        self.pos_std_m, self.heading_std_rad = pos_std_m, heading_std_rad
        self.accel_std, self.yaw_accel_std = accel_std, yaw_accel_std
        self.gate, self.reinit_after, self.max_speed_m_s = gate, reinit_after, max_speed_m_s
        self.reinit_std_m, self.min_confidence, self.reach_m = reinit_std_m, min_confidence, reach_m
        self.turn, self.max_heading_std_rad, self.slack_m = turn, max_heading_std_rad, slack_m
        self.scan_every_s, self.spare_radius_m, self.spare_memory_s = scan_every_s, spare_radius_m, spare_memory_s
        self._spares: list[tuple[float, float, float]] = []   # (x, y, last seen): markers not ours
        self._scan_t = -math.inf
        self.kf: KalmanFilter | None = None
        self._t: float | None = None          # time the filter stands at
        self._fix_t = -math.inf               # time of the last fix taken
        self._fix_xy = (math.nan, math.nan)   # ... and where
        self._dt = 0.0                        # the last step between frames (the next one, likely)
        self._held: list[tuple[float, FloatFix]] = []   # held-out fixes in a row
        self.state: State = "lost"

    # -- the filter -------------------------------------------------------------------------
    def _start(self, t: float, fix: FloatFix) -> None:
        kf = KalmanFilter(dim_x=6, dim_z=3)
        kf.x = np.array([fix.x_m, 0.0, fix.y_m, 0.0, fix.heading_rad, 0.0])
        kf.H = _MEASURE.copy()
        # speed unknown at the start: up to what the float can do
        kf.P = np.diag([self.pos_std_m ** 2, (0.5 * self.max_speed_m_s) ** 2, self.pos_std_m ** 2,
                        (0.5 * self.max_speed_m_s) ** 2, self.heading_std_rad ** 2, 1.0])
        self.kf, self._t, self._fix_t, self._held = kf, t, t, []
        self._fix_xy = (fix.x_m, fix.y_m)
        self.state = "tracking"
        self._note_spares(t, fix)

    def _predict(self, dt: float) -> None:
        """Coordinated turn: the velocity turns at the heading's rate (a robot goes where it faces,
        give or take the current), so a float unseen through a bend is predicted round it. With the
        rate taken as known over the step the model stays linear for filterpy's KalmanFilter."""
        if dt <= 0:
            return
        w = self.turn * float(self.kf.x[5])
        wt = w * dt
        if abs(wt) < 1e-6:
            s, c = dt, 0.5 * w * dt * dt                    # sin(wt)/w, (1 - cos wt)/w near w = 0
        else:
            s, c = math.sin(wt) / w, (1 - math.cos(wt)) / w
        cw, sw = math.cos(wt), math.sin(wt)
        F = np.eye(6)
        F[0, 1], F[0, 3], F[2, 1], F[2, 3] = s, -c, c, s
        F[1, 1], F[1, 3], F[3, 1], F[3, 3] = cw, -sw, sw, cw
        F[4, 5] = dt
        self.kf.F = F
        qp = Q_discrete_white_noise(2, dt, self.accel_std ** 2)
        self.kf.Q = block_diag(qp, qp, Q_discrete_white_noise(2, dt, self.yaw_accel_std ** 2))
        self.kf.predict()
        self.kf.x[4] = _wrap(self.kf.x[4])

    def _measure(self, fix: FloatFix) -> tuple[np.ndarray, np.ndarray]:
        z = np.array([fix.x_m, fix.y_m, self.kf.x[4] + _wrap(fix.heading_rad - self.kf.x[4])])
        c = max(fix.confidence, 1e-3)
        R = np.diag([self.pos_std_m ** 2, self.pos_std_m ** 2, self.heading_std_rad ** 2]) / (c * c)
        return z, R

    def _distance2(self, z: np.ndarray, R: np.ndarray) -> tuple[float, float]:
        """Squared Mahalanobis distances of the fix's position and of its heading from the prediction."""
        y = z - _MEASURE @ self.kf.x
        S = _MEASURE @ self.kf.P @ _MEASURE.T + R
        return float(y[:2] @ np.linalg.solve(S[:2, :2], y[:2])), float(y[2] ** 2 / S[2, 2])

    def _turned(self, z: np.ndarray, R: np.ndarray) -> None:
        """The heading jumped (a spin the model did not foresee): the marker says where it points
        now, so heading and its rate restart from the fix; position and speed are kept."""
        self.kf.x[4], self.kf.x[5] = z[2], 0.0
        self.kf.P[4:, :] = 0.0
        self.kf.P[:, 4:] = 0.0
        self.kf.P[4, 4], self.kf.P[5, 5] = R[2, 2], 1.0

    def _consistent(self) -> bool:
        """The held-out fixes in a row describe one object moving as the float can."""
        if len(self._held) < self.reinit_after:
            return False
        run = self._held[-self.reinit_after:]
        for (t0, a), (t1, b) in zip(run, run[1:], strict=False):
            reach = self.max_speed_m_s * max(t1 - t0, 0.0) + 3 * self.pos_std_m / min(a.confidence, b.confidence)
            if math.hypot(b.x_m - a.x_m, b.y_m - a.y_m) > reach:
                return False
        return True

    def _reachable(self, t: float, fix: FloatFix) -> bool:
        """Whether the float could be at ``fix`` by ``t`` from where its last fix was taken."""
        reach = (self.max_speed_m_s * max(t - self._fix_t, 0.0) + self.slack_m
                 + 3 * self.pos_std_m / max(fix.confidence, 1e-3))
        return math.hypot(fix.x_m - self._fix_xy[0], fix.y_m - self._fix_xy[1]) <= reach

    def _note_spares(self, t: float, fix: FloatFix) -> None:
        """Markers seen beside ours in a fix taken: spares (another cleaner's float, one lying by)."""
        # none where ours is: two markers do not lie in one place (a spare taken away, ours there now)
        keep = [sp for sp in self._spares if t - sp[2] <= self.spare_memory_s
                and math.hypot(sp[0] - fix.x_m, sp[1] - fix.y_m) > self.spare_radius_m]
        for x, y in fix.others:
            keep = [sp for sp in keep if math.hypot(sp[0] - x, sp[1] - y) > self.spare_radius_m]
            keep.append((x, y, t))
        self._spares = keep

    def _at_spare(self, t: float, fix: FloatFix) -> bool:
        return any(t - st <= self.spare_memory_s and math.hypot(fix.x_m - x, fix.y_m - y) <= self.spare_radius_m
                   for x, y, st in self._spares)

    def _in_place(self, fix: FloatFix) -> bool:
        """The fix is where the float is predicted, within a fix's error and the slack."""
        return (math.hypot(fix.x_m - self.kf.x[0], fix.y_m - self.kf.x[2])
                <= self.slack_m + 3 * self.pos_std_m / max(fix.confidence, 1e-3))

    # -- public --------------------------------------------------------------------------------
    def wants_scan(self, t_s: float) -> bool:
        """Whether this frame's detection should also list the frame's other markers
        (``detect_float(scan=True)``): every ``scan_every_s`` while tracking. Answering yes counts
        as the scan done."""
        if self.kf is None or self.state != "tracking" or t_s - self._scan_t < self.scan_every_s:
            return False
        self._scan_t = t_s
        return True

    def step(self, t_s: float, fix: FloatFix | None) -> FloatTrack:
        """Advance to ``t_s`` and take ``fix`` (None: the float was not seen in this frame).

        A fix at a spare (a marker once seen beside ours, ``FloatFix.others``) is taken only where
        ours is predicted: it never starts or restarts the track; nor is a fix whose heading jumped
        away from where ours is predicted taken as a spin (a spare 1 m off at right angles was)."""
        t_s = float(t_s)
        if fix is not None and not fix.confidence >= self.min_confidence:
            fix = None
        spare = fix is not None and self._at_spare(t_s, fix)
        if self.kf is None or self.state == "lost":
            if fix is not None and fix.heading_known and not spare:
                self._start(t_s, fix)
            else:
                self._t = t_s
            return self._report(t_s)
        if t_s > self._t:
            self._dt = t_s - self._t
        self._predict(t_s - self._t)
        self._t = max(self._t, t_s)
        taken = False
        if fix is not None:
            z, R = self._measure(fix)
            d_pos, d_heading = self._distance2(z, R)
            jumped = fix.heading_known and d_heading > self.gate
            if d_pos <= self.gate and self._reachable(t_s, fix) and (self._in_place(fix) or not (jumped or spare)):
                if not fix.heading_known:
                    self.kf.update(z[:2], R=R[:2, :2], H=_MEASURE[:2])
                    taken = self.heading_std() <= self.max_heading_std_rad
                else:
                    if jumped:
                        self._turned(z, R)
                    self.kf.update(z, R=R)
                    taken = True
                self.kf.x[4] = _wrap(self.kf.x[4])
                self._held = []
                if taken:
                    self._fix_t = t_s
                    self._fix_xy = (float(self.kf.x[0]), float(self.kf.x[2]))
                    self._note_spares(t_s, fix)
            elif fix.heading_known and not spare:
                self._held.append((t_s, fix))
                # the run's first fix judged at its own time: a float it follows could have been
                # there by then (judged at the latest, the whole hold counted as travel time)
                consistent = self._consistent()
                first_t, first = self._held[-self.reinit_after] if consistent else (t_s, fix)
                if (consistent or self.std_m() > self.reinit_std_m) and self._reachable(first_t, first):
                    self._start(t_s, fix)
                    return self._report(t_s)
        if taken:
            self.state = "tracking"
        elif t_s - self._fix_t > self.lost_after_s:
            self.state, self._held = "lost", []
        else:
            self.state = "predicted"
        return self._report(t_s)

    def heading_std(self) -> float:
        return float(math.sqrt(max(self.kf.P[4, 4], 0.0)))

    def std_m(self) -> float:
        """Position uncertainty (m): the larger axis of the position's 1-sigma ellipse."""
        P = self.kf.P[np.ix_([0, 2], [0, 2])]
        return float(math.sqrt(max(np.linalg.eigvalsh(P)[-1], 0.0)))

    def _report(self, t_s: float) -> FloatTrack:
        if self.kf is None or self.state == "lost":
            return FloatTrack(t_s, None, None, None, "lost", None, None)
        x = self.kf.x
        return FloatTrack(t_s, float(x[0]), float(x[2]), _wrap(float(x[4])), self.state, self.std_m(),
                          float(math.hypot(x[1], x[3])))

    def search_region(self, t_s: float | None = None) -> tuple[float, float, float] | None:
        """(x_m, y_m, radius_m) where the float should be at ``t_s`` (default: one frame step on),
        for ``detect_float(near=...)``; None when lost: search the whole frame."""
        if self.kf is None or self.state == "lost":
            return None
        x, vx, y, vy = (float(v) for v in self.kf.x[:4])
        dt = min(max(self._dt if t_s is None else t_s - self._t, 0.0), 1.0)
        return x + vx * dt, y + vy * dt, self.reach_m + 3 * self.std_m() + 0.5 * math.hypot(vx, vy) * dt


def track_frame(tracker: FloatTracker, t_s: float, frame_bgr: np.ndarray, H: np.ndarray,
                params: FloatParams | None = None) -> tuple[FloatTrack, FloatFix | None]:
    """One camera frame through detection and tracking, as the controller and ``fishfarm track`` run it:
    the detector looks first where the tracker expects the float at this frame's time (and now and
    then over the whole frame for spares)."""
    fix = detect_float(frame_bgr, H, params or FloatParams(), near=tracker.search_region(t_s),
                       scan=tracker.wants_scan(t_s))
    return tracker.step(t_s, fix), fix
