"""The simulated pond: the cleaning robot on its floor, pushed by the thrusters' twin, seen from the tower.

``SimPond`` steps the robot's physics (``PondRobot.step(dt, left, right)``, devices/sim/pond_physics.py)
at a fixed farm-time step with the thrust the twin gives at the middle of each step
(``SimThrusters.thrust``), so the motion does not depend on who looks when, nor on the speed of
the farm clock. A task keeps it up with the clock; ``render(t_s)`` (the tower camera's producer
thread) first brings it up to ``t_s`` and draws the scene (``PondScene.render``,
devices/sim/pond_view.py) with the float at the robot's pose, carried on from the last step by
its velocity. Both paths take one lock. The truth log gets the robot's pose every ``trace_s``.
"""
from __future__ import annotations

import asyncio
import dataclasses
import math
import threading
from collections.abc import Callable
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from devices.errors import BadInput
from devices.sections import validate_section
from devices.sim.ptys import end_task

Thrust = Callable[[float], tuple[float, float]]
WALL_PERIOD_S = 0.01          # how often the task brings the physics up to the clock


class SimPondParams(BaseModel):
    """farm.toml ``[sim.pond]``. The outline, keep-outs and start (the dock, heading 0) default to
    the ``[cleaning]`` section's."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    outline: list[tuple[float, float]] | None = None
    keepouts: list[list[tuple[float, float]]] | None = None
    start: tuple[float, float, float] | None = Field(None, description="x_m, y_m, heading_rad at power-on; "
                                                     "default: [cleaning] dock, else a point of the floor; heading 0")
    step_s: float = Field(0.02, gt=0, le=0.5, description="farm seconds per physics step")
    trace_s: float = Field(1.0, gt=0, description="farm seconds between truth records of the pose")
    robot: dict[str, Any] = Field({}, description="pond_physics.CleanerParams fields")
    tower: dict[str, Any] = Field({}, description="pond_view.tower_view keywords (tower_xy, tower_height_m, hfov_deg)")
    conditions: dict[str, Any] | None = Field(None, description="pond_view.PondScene conditions")
    seed: int = 0

    @field_validator("conditions")
    @classmethod
    def _conditions(cls, given: dict[str, Any] | None) -> dict[str, Any] | None:
        # checked with the config: out of range, it was the simulator's "internal error" exit 1
        # after the controller had started it and made its ledger (an outside tester)
        from devices.sim.pond_scene import scene_conditions
        try:
            scene_conditions(np.zeros((3, 2)), 0, given)
        except ValueError as exc:
            raise ValueError(str(exc).removeprefix("conditions: ")) from None
        return given


def wrap(angle: float) -> float:
    """An angle in (-pi, pi]."""
    a = math.remainder(angle, math.tau)
    return math.pi if a == -math.pi else a


class SimPond:
    """``robot``: a ``PondRobot`` (x, y, heading, vx, vy, omega; ``step(dt, left, right)``);
    ``thrust(t)``: the thrust at farm time t; ``scene``: a ``PondScene`` or None (no camera)."""

    def __init__(self, robot, thrust: Thrust, clock, *, step_s: float = 0.02, scene=None,
                 float_pose: Callable | None = None, truth=None, trace_s: float = 1.0):
        self.robot, self.thrust, self.clock, self.scene = robot, thrust, clock, scene
        self.step_s, self.truth, self.trace_s = step_s, truth, trace_s
        self.float_pose = float_pose or (lambda x, y, h: (x, y, h))
        self.t0 = self.t = clock.now()        # farm time the robot's state is at
        self.steps = 0                        # t = t0 + steps * step_s: no drift from summing steps
        self._next_trace = self.t
        self._lock = threading.Lock()
        self._task: asyncio.Task | None = None
        self.halted = False                   # set on the way out: no more stepping, whoever asks

    def halt(self) -> None:
        """Stop stepping now, from any thread: a physics far behind a fast clock (at 600x the demo's
        pond asks 30,000 steps a wall second) no longer holds the process's stop while it catches up."""
        self.halted = True

    def advance(self, until: float) -> None:
        """Step the physics up to ``until`` (farm s), to within one step."""
        with self._lock:
            self._advance(until)

    def _advance(self, until: float) -> None:
        dt = self.step_s
        robot = self.robot
        while self.t + dt <= until and not self.halted:
            left, right = self.thrust(self.t + dt / 2)
            robot.step(dt, left, right)
            self.steps += 1
            self.t = self.t0 + self.steps * dt
            if self.truth is not None and self.t >= self._next_trace:
                self._next_trace = self.t + self.trace_s
                self.truth.write("cleaner", self.t, x_m=round(robot.x, 4), y_m=round(robot.y, 4),
                                 heading_rad=round(wrap(robot.heading), 5), left=round(left, 3),
                                 right=round(right, 3), bumped=bool(getattr(robot, "bumped", False)))

    def pose(self, t: float | None = None) -> tuple[float, float, float]:
        """The robot's (x_m, y_m, heading_rad) at farm time ``t`` (default now)."""
        t = self.clock.now() if t is None else t
        with self._lock:
            self._advance(t)
            return self._pose_at(t)

    def _pose_at(self, t: float) -> tuple[float, float, float]:
        r = self.robot
        dt = max(0.0, t - self.t)             # less than one step: carried on by the velocity
        return (r.x + getattr(r, "vx", 0.0) * dt, r.y + getattr(r, "vy", 0.0) * dt,
                wrap(r.heading + getattr(r, "omega", 0.0) * dt))

    def render(self, t_s: float):
        """The tower camera's picture at farm time ``t_s``."""
        if self.scene is None:
            raise RuntimeError("this pond has no scene to render")
        return self.scene.render(t_s, self.float_pose(*self.pose(t_s)))

    # --- life cycle -------------------------------------------------------------------------------
    async def start(self) -> None:
        self._task = asyncio.create_task(self._run(), name="sim-pond")

    async def stop(self) -> None:
        self.halt()
        await end_task(self._task)
        self._task = None

    async def _run(self) -> None:
        # physics on a worker thread: a fast clock makes many steps per look, and the loop
        # serves the thrusters' line meanwhile
        while True:
            await asyncio.to_thread(self.advance, self.clock.now())
            await asyncio.sleep(WALL_PERIOD_S)


def pond_outline(cfg: Any):
    """The ``[cleaning]`` section's pond outline, if the config has one."""
    return _cleaning(cfg, "outline")


def _cleaning(cfg: Any, key: str):
    section = getattr(cfg, "cleaning", None)
    if section is None:
        return None
    return section.get(key) if isinstance(section, dict) else getattr(section, key, None)


def check_robot(robot: dict, where: str) -> CleanerParams:  # noqa: F821 - imported inside
    """``[sim.pond] robot``: pond_physics.CleanerParams fields, each a finite number (its current
    a pair); BadInput naming the key (``speed = 1`` was a TypeError from the simulator)."""
    from devices.sim.pond_physics import CleanerParams
    fields = {f.name: f for f in dataclasses.fields(CleanerParams)}
    for key, value in robot.items():
        if key not in fields:
            raise BadInput(where, f"sim.pond.robot.{key}", f"unknown key (keys: {', '.join(fields)})")
        numbers = value if key == "current_m_s" else [value]
        if (key == "current_m_s" and (not isinstance(value, list | tuple) or len(value) != 2)) or not all(
                isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) for x in numbers):
            raise BadInput(where, f"sim.pond.robot.{key}",
                           "must be two finite numbers" if key == "current_m_s" else "must be a finite number")
        if key not in ("current_m_s", "slip", "force_noise_n") and value <= 0:
            raise BadInput(where, f"sim.pond.robot.{key}", f"must be above 0, not {value}")
    return CleanerParams(**{k: tuple(v) if k == "current_m_s" else float(v) for k, v in robot.items()})


def pond_params(cfg: Any, raw: dict, where: str) -> SimPondParams:
    """``[sim.pond]`` with the outline and keep-outs filled from ``[cleaning]`` where not given."""
    params = validate_section(SimPondParams, raw, where, "sim.pond")
    if params.start is None and _cleaning(cfg, "dock") is not None:
        x, y = _cleaning(cfg, "dock")
        params = params.model_copy(update={"start": (float(x), float(y), 0.0)})
    outline = params.outline if params.outline is not None else _cleaning(cfg, "outline")
    if outline is None:
        raise BadInput(where, "sim.pond.outline", "the simulated pond needs an outline ([sim.pond] or [cleaning])")
    keepouts = params.keepouts if params.keepouts is not None else (_cleaning(cfg, "keepouts") or [])
    return params.model_copy(update={"outline": [tuple(map(float, p)) for p in outline],
                                     "keepouts": [[tuple(map(float, p)) for p in k] for k in keepouts]})


def start_pose(params: SimPondParams, body_radius_m: float = 0.0) -> tuple[float, float, float]:
    """``[sim.pond] start``, or a point of the floor clear of the walls and keep-outs by the body."""
    if params.start is not None:
        return params.start
    from shapely.geometry import Polygon
    floor = Polygon(params.outline, holes=params.keepouts or None).buffer(-body_radius_m)
    p = (floor if not floor.is_empty else Polygon(params.outline)).representative_point()
    return (p.x, p.y, 0.0)


def pond_view(params: SimPondParams, width: int, height: int, where: str = "farm.toml"):
    """The simulated tower camera's view of the pond: its exact pixel -> pond homography is ``.H``."""
    from devices.sim.pond_view import tower_view
    try:
        return tower_view(params.outline, width=width, height=height, **params.tower)
    except (TypeError, ValueError) as exc:
        raise BadInput(where, "sim.pond.tower", str(exc)) from None


def build_pond(cfg: Any, raw: dict, clock, thrust: Thrust, *, camera: dict | None, truth=None,
               where: str = "farm.toml") -> SimPond:
    """The pond of the config: physics (devices/sim/pond_physics.py) and, when ``camera`` gives its
    ``width``/``height``, the tower's view of it (devices/sim/pond_view.py)."""
    from devices.sim.pond_physics import PondRobot
    params = pond_params(cfg, raw, where)
    try:
        robot_params = check_robot(params.robot, where)
    except (TypeError, ValueError) as exc:
        raise BadInput(where, "sim.pond.robot", str(exc)) from None
    x, y, heading = start_pose(params, getattr(robot_params, "body_radius_m", 0.0))
    try:
        robot = PondRobot(robot_params, params.outline, x, y, heading, seed=params.seed)
    except ValueError as exc:
        raise BadInput(where, "sim.pond.start", str(exc)) from None
    scene = float_pose = None
    if camera is not None:
        from devices.sim.pond_view import FloatPose, PondScene
        view = pond_view(params, camera["width"], camera["height"], where)
        scene = PondScene(view, params.outline, params.keepouts, seed=params.seed, conditions=params.conditions)
        float_pose = FloatPose
    return SimPond(robot, thrust, clock, step_s=params.step_s, scene=scene, float_pose=float_pose,
                   truth=truth, trace_s=params.trace_s)


def main(argv: list[str] | None = None) -> int:
    """``python -m devices.sim.pond --config farm.toml --out TOWER.json``: the simulated tower
    camera's exact TOWER.json for that config, for ``[cleaning] tower``."""
    import argparse
    import json
    import sys
    import tomllib
    from types import SimpleNamespace

    from devices.sim.tower_camera import SimTowerCameraParams

    ap = argparse.ArgumentParser(prog="python -m devices.sim.pond", description=main.__doc__)
    ap.add_argument("--config", default="config/farm.toml")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    try:
        with open(a.config, "rb") as f:
            raw = tomllib.load(f)
        sim = raw.get("sim", {})
        params = pond_params(SimpleNamespace(cleaning=raw.get("cleaning")), sim.get("pond", {}), a.config)
        cam = validate_section(SimTowerCameraParams, sim.get("tower_camera", {}), a.config, "sim.tower_camera")
        view = pond_view(params, cam.width, cam.height, a.config)
        with open(a.out, "w", encoding="utf-8") as f:
            json.dump({"H": view.H.tolist(), "image_size": [cam.width, cam.height]}, f, indent=2)
    except (BadInput, OSError, tomllib.TOMLDecodeError) as exc:
        print(f"{exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
