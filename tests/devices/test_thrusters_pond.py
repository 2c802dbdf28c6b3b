"""The simulated pond's glue: the thrusters' twin pushes the robot's physics at a fixed farm step,
the tower camera draws the robot where it is, and ``fishfarm sim`` serves both to the real drivers.

The physics (devices/sim/pond_physics.py) and the renderer (devices/sim/pond_view.py) are other
parts' work; here they are stand-ins with the same interface whose answers can be worked out by
hand, so what is tested is the glue: which thrust, when, which pose, which frame."""
from __future__ import annotations

import asyncio
import json
import math
import sys
import types
from dataclasses import dataclass

import numpy as np
import pytest

from controller.config import Config, TankConfig
from devices.camera.capture import CaptureCamera
from devices.camera.capture import Config as CameraConfig
from devices.clock import ManualClock
from devices.errors import BadInput
from devices.sim.pond import SimPond, build_pond, pond_params, wrap
from devices.sim.thrusters import SimThrusterParams, ThrusterTwin
from devices.sim.truth import TruthLog
from devices.sim.world import SimFarm
from devices.thrusters import protocol as p
from devices.thrusters.serial_thrusters import Config as ThrustersConfig
from devices.thrusters.serial_thrusters import SerialThrusters

SPEED = 0.5            # m/s at full thrust on both sides, stand-in physics
TURN = 0.4             # rad/s per unit of thrust difference
LOADED_S = 5.0         # wall s for a reply: the glue is under test here, not a loaded machine's latency


@dataclass(frozen=True)
class CleanerParams:
    mass_kg: float = 40.0


class PondRobot:
    """Stand-in physics: velocity proportional to thrust, no inertia — positions are integrals of thrust."""

    def __init__(self, params, outline_xy, x, y, heading, seed=0):
        self.x, self.y, self.heading = x, y, heading
        self.vx = self.vy = self.omega = 0.0
        self.bumped = False
        self.outline = outline_xy
        self.calls = []

    def step(self, dt, left, right):
        self.calls.append((dt, left, right))
        v = SPEED * (left + right) / 2
        self.omega = TURN * (right - left)
        self.vx, self.vy = v * math.cos(self.heading), v * math.sin(self.heading)
        self.x += self.vx * dt
        self.y += self.vy * dt
        self.heading += self.omega * dt


@dataclass(frozen=True)
class FloatPose:
    x_m: float
    y_m: float
    heading_rad: float


class Scene:
    """Stand-in renderer: the float's x (2.5 cm a grey level) as the whole frame; notes each ask."""

    def __init__(self, view, outline_xy, keepouts=(), *, seed=0, conditions=None):
        self.view, self.asked = view, []

    def render(self, t_s, pose, *, occlusion=0.0):
        self.asked.append((t_s, pose))
        img = np.zeros((self.view["height"], self.view["width"], 3), np.uint8)
        img[:, :] = min(255, max(0, round(pose.x_m * 40)))
        return img


def tower_view(outline_xy, *, width=1280, height=720, **kw):
    return {"width": width, "height": height, **kw}


@pytest.fixture
def stand_in_physics(monkeypatch):
    physics = types.ModuleType("devices.sim.pond_physics")
    physics.CleanerParams, physics.PondRobot = CleanerParams, PondRobot
    monkeypatch.setitem(sys.modules, "devices.sim.pond_physics", physics)


@pytest.fixture
def stand_ins(monkeypatch, stand_in_physics):
    view = types.ModuleType("devices.sim.pond_view")
    view.FloatPose, view.PondScene, view.tower_view = FloatPose, Scene, tower_view
    monkeypatch.setitem(sys.modules, "devices.sim.pond_view", view)


OUTLINE = [(0.0, 0.0), (20.0, 0.0), (20.0, 10.0), (0.0, 10.0)]


def twin_and_pond(clock, step_s=0.02, **kw):
    twin = ThrusterTwin(SimThrusterParams(), clock.now())
    robot = PondRobot(None, OUTLINE, 1.0, 2.0, 0.0)
    return twin, robot, SimPond(robot, twin.thrust, clock, step_s=step_s, **kw)


def test_the_robot_moves_by_the_thrust_the_twin_gives_watchdog_and_ramps_included():
    clock = ManualClock()
    twin, robot, pond = twin_and_pond(clock)
    t0 = clock.now()
    assert twin.handle(p.Line("D", (1, 1000, 1000)), t0) is p.Result.ACCEPTED
    clock.advance(3.0)                     # nobody drives again: the watchdog stops it at 0.5 s
    pond.advance(clock.now())
    # thrust: ramp 0->1 over 0.25 s, full to 0.5 s (watchdog), ramp 1->0 over 0.25 s: 0.5 s of full
    assert robot.x == pytest.approx(1.0 + SPEED * 0.5, abs=1e-6)     # farm time in Unix s: ulp 2e-7
    assert robot.y == pytest.approx(2.0) and twin.watchdog_trips == [pytest.approx(t0 + 0.5)]
    assert all(c[0] == 0.02 for c in robot.calls) and len(robot.calls) == pytest.approx(150, abs=1)


def test_the_motion_does_not_depend_on_who_looks_when():
    a_clock, b_clock = ManualClock(), ManualClock()
    # binary fractions of a second: farm time in Unix seconds adds them exactly
    a_twin, a_robot, a = twin_and_pond(a_clock, step_s=1 / 64)
    b_twin, b_robot, b = twin_and_pond(b_clock, step_s=1 / 64)
    for twin, clock in ((a_twin, a_clock), (b_twin, b_clock)):
        twin.handle(p.Line("D", (1, 300, 900)), clock.now())
    a_clock.advance(0.4375)
    a.advance(a_clock.now())                                  # one look
    for _ in range(56):                                       # 56 looks, between steps
        b_clock.advance(1 / 128)
        b.advance(b_clock.now() - 1 / 256)
    b.advance(b_clock.now())
    assert a.steps == b.steps == 28
    assert (a_robot.x, a_robot.y, a_robot.heading) == pytest.approx((b_robot.x, b_robot.y, b_robot.heading), abs=1e-12)
    assert a_robot.heading > 0                                 # more thrust right: turns left (ccw)


def test_render_draws_the_float_at_the_pose_carried_on_within_the_step():
    clock = ManualClock()
    twin, robot, pond = twin_and_pond(clock, step_s=0.1, scene=Scene({"width": 64, "height": 48}, OUTLINE),
                                      float_pose=FloatPose)
    twin.handle(p.Line("W", (1, 10_000)), clock.now())
    twin.handle(p.Line("D", (2, 1000, 1000)), clock.now())
    clock.advance(1.0)
    pond.advance(clock.now())
    x1 = robot.x
    img = pond.render(clock.now() + 0.05)                      # half a step on
    t, pose = pond.scene.asked[-1]
    assert pose.x_m == pytest.approx(x1 + SPEED * 0.05) and pose.heading_rad == 0.0
    assert img[0, 0, 0] == round(pose.x_m * 40)


def test_the_truth_log_traces_the_robot(tmp_path):
    clock = ManualClock()
    truth = TruthLog(tmp_path / "truth.jsonl")
    twin, robot, pond = twin_and_pond(clock, truth=truth, trace_s=0.5)
    twin.handle(p.Line("D", (1, 500, 500)), clock.now())
    clock.advance(2.0)
    pond.advance(clock.now())
    truth.close()
    lines = (tmp_path / "truth.jsonl").read_text().splitlines()
    assert len(lines) == 4 and all('"cleaner"' in line and '"x_m"' in line for line in lines)


def test_wrap_keeps_headings_in_the_half_open_interval():
    for a in np.linspace(-20, 20, 4001):
        w = wrap(float(a))
        assert -math.pi < w <= math.pi and math.isclose(math.cos(w), math.cos(a), abs_tol=1e-9)
    assert wrap(-math.pi) == math.pi


def test_the_outline_comes_from_sim_pond_or_the_cleaning_section():
    cfg = types.SimpleNamespace(cleaning={"outline": OUTLINE, "keepouts": [[(5, 5), (6, 5), (6, 6)]]})
    params = pond_params(cfg, {}, "farm.toml")
    assert params.outline == OUTLINE and params.keepouts == [[(5.0, 5.0), (6.0, 5.0), (6.0, 6.0)]]
    assert pond_params(cfg, {"outline": [(0, 0), (1, 0), (1, 1)]}, "f").outline == [(0, 0), (1, 0), (1, 1)]
    with pytest.raises(BadInput, match="farm.toml: sim.pond.outline: the simulated pond needs an outline"):
        pond_params(types.SimpleNamespace(), {}, "farm.toml")
    with pytest.raises(BadInput, match="sim.pond.stepp: unknown key"):
        pond_params(cfg, {"stepp": 1}, "farm.toml")


def test_the_default_start_is_on_the_floor_outside_every_keepout(stand_ins):
    keep = [(8.0, 3.0), (12.0, 3.0), (12.0, 7.0), (8.0, 7.0)]
    cfg = types.SimpleNamespace(cleaning={"outline": OUTLINE, "keepouts": [keep]})
    pond = build_pond(cfg, {}, ManualClock(), lambda t: (0.0, 0.0), camera=None)
    x, y, _ = pond.pose()
    assert 0 < x < 20 and 0 < y < 10 and not (8 <= x <= 12 and 3 <= y <= 7)
    assert pond.scene is None


def test_the_real_renderer_draws_the_pond_at_the_camera_s_size(stand_in_physics):
    cfg = types.SimpleNamespace(cleaning={"outline": OUTLINE})
    pond = build_pond(cfg, {"start": (4.0, 5.0, 1.0)}, ManualClock(), lambda t: (0.0, 0.0),
                      camera={"width": 320, "height": 180})
    img = pond.render(pond.t)
    assert img.shape == (180, 320, 3) and img.dtype == np.uint8
    # the float is drawn where the robot is: its orange disc's centre projects near the pixels
    # that differ from the same scene with the float elsewhere
    moved = build_pond(cfg, {"start": (15.0, 5.0, 1.0)}, ManualClock(), lambda t: (0.0, 0.0),
                       camera={"width": 320, "height": 180})
    diff = np.abs(img.astype(int) - moved.render(pond.t).astype(int)).sum(axis=2)
    u, v = pond.scene.view.to_pixels(np.array([[4.0, 5.0]]))[0]
    near = diff[max(0, int(v) - 6):int(v) + 7, max(0, int(u) - 6):int(u) + 7]
    assert near.max() > 100


def farm_config() -> Config:
    return Config(tanks=[TankConfig(id="T1", stock=100, mean_weight_g=50, position_m=2.0, sensors=["T1-a"])],
                  path="<test>",
                  devices={"thrusters": {"kind": "thrusters", "driver": "sim", "watchdog_s": 2.0},
                           "tower": {"kind": "tower_camera", "driver": "sim"}},
                  sim={"pond": {"outline": OUTLINE, "start": (3.0, 5.0, 0.0), "step_s": 0.01},
                       "tower_camera": {"width": 160, "height": 96, "fps": 50}})


def test_fishfarm_sim_serves_thrusters_and_camera_to_the_real_drivers(stand_ins):
    """Drive through the serial driver; the camera, read through VideoCapture, sees the robot move."""
    async def main():
        clock = ManualClock()
        farm = SimFarm(farm_config(), clock)
        endpoints = await farm.start()
        try:
            assert endpoints["thrusters"]["driver"] == "serial" and endpoints["thrusters"]["watchdog_s"] == 2.0
            assert endpoints["tower"]["source"].startswith("http://127.0.0.1:")
            thr_cfg = ThrustersConfig(**endpoints["thrusters"], command_timeout_s=LOADED_S)
            thr = SerialThrusters("thrusters", thr_cfg, clock)
            cam = CaptureCamera("tower", CameraConfig(**endpoints["tower"]), clock)
            await thr.open()
            await cam.open()
            assert farm.thrusters.twin.watchdog_s == 2.0             # set on open, from the section
            before = (await cam.read()).image[0, 0, 0]
            assert before == pytest.approx(120, abs=2)                # x = 3.00 m
            await thr.drive(1.0, 1.0)
            clock.advance(1.0)                                        # 0.125 ramp, 0.875 full: 0.9375 s
            want = 3.0 + SPEED * 0.9375
            for _ in range(20):                        # frames rendered before the move still in the pipe
                after = float((await cam.read()).image[0, 0].mean())
                if after > before + 2:
                    break
            assert after == pytest.approx(want * 40, abs=2)           # JPEG: a grey level or two
            await thr.close()
            await cam.close()
        finally:
            await farm.stop()
    asyncio.run(main())


def test_the_whole_loop_with_the_real_physics_and_renderer():
    """Thrusters driver -> twin -> pond physics -> renderer -> MJPEG -> capture driver."""
    async def main():
        clock = ManualClock()
        cfg = farm_config()
        cfg = cfg.model_copy(update={"sim": {"pond": {"outline": OUTLINE, "start": (5.0, 5.0, 0.5)},
                                             "tower_camera": {"width": 640, "height": 360, "fps": 25}}})
        farm = SimFarm(cfg, clock)
        endpoints = await farm.start()
        try:
            thr_cfg = ThrustersConfig(**endpoints["thrusters"], command_timeout_s=LOADED_S)
            thr = SerialThrusters("thrusters", thr_cfg, clock)
            cam = CaptureCamera("tower", CameraConfig(**endpoints["tower"]), clock)
            await thr.open()
            await cam.open()
            first = (await cam.read()).image
            for _ in range(20):                                   # 10 s farm, a drive every 0.5 s
                await thr.drive(1.0, 1.0)
                clock.advance(0.5)
            await thr.stop()
            x, y, heading = farm.pond.pose()
            along = (x - 5.0) * math.cos(0.5) + (y - 5.0) * math.sin(0.5)
            assert 1.5 < along < 4.5 and abs(heading - 0.5) < 0.3    # top speed 0.4 m/s, slip and noise
            # the float (orange: red well above blue) has left where it was and is where the robot is
            def orange(image, xy):
                u, v = np.round(farm.pond.scene.view.to_pixels(np.array([xy]))[0]).astype(int)
                b, _, r = image[v - 1:v + 2, u - 1:u + 2].reshape(-1, 3).astype(int).mean(axis=0)
                return r - b > 60
            for _ in range(20):                                   # frames from before the drive may be in the pipe
                last = (await cam.read()).image
                if orange(last, (x, y)):
                    break
            assert last.shape == (360, 640, 3)
            assert orange(first, (5.0, 5.0)) and not orange(first, (x, y))
            assert orange(last, (x, y)) and not orange(last, (5.0, 5.0))
            assert farm.thrusters.twin.watchdog_trips == []
            await thr.close()
            await cam.close()
        finally:
            await farm.stop()
    asyncio.run(main())


def test_the_tower_file_for_the_cleaner_is_the_simulated_camera_s_exact_view(tmp_path, stand_in_physics):
    from devices.sim.pond import main
    toml = tmp_path / "farm.toml"
    toml.write_text('[cleaning]\noutline = [[0, 0], [20, 0], [20, 10], [0, 10]]\ndock = [2, 3]\n'
                    '[sim.tower_camera]\nwidth = 640\nheight = 360\n')
    assert main(["--config", str(toml), "--out", str(tmp_path / "TOWER.json")]) == 0
    H = np.array(json.loads((tmp_path / "TOWER.json").read_text())["H"])
    cfg = types.SimpleNamespace(cleaning={"outline": OUTLINE, "dock": (2.0, 3.0)})
    pond = build_pond(cfg, {}, ManualClock(), lambda t: (0.0, 0.0), camera={"width": 640, "height": 360})
    assert pond.pose()[:2] == (2.0, 3.0)                        # the dock, by default
    xy = np.array([[2.0, 3.0], [17.5, 8.25], [10.0, 5.0]])
    uv = pond.scene.view.to_pixels(xy)
    back = np.c_[uv, np.ones(3)] @ H.T
    assert np.allclose(back[:, :2] / back[:, 2:], xy, atol=1e-6)
    toml.write_text("[sim.pond]\nstep_s = 0.01\n")
    assert main(["--config", str(toml), "--out", str(tmp_path / "T2.json")]) == 2   # no outline anywhere
