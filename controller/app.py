"""The controller process: builds every part from the config and runs them on one event loop.

Wiring only: components talk through their interfaces (devices/*, Bus, Store); nothing here
reaches into hardware. Simulated devices (``driver = "sim"``) are served by a child
``fishfarm sim`` process on the same timeline, and reached through the real drivers.
"""
from __future__ import annotations

import asyncio
import contextlib
import gc
import importlib
import itertools
import logging
import signal

from controller.alarms import Alarms
from controller.bus import Bus
from controller.config import Config, validate_section
from controller.demand import Demand, DemandFilter, DemandParams, SensorFault, SensorRecovered
from controller.errors import BadInput
from controller.feeding.estop import EstopLane
from controller.feeding.rations import Rations, load_species, ration_payload
from controller.feeding.robot import FeedingRobot, Job
from controller.overrides import Overrides
from controller.simproc import SimProcess
from controller.store import Store
from devices.errors import DeviceError

log = logging.getLogger("fishfarm")

HOUSEKEEPING_S = 5.0        # farm seconds between filter ticks and expiry checks
STATE_EVERY_WALL_S = 1.0    # periodic state publication besides every change
OPEN_BACKOFF_S = (0.2, 0.5, 1.0, 2.0, 5.0, 10.0)


def build_device(name: str, section: dict, clock, where: str):
    kind = section["kind"]
    backends = importlib.import_module(f"devices.{kind}").BACKENDS
    module, attr = backends[section["driver"]].split(":")
    cls = getattr(importlib.import_module(module), attr)
    return cls(name, validate_section(cls.Config, section, where, f"devices.{name}"), clock)


def check_farm(cfg: Config, species: dict) -> None:
    """What the sections cannot check alone: every tank's species is known, one device of each kind."""
    for i, tank in enumerate(cfg.tanks):
        if tank.species not in species:
            raise BadInput(cfg.path, f"tanks.{i}.species",
                           f"unknown species {tank.species!r} (known: {', '.join(sorted(species))})")
    for kind in ("contacts", "rail", "dispenser"):
        found = [name for name, s in cfg.devices.items() if s["kind"] == kind]
        if len(found) != 1:
            raise BadInput(cfg.path, "devices", f"the feeding robot needs exactly one {kind} device, "
                                                f"found {len(found)}")


class Controller:
    def __init__(self, cfg: Config, clock, *, duration_s: float | None = None):
        self.cfg, self.clock, self.duration_s = cfg, clock, duration_s
        self.sensor_tank = {s: t.id for t in cfg.tanks for s in t.sensors}
        self.sim: SimProcess | None = None
        self.tasks: list[asyncio.Task] = []
        self.stopping = asyncio.Event()
        self.unknown_sensors: set[str] = set()
        self.robot: FeedingRobot | None = None
        self.lane: EstopLane | None = None
        self.estop_before_start: str | None = None
        self.species = load_species()
        check_farm(cfg, self.species)

    # -- life cycle -------------------------------------------------------------
    async def start(self) -> None:
        """Bring the parts up. The bus and status come first, so operators can see (and e-stop) a
        controller still waiting for a device; the robot starts once every device has opened."""
        cfg = self.cfg
        sections = dict(cfg.devices)
        if any(s["driver"] == "sim" for s in sections.values()):
            self.sim = SimProcess(cfg, self.clock)
            sections.update(await self.sim.start())
        self.bus = Bus(cfg.bus, cfg.site)
        self.store = Store(cfg.store.path)
        self.alarms = Alarms(self.store, self.bus.publish, self.clock)
        self.rations = Rations(cfg, self.species, self.store)
        self.filter = DemandFilter(validate_section(DemandParams, cfg.demand, cfg.path, "demand"),
                                   {t.id: list(t.sensors) for t in cfg.tanks})
        self.devices = {name: build_device(name, s, self.clock, cfg.path) for name, s in sections.items()}
        self.contacts = self._one("contacts")
        self.rail = self._one("rail")
        self.dispenser = self._one("dispenser")
        self.lane = EstopLane(self.rail, self.dispenser)    # live before any device is open
        self.overrides = Overrides(self)
        self.overrides.declare(self.bus)
        await asyncio.gather(*(self._open(device) for device in self.devices.values()))
        self.robot = FeedingRobot(cfg, self.clock, self.rail, self.dispenser, self.store, self.rations,
                                  self.alarms, self.bus.publish, lane=self.lane)
        if self.estop_before_start is not None:
            await self.robot.emergency_stop(self.estop_before_start)
        self._requeue_open_demands()
        for loop in (self.robot.run, self._contacts_loop, self._housekeeping, self._state_loop):
            self.tasks.append(asyncio.create_task(self._supervise(loop)))
        # what start-up built lives as long as the process: out of the collector's sight, a full
        # collection (which holds the GIL, so the e-stop's threads too) takes ~1 ms, not ~70
        gc.freeze()
        log.info("controller for site %s up: %d tanks", cfg.site, len(cfg.tanks))

    def trip_estop(self, reason: str = "operator e-stop") -> None:
        """From any thread (the Zenoh thread that got the query): latch the devices now, before
        the loop hears of it. ``emergency_stop`` follows on the loop."""
        if self.lane is not None:
            self.lane.trip(reason)

    async def emergency_stop(self, reason: str) -> bool:
        """E-stop wins from any state, even before the robot exists: it then starts stopped.
        True once the devices confirmed their latches."""
        if self.robot is None:
            self.estop_before_start = reason
            self.alarms.raise_("estop", f"emergency stop: {reason}", "critical")
            if self.lane is None:
                return False
            done, _ = await asyncio.wait({asyncio.wrap_future(self.lane.trip(reason))}, timeout=1.0)
            return bool(done)
        return await self.robot.emergency_stop(reason)

    async def stop(self) -> None:
        for task in self.tasks:
            task.cancel()
        await asyncio.gather(*self.tasks, return_exceptions=True)
        if self.lane is not None:
            self.lane.close()
        for device in getattr(self, "devices", {}).values():
            with contextlib.suppress(Exception):
                await device.close()
        if hasattr(self, "bus"):
            self.bus.close()
        if hasattr(self, "store"):
            self.store.close()
        if self.sim is not None:
            await self.sim.stop()

    async def run(self) -> None:
        starting = asyncio.create_task(self.start())
        stopping = asyncio.create_task(self.stopping.wait())
        try:
            await asyncio.wait({starting, stopping}, return_when=asyncio.FIRST_COMPLETED)
            if starting.done():
                starting.result()                     # a start-up fault surfaces here
                wall = None if self.duration_s is None else self.clock.wall(self.duration_s)
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stopping, wall)
        finally:
            for task in (starting, stopping):
                task.cancel()
            await asyncio.gather(starting, stopping, return_exceptions=True)
            await self.stop()

    async def _supervise(self, loop) -> None:
        """Run a loop forever: a bug in one part is logged and alarmed, never the end of the process."""
        name = loop.__name__.strip("_")
        while True:
            try:
                await loop()
            except asyncio.CancelledError:
                raise
            except Exception as exc:
                log.exception("%s crashed; restarting it", name)
                self.alarms.raise_(f"controller/{name}", f"internal error: {type(exc).__name__}: {exc}",
                                   "critical")
                await asyncio.sleep(1.0)

    def _one(self, kind: str):
        return next(d for d in self.devices.values() if d.kind == kind)

    async def _open(self, device) -> None:
        """Open a device, retrying with back-off for as long as it takes: a farm's controller
        often starts before every PLC is up. Lost and found are each alarmed once."""
        for attempt in itertools.count():
            try:
                await device.open()
                self.alarms.clear(f"device/{device.name}", "connected")
                return
            except DeviceError as exc:
                self.alarms.raise_(f"device/{device.name}", f"cannot open: {exc.text}")
                await asyncio.sleep(OPEN_BACKOFF_S[min(attempt, len(OPEN_BACKOFF_S) - 1)])

    def _requeue_open_demands(self) -> None:
        for row in self.store.open_demands():
            self.robot.on_demand(Job(row["tank"], row["t"], row["id"]))

    # -- loops ------------------------------------------------------------------
    async def _contacts_loop(self) -> None:
        publish = self.bus.publish if self.cfg.bus.publish_contacts else None
        while True:
            try:
                batch = await self.contacts.read()
                self.alarms.clear(f"device/{self.contacts.name}", "contacts back")
            except DeviceError as exc:
                self.alarms.raise_(f"device/{self.contacts.name}", exc.text)
                await self._reopen(self.contacts)
                continue
            for contact in batch:
                tank = self.sensor_tank.get(contact.sensor)
                if tank is None:
                    if contact.sensor not in self.unknown_sensors:
                        self.unknown_sensors.add(contact.sensor)
                        log.warning("contact from unknown sensor %r ignored", contact.sensor)
                    continue
                if publish is not None:
                    publish(f"tank/{tank}/contact", {"t": self.clock.iso(contact.t), "sensor": contact.sensor})
                for event in self.filter.on_contact(contact.t, tank, contact.sensor):
                    self._on_filter_event(event)

    async def _reopen(self, device) -> None:
        with contextlib.suppress(Exception):
            await device.close()
        name, section = device.name, dict(device.config)
        fresh = type(device)(name, type(device.config).model_validate(section), self.clock)
        while True:
            await asyncio.sleep(0.5)
            try:
                await fresh.open()
                break
            except DeviceError:
                continue
        self.devices[name] = fresh
        self.contacts = fresh

    def _on_filter_event(self, event) -> None:
        if isinstance(event, Demand):
            log.info("demand from %s at %.1f contacts/s, heard %.1f s after", event.tank, event.rate_hz,
                     self.clock.now() - event.t)
            demand_id = self.store.add_demand(event.tank, event.t, event.rate_hz)
            self.bus.publish(f"tank/{event.tank}/demand",
                             {"t": self.clock.iso(event.t), "rate_hz": round(event.rate_hz, 3)}, reliable=True)
            self.robot.on_demand(Job(event.tank, event.t, demand_id))
        elif isinstance(event, SensorFault):
            self.alarms.raise_(f"sensor/{event.sensor}", f"tank {event.tank}: sensor {event.sensor} {event.kind}")
        elif isinstance(event, SensorRecovered):
            self.alarms.clear(f"sensor/{event.sensor}", f"tank {event.tank}: sensor {event.sensor} recovered")

    async def _housekeeping(self) -> None:
        last_date = None
        while True:
            now = self.clock.now()
            heard = self.contacts.stream_t
            for event in self.filter.on_time(now if heard is None else min(now, heard)):
                self._on_filter_event(event)
            date = self.rations.date(now)
            if date != last_date:
                last_date = date
                for tank in self.cfg.tanks:
                    self.publish_ration(tank.id)
            await self.clock.asleep(HOUSEKEEPING_S)

    def publish_ration(self, tank_id: str) -> None:
        self.bus.publish(f"tank/{tank_id}/ration", ration_payload(self.rations.today(tank_id, self.clock.now())))

    async def _state_loop(self) -> None:
        while True:
            self.bus.publish("feeder/state", self.robot.snapshot())
            await asyncio.sleep(STATE_EVERY_WALL_S)

    # -- what status and the console show ----------------------------------------
    def status(self) -> dict:
        now = self.clock.now()
        tanks = {}
        pending = self.robot.pending if self.robot is not None else {}
        for tank in self.cfg.tanks:
            r = self.rations.today(tank.id, now)
            job = pending.get(tank.id)
            tanks[tank.id] = {"demand": job is not None,
                              "demand_t": None if job is None else self.clock.iso(job.t),
                              "fed_g": round(r.fed_g, 1), "ration_g": round(r.grams, 1),
                              "pellet_mm": r.pellet_mm}
        feeder = self.robot.snapshot() if self.robot is not None else {
            "t": self.clock.iso(now), "state": "starting", "position_m": None, "hopper_g": None}
        return {"t": self.clock.iso(now), "site": self.cfg.site, "feeder": feeder,
                "tanks": tanks,
                "alarms": [{"source": a.source, "severity": a.severity, "text": a.text,
                            "t": self.clock.iso(a.t)} for a in self.alarms.active.values()]}


def install_signal_handlers(controller: Controller) -> None:
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, controller.stopping.set)
