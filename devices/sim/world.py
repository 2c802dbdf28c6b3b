"""The simulated farm: tanks of fish, the rail carriage and the dispenser on it, and the pond with
its cleaning robot (thrusters, physics, tower camera), in one process.

Each simulated device serves its own protocol; the world only links their physics: food
leaving the auger falls into the tank under the carriage (or on the floor between tanks),
and the hopper refills only while the carriage stands at the food box. The dispenser reports
what happened over an interval between its looks (at 1440x one auger run is a few ms of wall,
and nothing looks in between); the world splits it by where the carriage was, from the rail's
closed-form motion, at the instants the carriage passes a tank mouth's or the food box's edge.
"""
from __future__ import annotations

import asyncio
import contextlib
import logging
import random
import tempfile
import threading
from itertools import pairwise
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from devices.errors import BadInput
from devices.sections import validate_section
from devices.sim.dispenser import SimDispenser, SimDispenserParams
from devices.sim.rail import SimRailMotor, SimRailParams
from devices.sim.slcan_adapter import SlcanAdapter
from devices.sim.truth import TruthLog

log = logging.getLogger("fishfarm.sim")

TANK_MOUTH_M = 0.30       # the chute is over a tank when within this of the tank's position
RECV_WINDOW = "recv_buffer_size;262144"   # the simulated camera's reader: FFmpeg's TCP receive buffer
FOOD_BOX_M = 0.10         # the hopper fills only this close to the food box
CAMERA_STOP_S = 0.2       # wall s the stop waits for a camera's threads (a survey pair renders for longer)


class SimSection(BaseModel):
    """farm.toml ``[sim]``: the simulated world. Each part validates its own sub-section."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    seed: int = 0
    fish: dict[str, Any] = {}
    contacts: dict[str, Any] = {}
    rail: dict[str, Any] = {}
    dispenser: dict[str, Any] = {}
    thrusters: dict[str, Any] = {}
    tower_camera: dict[str, Any] = {}
    stereo_camera: dict[str, Any] = {}
    pond: dict[str, Any] = {}
    thermometer: dict[str, Any] = {}
    stock: dict[str, Any] = {}
    soak_days: float = Field(0.0, ge=0, description="reserved")


def check_sim(cfg: Any) -> SimSection:
    """``[sim]`` and each of its sub-sections, before anything starts (``fishfarm run`` checks them
    at load: a sub-section's fault was the simulator's exit after the controller had started it).
    A sub-section no simulated device uses is checked all the same: a typo is a typo."""
    from devices.sim.contact_hub import SimHubParams
    from devices.sim.fish import SimFishParams
    from devices.sim.pond import SimPondParams, check_robot
    from devices.sim.stereo_camera import SimStereoCameraParams
    from devices.sim.stock import SimStockParams
    from devices.sim.thermometer import WaterParams
    from devices.sim.thrusters import SimThrusterParams
    from devices.sim.tower_camera import SimTowerCameraParams
    section = validate_section(SimSection, cfg.sim, cfg.path, "sim")
    models = {"fish": SimFishParams, "stock": SimStockParams, "rail": SimRailParams, "dispenser": SimDispenserParams,
              "contacts": SimHubParams, "thrusters": SimThrusterParams, "tower_camera": SimTowerCameraParams,
              "stereo_camera": SimStereoCameraParams, "thermometer": WaterParams, "pond": SimPondParams}
    for key, model in models.items():
        params = validate_section(model, getattr(section, key), cfg.path, f"sim.{key}")
        if key == "pond":
            check_robot(params.robot, cfg.path)
        if key == "rail" and any(s.get("kind") == "rail" and s.get("driver") == "sim" for s in cfg.devices.values()):
            _check_on_rail(cfg, params)
    return section


def _check_on_rail(cfg: Any, rail: SimRailParams) -> None:
    """Every tank and the food box lie on the simulated rail, and no two tank mouths overlap (food
    under the chute would be credited to the first tank found there)."""
    stops = [(t.position_m, f"tanks.{i}.position_m", f"tank {t.id!r}") for i, t in enumerate(cfg.tanks)]
    stops.append((cfg.feeding.food_box_m, "feeding.food_box_m", "the food box"))
    for position, key, what in stops:
        if position > rail.rail_length_m:
            raise BadInput(cfg.path, key, f"{what} at {position:g} m is beyond the simulated rail's end "
                                          f"(sim.rail.rail_length_m = {rail.rail_length_m:g} m)")
    placed = sorted((t.position_m, i) for i, t in enumerate(cfg.tanks))
    for (a, i), (b, j) in pairwise(placed):
        if b - a < 2 * TANK_MOUTH_M:
            k = max(i, j)
            raise BadInput(cfg.path, f"tanks.{k}.position_m",
                           f"tank {cfg.tanks[k].id!r} is {b - a:g} m from tank {cfg.tanks[min(i, j)].id!r}: the "
                           f"simulated tanks' mouths ({TANK_MOUTH_M:g} m each side) would overlap")


async def _on_daemon_thread(fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` on a daemon thread, awaited. Not asyncio.to_thread: its executor is
    joined as the loop closes, so a stop during the drawing waited for the drawing to end."""
    loop = asyncio.get_running_loop()
    done = loop.create_future()

    def settle(ok: bool, value) -> None:
        if not done.done():
            (done.set_result if ok else done.set_exception)(value)

    def work() -> None:
        try:
            result, ok = fn(*args, **kwargs), True
        except BaseException as exc:  # noqa: BLE001 - handed to the awaiting task as it is
            result, ok = exc, False
        with contextlib.suppress(RuntimeError):       # the loop has closed: nobody waits
            loop.call_soon_threadsafe(settle, ok, result)
    threading.Thread(target=work, name=f"sim-{getattr(fn, '__name__', 'work')}", daemon=True).start()
    return await done


class SimFarm:
    """``cfg``: the farm's validated config (controller.config.Config), read for its ``tanks``,
    ``devices``, ``feeding.food_box_m``, ``sim`` and ``path``; devices/ does not import its model."""

    def __init__(self, cfg: Any, clock, truth: TruthLog | None = None):
        self.cfg, self.clock = cfg, clock
        self.truth = truth or TruthLog(None)
        self.section = validate_section(SimSection, cfg.sim, cfg.path, "sim")
        self.rng = random.Random(self.section.seed)
        simulated = [(n, s) for n, s in cfg.devices.items() if s["driver"] == "sim"]
        self.devices = {kind: [(n, s) for n, s in simulated if s["kind"] == kind]
                        for kind in ("contacts", "rail", "dispenser", "thrusters", "tower_camera", "thermometer",
                                     "stereo_camera")}
        self.motor: SimRailMotor | None = None
        self.adapter: SlcanAdapter | None = None
        self.dispenser: SimDispenser | None = None
        self.tanks = self._build_tanks()
        self.hubs: list = []
        self.thrusters = None                 # SimThrusters, the pond cleaner's
        self.pond = None                      # SimPond: the cleaner on the floor
        self.camera = None                    # SimTowerCamera
        self.thermometer = None               # SimThermometer over the water model
        self.stereo = None                    # the survey cameras' server (a SimTowerCamera of pairs)
        self.files_dir: Path | None = None    # where the stereo rig's CALIB.json goes (a temporary dir if None)
        self.tank_positions = sorted((t.position_m, t.id) for t in cfg.tanks)
        box = cfg.feeding.food_box_m
        self.edges = sorted({p + d for p, _ in self.tank_positions for d in (-TANK_MOUTH_M, TANK_MOUTH_M)}
                            | {box - FOOD_BOX_M, box + FOOD_BOX_M})
        self.spilled_g = 0.0

    # -- physics links -----------------------------------------------------------
    def carriage_m(self, t: float) -> float:
        return self.motor.position(t) if self.motor is not None else self.cfg.feeding.food_box_m

    def tank_under(self, position_m: float) -> str | None:
        for tank_pos, tank_id in self.tank_positions:
            if abs(tank_pos - position_m) <= TANK_MOUTH_M:
                return tank_id
        return None

    def path(self, t_from: float, t_to: float) -> list[tuple[float, float, float]]:
        """Pieces ``(t_a, t_b, position)`` of farm time [t_from, t_to], each within one place
        (over one tank, between tanks, at the food box or not)."""
        if self.motor is None or t_to <= t_from:
            return [(t_from, t_to, self.carriage_m(t_to))]
        return self.motor.travel(t_from, t_to, self.edges)

    def deliver(self, grams: float, t_from: float, t_to: float) -> None:
        """Food that left the auger evenly over farm time [t_from, t_to], credited to the tanks
        the chute was over (called under the dispenser's lock: no blocking). One ``delivered``
        record per tank (tank null: spilled between tanks), stamped when the chute left it."""
        span = t_to - t_from
        where: dict[str | None, list[float]] = {}         # tank -> [grams, last instant over it]
        for a, b, position in self.path(t_from, t_to):
            share = where.setdefault(self.tank_under(position), [0.0, b])
            share[0] += grams * (b - a) / span if span > 0 else grams
            share[1] = b
        for tank, (g, t) in sorted(where.items(), key=lambda item: item[1][1]):
            if tank is None:
                self.spilled_g += g
            elif tank in self.tanks:
                self.tanks[tank].feed(g, t)
            self.truth.write("delivered", t, tank=tank, grams=round(g, 4))

    def time_at_food_box(self, t_from: float, t_to: float) -> float:
        """Farm seconds of [t_from, t_to] the carriage spent at the food box (the hopper fills)."""
        box = self.cfg.feeding.food_box_m
        return sum(b - a for a, b, position in self.path(t_from, t_to) if abs(position - box) <= FOOD_BOX_M)

    # -- life cycle ----------------------------------------------------------------
    def _build_tanks(self) -> dict:
        if not self.devices["contacts"]:
            return {}
        from devices.sim.fish import SimFishParams, SimTank
        params = validate_section(SimFishParams, self.section.fish, self.cfg.path, "sim.fish")
        import numpy as np

        from devices.sim.stock import SimStock, SimStockParams
        stock = validate_section(SimStockParams, self.section.stock, self.cfg.path, "sim.stock")
        seeds = np.random.SeedSequence(self.section.seed).spawn(len(self.cfg.tanks))
        tanks = {}
        for t, s in zip(self.cfg.tanks, seeds, strict=True):
            fish_seed, stock_seed = s.spawn(2)
            tanks[t.id] = tank = SimTank(t, params, np.random.default_rng(fish_seed), self.truth,
                                         utc_offset_h=self.cfg.utc_offset_h)
            tank.stock = SimStock(t.id, t.stock, t.mean_weight_g, stock, np.random.default_rng(stock_seed),
                                  self.clock.now(), self.truth)
        return tanks

    async def start(self) -> dict[str, dict]:
        """Start every simulated device; return the real-driver config section for each."""
        endpoints: dict[str, dict] = {}
        where = self.cfg.path
        for name, section in self.devices["rail"][:1]:
            params = validate_section(SimRailParams, self.section.rail, where, "sim.rail")
            self.motor = SimRailMotor(params, self.clock, node_id=section.get("node_id", 1), truth=self.truth)
            self.adapter = SlcanAdapter()
            await self.motor.start(self.adapter)
            endpoints[name] = {"kind": "rail", "driver": "can", "interface": "slcan",
                               "channel": self.adapter.port, "node_id": section.get("node_id", 1)}
        for name, section in self.devices["dispenser"][:1]:
            params = validate_section(SimDispenserParams, self.section.dispenser, where, "sim.dispenser")
            host, unit = section.get("host", "127.0.0.1"), section.get("unit", 1)
            self.dispenser = SimDispenser(params, self.clock, host=host, port=section.get("port", 0), unit=unit,
                                          deliver=self.deliver, at_food_box=self.time_at_food_box,
                                          truth=self.truth)
            try:
                await self.dispenser.start()
            except OSError as exc:
                raise BadInput(where, f"devices.{name}.port", str(exc)) from None
            endpoints[name] = {"kind": "dispenser", "driver": "modbus", "host": host,
                               "port": self.dispenser.port, "unit": unit}
        for name, _section in self.devices["contacts"]:
            endpoints[name] = await self._start_hub()
        endpoints.update(await self._start_pond())
        endpoints.update(await self._start_thermometer())
        endpoints.update(self._start_stereo())
        return endpoints

    async def _start_thermometer(self) -> dict[str, dict]:
        from devices.sim.thermometer import SimThermometer
        endpoints: dict[str, dict] = {}
        for name, section in self.devices["thermometer"][:1]:
            host, unit, probes = section.get("host", "127.0.0.1"), section.get("unit", 1), section["probes"]
            self.thermometer = SimThermometer(self.section.thermometer, self.clock, probes, host=host,
                                              port=section.get("port", 0), unit=unit, where=self.cfg.path)
            try:
                await self.thermometer.start()
            except OSError as exc:
                raise BadInput(self.cfg.path, f"devices.{name}.port", str(exc)) from None
            endpoints[name] = {"kind": "thermometer", "driver": "modbus", "host": host,
                               "port": self.thermometer.port, "unit": unit, "probes": probes}
        return endpoints

    def _start_stereo(self) -> dict[str, dict]:
        """The survey cameras on the carriage: they see the fish of the tank under it."""
        from devices.sim.stereo_camera import SimStereoCameraParams, TankView, frame_size
        from devices.sim.tower_camera import SimTowerCamera
        endpoints: dict[str, dict] = {}
        where = self.cfg.path
        for name, section in self.devices["stereo_camera"][:1]:
            params = validate_section(SimStereoCameraParams, self.section.stereo_camera, where, "sim.stereo_camera")
            view = TankView(params, self.tanks, lambda t: self.tank_under(self.carriage_m(t)))
            if self.files_dir is None:
                self._tmp = tempfile.TemporaryDirectory(prefix="fishfarm-stereo-")
                self.files_dir = Path(self._tmp.name)
            calib = view.write_calibration(self.files_dir / f"{name}-CALIB.json")
            served = {"fps": params.fps, "jpeg_quality": params.jpeg_quality, **frame_size(params)}
            self.stereo = SimTowerCamera(view.render, self.clock, served, host=section.get("host", "127.0.0.1"),
                                         port=section.get("port", 0), where=where)
            try:
                self.stereo.start()
            except OSError as exc:
                raise BadInput(where, f"devices.{name}.port", str(exc)) from None
            endpoints[name] = {"kind": "stereo_camera", "driver": "capture", "sources": [self.stereo.url],
                               "layout": "side_by_side", "calib": calib, "api": "ffmpeg",
                               "ffmpeg_options": RECV_WINDOW}
        return endpoints

    async def _start_pond(self) -> dict[str, dict]:
        """The cleaner's thruster controller, the pond it moves on and the tower camera over it."""
        from devices.sim.thrusters import SimThrusters
        from devices.sim.tower_camera import SimTowerCamera, SimTowerCameraParams
        endpoints: dict[str, dict] = {}
        where = self.cfg.path
        for name, section in self.devices["thrusters"][:1]:
            self.thrusters = SimThrusters(self.clock, self.section.thrusters, self.truth, where=where)
            await self.thrusters.start()
            endpoints[name] = {"kind": "thrusters", "driver": "serial", "port": self.thrusters.port}
            if section.get("watchdog_s") is not None:
                endpoints[name]["watchdog_s"] = section["watchdog_s"]
        cameras = self.devices["tower_camera"][:1]
        if not (self.thrusters or cameras):
            return endpoints
        from devices.sim.pond import build_pond, pond_outline
        params = validate_section(SimTowerCameraParams, self.section.tower_camera, where, "sim.tower_camera")
        if not cameras and self.section.pond.get("outline") is None and pond_outline(self.cfg) is None:
            return endpoints                  # thrusters on a bench: no pond to push
        thrust = self.thrusters.thrust if self.thrusters is not None else (lambda t: (0.0, 0.0))
        size = {"width": params.width, "height": params.height} if cameras else None
        # the pose trace goes to a truth file only: kept in memory it would grow all night
        trace = self.truth if self.truth.records is None else None
        # on a thread: drawing the pond's still layers takes a second and more, and the loop must
        # stay free to hear a stop (a SIGTERM during start-up overran SIM_STOP_S: exit 70)
        self.pond = await _on_daemon_thread(build_pond, self.cfg, self.section.pond, self.clock, thrust,
                                            camera=size, truth=trace, where=where)
        await self.pond.start()
        for name, section in cameras:
            self.camera = SimTowerCamera(self.pond.render, self.clock, params, host=section.get("host", "127.0.0.1"),
                                         port=section.get("port", 0), where=where)
            try:
                self.camera.start()
            except OSError as exc:
                raise BadInput(where, f"devices.{name}.port", str(exc)) from None
            # a small receive window: a reader that falls behind makes the camera skip frames
            # instead of the kernel queueing old ones (loopback TCP, nothing lost)
            endpoints[name] = {"kind": "tower_camera", "driver": "capture", "source": self.camera.url,
                               "api": "ffmpeg", "ffmpeg_options": RECV_WINDOW}
        return endpoints

    async def _start_hub(self) -> dict:
        from devices.sim.contact_hub import SimContactHub
        hub = SimContactHub(list(self.tanks.values()), self.clock, self.section.contacts, self.truth)
        await hub.start()
        self.hubs.append(hub)
        return {"kind": "contacts", "driver": "serial", "port": hub.port}

    def halt(self) -> None:
        """From any thread, at once: the pond stops stepping and the cameras rendering, so nothing
        the stop waits for is busy catching up with a fast clock."""
        if self.pond is not None:
            self.pond.halt()
        for camera in (self.stereo, self.camera):
            if camera is not None:
                camera.halt()

    async def stop(self) -> None:
        """Everything stopped within about a second (a frame still rendering is not waited for:
        its thread is a daemon), the truth log's closing records written."""
        self.halt()
        if self.thermometer is not None:
            await self.thermometer.stop()
        cameras = [c for c in (self.stereo, self.camera) if c is not None]
        if cameras:
            await asyncio.gather(*(asyncio.to_thread(c.stop, CAMERA_STOP_S) for c in cameras))
        if self.stereo is not None:          # beside the pairs a survey measured: what rendering cost
            self.truth.write("stereo_camera", self.clock.now(), rendered=self.stereo.rendered)
        if self.pond is not None:
            await self.pond.stop()
        if self.thrusters is not None:
            await self.thrusters.stop()
        for hub in self.hubs:
            await hub.stop()
            self.truth.write("contact_hub", self.clock.now(), sent=hub.sent, dropped=hub.dropped)
        if self.dispenser is not None:
            self.truth.write("dispenser_total", self.clock.now(), physical_g=self.dispenser.physical_total_g)
            await self.dispenser.stop()
        if self.motor is not None:
            await self.motor.stop()
        self.truth.close()
