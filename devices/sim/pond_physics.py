"""The cleaning robot on the pond floor: two thrusters, drag, slip, a current, and the walls.

Body frame: surge along the heading, sway to its left. Each thruster pushes along the heading
at ``max_thrust_n`` x its command, less a random slip (the robot's feet losing grip) and plus
force noise. Drag acts on the velocity relative to the water (``current_m_s``, pond frame):
small in surge, large in sway, so under a current the robot moves crabwise, its heading off its
course. The walls are the pond's outline: a step that would put any of the body's footprint (a
disc ``body_radius_m``) outside it does not happen: the robot loses its speed into the wall,
slides along it if it can, and ``bumped`` is set for that step (``bumps`` counts such steps).
Everything random comes from ``seed``.

The floor grips the tracks. The robot presses on it with its weight in water
(``submerged_weight_n``). With its drive off (both commands under ``drive_deadband``: the track
motors do not turn and their gearboxes hold them) the tracks grip like a block on the floor:
static friction ``grip_static`` x that weight holds it against whatever else pushes (the
current's drag on the body, 10 N at most for 4 cm/s across it, a random push), kinetic friction
``grip_kinetic`` x that weight brakes it while it slides (cut from full thrust it skids ~6 cm),
and the same grip at half the track holds and brakes its turning. Driven, the
tracks' grip goes into traction and the silt under them shears sideways: the robot yields to
the current and crabs, as it does with no floor at all.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely
import shapely.ops
from shapely.geometry import Polygon

MAX_DT = 0.02          # s: longer steps are split (the yaw time constant is ~0.4 s)
AT_REST_M_S = 1e-3     # slower over the floor than this: at rest (static friction)


@dataclass(frozen=True)
class CleanerParams:
    mass_kg: float = 40.0
    inertia_kg_m2: float = 2.5
    max_thrust_n: float = 12.0             # per thruster, at command 1.0
    track_m: float = 0.5                   # between the thrusters
    drag: float = 60.0                     # N per m/s along the heading (top speed 2 * 12 / 60 = 0.4 m/s)
    sway_drag: float = 240.0               # N per m/s sideways
    yaw_drag: float = 6.0                  # N m per rad/s
    slip: float = 0.05                     # std of the fraction of thrust lost per step
    force_noise_n: float = 0.5             # std of a random push, N
    current_m_s: tuple[float, float] = (0.0, 0.0)
    body_radius_m: float = 0.35
    submerged_weight_n: float = 100.0      # weight less buoyancy: ~10 kg of the 40 kg pressing on the floor
    grip_static: float = 0.5               # rubber tracks held still on a silted liner
    grip_kinetic: float = 0.35             # the same, sliding
    drive_deadband: float = 0.05           # commands under this on both tracks: motors still, tracks held


class PondRobot:
    def __init__(self, params: CleanerParams, outline_xy, x: float, y: float, heading: float, seed: int = 0):
        self.params = params
        self._room = Polygon(outline_xy).buffer(-params.body_radius_m)
        shapely.prepare(self._room)
        self.x, self.y, self.heading = float(x), float(y), float(heading)
        self.vx = self.vy = self.omega = 0.0
        self.bumped = False
        self.bumps = 0
        self._rng = np.random.default_rng(seed)
        if not self.fits(self.x, self.y):
            raise ValueError(f"robot at ({x}, {y}) does not fit inside the pond")

    def fits(self, x: float, y: float) -> bool:
        return bool(shapely.contains_xy(self._room, x, y))

    def step(self, dt_s: float, left: float, right: float) -> None:
        """Advance ``dt_s`` seconds with thrust commands clipped to [-1, 1]."""
        left, right = (max(-1.0, min(1.0, float(c))) for c in (left, right))
        n = max(1, math.ceil(dt_s / MAX_DT))
        self.bumped = False
        for _ in range(n):
            self._substep(dt_s / n, left, right)

    def _substep(self, dt: float, left: float, right: float) -> None:
        p, rng = self.params, self._rng
        held = abs(left) < p.drive_deadband and abs(right) < p.drive_deadband
        if held:
            left = right = 0.0
        grip = 1.0 - np.abs(rng.normal(0.0, p.slip, 2))
        fl, fr = p.max_thrust_n * left * grip[0], p.max_thrust_n * right * grip[1]
        c, s = math.cos(self.heading), math.sin(self.heading)
        rx, ry = self.vx - p.current_m_s[0], self.vy - p.current_m_s[1]
        surge, sway = c * rx + s * ry, -s * rx + c * ry
        push = rng.normal(0.0, p.force_noise_n, 2)
        f_surge = fl + fr - p.drag * surge + push[0]
        f_sway = -p.sway_drag * sway + push[1]
        torque = (fr - fl) * p.track_m / 2 - p.yaw_drag * self.omega
        fx, fy = c * f_surge - s * f_sway, s * f_surge + c * f_sway
        if held:
            self._grip(dt, fx, fy, torque)
        else:
            self.vx += dt * fx / p.mass_kg
            self.vy += dt * fy / p.mass_kg
            self.omega += dt * torque / p.inertia_kg_m2
        self.heading = math.remainder(self.heading + self.omega * dt, 2 * math.pi)
        if self.heading == -math.pi:
            self.heading = math.pi
        if not self._move(dt):
            self._slide(dt)

    def _grip(self, dt: float, fx: float, fy: float, torque: float) -> None:
        """Tracks held: at rest, static friction holds up to ``grip_static`` x weight; sliding,
        ``grip_kinetic`` x weight acts against the motion (never reversing it: it stops there)."""
        p = self.params
        hold, brake = p.grip_static * p.submerged_weight_n, p.grip_kinetic * p.submerged_weight_n
        if math.hypot(self.vx, self.vy) < AT_REST_M_S and math.hypot(fx, fy) <= hold:
            self.vx = self.vy = 0.0
        else:
            vx, vy = self.vx + dt * fx / p.mass_kg, self.vy + dt * fy / p.mass_kg
            speed, cut = math.hypot(vx, vy), dt * brake / p.mass_kg
            k = 0.0 if speed <= cut else 1.0 - cut / speed
            self.vx, self.vy = vx * k, vy * k
        arm = p.track_m / 2                  # the tracks' grip acts about this far from the centre
        if abs(self.omega) < AT_REST_M_S / arm and abs(torque) <= hold * arm:
            self.omega = 0.0
        else:
            w, cut = self.omega + dt * torque / p.inertia_kg_m2, dt * brake * arm / p.inertia_kg_m2
            self.omega = 0.0 if abs(w) <= cut else w - math.copysign(cut, w)

    def _move(self, dt: float) -> bool:
        nx, ny = self.x + self.vx * dt, self.y + self.vy * dt
        if self.fits(nx, ny):
            self.x, self.y = nx, ny
            return True
        return False

    def _slide(self, dt: float) -> None:
        """At the wall: the velocity into it is lost; along it the robot slides, if it fits."""
        self.bumped = True
        self.bumps += 1
        here = shapely.Point(self.x, self.y)
        wall = shapely.ops.nearest_points(self._room.exterior, here)[0]
        n = np.array([self.x - wall.x, self.y - wall.y])
        if np.hypot(*n) < 1e-9:
            n = -np.array([self.vx, self.vy])
        n /= max(np.hypot(*n), 1e-12)
        into = self.vx * n[0] + self.vy * n[1]
        if into < 0:
            self.vx, self.vy = self.vx - into * n[0], self.vy - into * n[1]
        if not self._move(dt):
            self.vx = self.vy = 0.0
