"""The controller process: builds every part from the config and runs them on one event loop.

Wiring only: components talk through their interfaces (devices/*, Bus, Store); nothing here
reaches into hardware. Simulated devices (``driver = "sim"``) are served by a child
``fishfarm sim`` process on the same timeline, and reached through the real drivers.
"""
from __future__ import annotations

import asyncio
import contextlib
import gc
import itertools
import logging
import time

from controller import shutdown
from controller.alarms import Alarms
from controller.bus import Bus, session_config
from controller.config import Config, validate_section
from controller.demand import DemandFilter, DemandParams
from controller.farm_setup import CLEANER_KINDS, build_device, check_farm
from controller.feeding.estop import PROVISIONAL, EstopLane, Latch, log_latch
from controller.feeding.rations import Rations, load_species, species_file
from controller.feeding.robot import FeedingRobot, Job
from controller.hearing import Hearing
from controller.hub_clock import HubClock
from controller.ledger_config import check_against_ledger
from controller.ledger_writes import LedgerUnwritable
from controller.overrides import Overrides
from controller.scada.service import Scada
from controller.shutdown import install_signal_handlers
from controller.simproc import SimProcess
from controller.status import farm_status
from controller.stopping import Stopping
from controller.store import CONTROLLER_BUSY_MS, Store
from controller.surveys.watch import SurveyWatch
from controller.surveys.wiring import build_survey_stops, survey_camera_name
from controller.water import WaterTemperatures
from devices.errors import DeviceError
from devices.sim.world import check_sim

log = logging.getLogger("fishfarm")

HOUSEKEEPING_S = 5.0        # farm seconds between filter ticks and expiry checks
STATE_EVERY_WALL_S = 1.0    # periodic state publication besides every change
OPEN_BACKOFF_S = (0.2, 0.5, 1.0, 2.0, 5.0, 10.0)
SIM_WATCH_S = 0.5           # wall seconds between checks that the simulated devices' child lives



class Controller(Hearing, Stopping):
    def __init__(self, cfg: Config, clock, *, duration_s: float | None = None):
        self.cfg, self.clock, self.duration_s = cfg, clock, duration_s
        self.sensor_tank = {s: t.id for t in cfg.tanks for s in t.sensors}
        self.sim: SimProcess | None = None
        self.tasks: list[asyncio.Task] = []
        self.stopping = asyncio.Event()
        self.unknown_sensors: set[str] = set()
        self.contacts_carried = {"malformed": 0, "lost": 0}   # counted by hub links since replaced
        self.contacts_waiting = 0.0      # contacts estimated unread after the last read (controller/pace.py)
        self.robot: FeedingRobot | None = None
        self.cleaner = None                   # the pond cleaner (controller/cleaning), with [cleaning]
        self.lane: EstopLane | None = None
        self.estop_before_start: str | None = None
        self.watchdog: shutdown.StopWatchdog | None = None
        self._starting: asyncio.Task | None = None
        self._stopped = False
        self.scada: Scada | None = None
        self.started_monotonic = time.monotonic()
        self.not_opened: set[str] = set()        # devices whose open has failed and not succeeded since
        self.species = load_species(species_file(cfg.path))
        check_farm(cfg, self.species)
        # every section is checked before anything starts: a bad key is one line and exit 2, not a
        # simulator started and stopped around it
        self.demand_params = validate_section(DemandParams, cfg.demand, cfg.path, "demand")
        session_config(cfg.bus, str(cfg.path))
        self.cleaning = None
        if cfg.cleaning is not None:
            from controller.cleaning.setup import prepare
            self.cleaning = prepare(cfg)          # geometry, dock, tower, plan: bad input now, not at start
        if any(s["driver"] == "sim" for s in cfg.devices.values()):
            check_sim(cfg)                        # [sim] and each sub-section
        survey_camera_name(cfg)                   # scheduled surveys without a camera: bad input now
        self.survey_stops = None

    # -- life cycle -------------------------------------------------------------
    async def start(self) -> None:
        """Bring the parts up. The bus and status come first, so operators can see (and e-stop) a
        controller still waiting for a device; the robot starts once every device has opened."""
        cfg = self.cfg
        # first: an unusable ledger path is bad input, exit 2
        self.store = Store(cfg.store.path, cfg.surveys.min_weighed_fish, busy_ms=CONTROLLER_BUSY_MS)
        self.store.claim()                     # ... and so is a ledger another controller runs on
        check_against_ledger(cfg, self.store, self.clock.now())   # ... and a config its events rule out
        sections = dict(cfg.devices)
        if any(s["driver"] == "sim" for s in sections.values()):
            self.sim = SimProcess(cfg, self.clock)
            sections.update(await self.sim.start())
            if self.stopping.is_set():            # a start that ignored its cancel opens nothing more
                return
            for name, section in cfg.devices.items():
                if section["driver"] == "sim":    # a simulator we just started is a new PLC: its
                    self.store.forget_counters(name)   # counters start at zero, not "backwards"
        self.bus = Bus(cfg.bus, cfg.site)
        self.alarms = Alarms(self.store, self.bus.publish, self.clock)
        if self.sim is not None:
            # a new simulator runs: the last one's death (alarms reload across restarts) is over,
            # and this one's, should it come, is raised and logged anew, not counted under the old
            self.alarms.clear("sim", "simulated devices running again", kind="exited")
            self.tasks.append(asyncio.create_task(self._watch_sim()))
        self.rations = Rations(cfg, self.species, self.store)
        self.surveys = SurveyWatch(cfg, self.store, self.rations, self.alarms, self.bus.publish)
        self.filter = DemandFilter(self.demand_params,
                                   {t.id: list(t.sensors) for t in cfg.tanks})
        self.devices = {name: build_device(name, s, self.clock, cfg.path) for name, s in sections.items()}
        self.contacts = self._one("contacts")
        self.hub_clock = HubClock(self.clock, self.alarms, self.contacts.name)
        self.rail = self._one("rail")
        self.dispenser = self._one("dispenser")
        self._loop = asyncio.get_running_loop()
        cleaner_devices = [d for d in self.devices.values() if d.kind in CLEANER_KINDS]
        thrusters = [Latch(d.name, d) for d in cleaner_devices if d.kind == "thrusters"]
        self.lane = EstopLane(self.rail, self.dispenser, *thrusters)    # live before any device is open
        self.lane.listen(self._lane_report_before_start)
        thermometer = next((d for d in self.devices.values() if d.kind == "thermometer"), None)
        self.water = WaterTemperatures(cfg, thermometer, self.clock, self.alarms, reopen=self._fresh,
                                       on_fresh=self._water_measured)
        self.rations.water = self.water
        if thermometer is not None:           # opened in its own task: a silent one holds nothing up
            self.tasks.append(asyncio.create_task(self._supervise(self._water_loop)))
        if self.cleaning is not None:
            from controller.cleaning.setup import build
            self.cleaner = build(self.cleaning, self._one("tower_camera"), self._one("thrusters"), self.store,
                                 self.clock, self.bus.publish, alarms=self.alarms, lane=self.lane,
                                 reopen=self._fresh)
            self.tasks.append(asyncio.create_task(self._supervise(self._cleaner_loop)))
        self.overrides = Overrides(self)
        self.overrides.declare(self.bus)
        if cfg.scada is not None and cfg.scada.enabled:     # SCADA sees (and can e-stop) a starting controller
            self.scada = Scada(self, cfg, alarms=self.alarms)
            self.tasks.append(asyncio.create_task(self._supervise(self._scada)))
        # the cleaner's devices open in its own task: a camera that is not up does not hold the feeder
        await asyncio.gather(*(self._open(device) for device in self.devices.values()
                               if device not in cleaner_devices and device is not thermometer))
        if self.stopping.is_set():                # stopped while waiting for a device: start nothing
            return
        self.robot = FeedingRobot(cfg, self.clock, self.rail, self.dispenser, self.store, self.rations,
                                  self.alarms, self.bus.publish, lane=self.lane, reopen=self._fresh)
        self.robot.surveys = self.survey_stops = build_survey_stops(self)
        if self.estop_before_start is not None:
            await self.robot.emergency_stop(self.estop_before_start)
        self._requeue_open_demands()
        for loop in (self.robot.run, self._contacts_loop, self._housekeeping, self._state_loop):
            self.tasks.append(asyncio.create_task(self._supervise(loop)))
        if hasattr(self.clock, "idle_until"):     # an elastic clock: say when the farm may run fast
            self.tasks.append(asyncio.create_task(self._supervise(self._pace)))
        # what start-up built lives as long as the process: out of the collector's sight, a full
        # collection (which holds the GIL, so the e-stop's threads too) takes ~1 ms, not ~70
        gc.freeze()
        log.info("controller for site %s up: %d tanks", cfg.site, len(cfg.tanks))

    async def _pace(self) -> None:
        from controller.pace import pace
        await pace(self)

    async def _scada(self) -> None:
        await self.scada.run()

    def trip_estop(self, reason: str = PROVISIONAL) -> None:
        """From any thread (the Zenoh thread that got the query): latch the devices now, before
        the loop hears of it. ``emergency_stop`` follows on the loop."""
        if self.lane is not None:
            self.lane.trip(reason)

    def _lane_report_before_start(self, device: str, why: str | None) -> None:
        """From the lane's thread, until the robot exists (then its own listener speaks): the
        ``estop`` alarm names a device whose latch is not confirmed, as the robot's does."""
        def on_loop():
            if self.robot is not None:
                return
            log_latch(device, why)
            if self.estop_before_start is not None:
                self.alarms.retext("estop", self.lane.alarm_text(self.estop_before_start), kind="latched")
        with contextlib.suppress(RuntimeError):     # the loop is closed: the process is ending
            self._loop.call_soon_threadsafe(on_loop)

    async def emergency_stop(self, reason: str) -> bool:
        """E-stop wins from any state, even before the robot exists: it then starts stopped.
        True once the devices confirmed their latches."""
        if self.cleaner is not None:
            self.cleaner.stopped(reason)          # its thrusters were latched by the lane's trip
        if self.robot is None:
            self.estop_before_start = reason
            text = self.lane.alarm_text(reason) if self.lane is not None else f"emergency stop: {reason}"
            self.alarms.raise_("estop", text, "critical", kind="latched")
            if self.lane is None:
                return False
            done, _ = await asyncio.wait({asyncio.wrap_future(self.lane.trip(reason))}, timeout=1.0)
            return bool(done)
        return await self.robot.emergency_stop(reason)

    async def run(self) -> None:
        self._starting = starting = asyncio.create_task(self.start())
        stopping = asyncio.create_task(self.stopping.wait())
        wall = None if self.duration_s is None else self.clock.wall(self.duration_s)
        try:
            # a start still retrying a device that did not open when the whole run's time has passed
            # ends too (it retried for good, --duration or not); a start only slow (a loaded
            # simulator) is waited for
            while True:
                await asyncio.wait({starting, stopping}, timeout=wall, return_when=asyncio.FIRST_COMPLETED)
                if starting.done() or self.stopping.is_set() or self.not_opened:
                    break
            if not starting.done() and not self.stopping.is_set():
                log.warning("stopping: --duration passed while the controller was still starting "
                            "(%s not opened)", ", ".join(sorted(self.not_opened)))
            elif starting.done() and not self.stopping.is_set():
                starting.result()                     # a start-up fault surfaces here
                await asyncio.wait({stopping}, timeout=wall)
        finally:
            stopping.cancel()
            await self.stop()

    async def _supervise(self, loop) -> None:
        """Run a loop until the controller stops: a bug in one part is logged and alarmed, never the
        end of the process."""
        name = loop.__name__.strip("_")
        while not self.stopping.is_set():
            try:
                await loop()
            except asyncio.CancelledError:
                raise
            except Exception as exc:
                if self.stopping.is_set():
                    return
                if isinstance(exc, LedgerUnwritable):     # the ledger alarm says it, once
                    log.debug("%s: the ledger cannot be written; restarting it", name)
                    await self._pause(1.0)
                    continue
                log.exception("%s crashed; restarting it", name)
                self.alarms.raise_(f"controller/{name}", f"internal error: {type(exc).__name__}: {exc}",
                                   "critical", kind="crashed")
                await self._pause(1.0)

    async def _pause(self, seconds: float) -> None:
        """Sleep, cut short when the controller stops."""
        waiter = asyncio.ensure_future(self.stopping.wait())
        try:
            await asyncio.wait({waiter}, timeout=seconds)
        finally:
            waiter.cancel()

    def _one(self, kind: str):
        return next(d for d in self.devices.values() if d.kind == kind)

    async def _open(self, device, failed=None) -> None:
        """Open a device, retrying with back-off until it opens or the controller stops: a farm's
        controller often starts before every PLC is up. The loss is alarmed once (on the first
        failure, when ``failed(why)`` is told too), the recovery once; the retries between are
        logged at debug level only."""
        for attempt in itertools.count():
            if self.stopping.is_set():
                return
            try:
                await device.open()
                self.not_opened.discard(device.name)
                if self.alarms.clear(f"device/{device.name}", "connected") and attempt:
                    log.info("%s opened after %d attempts", device.name, attempt + 1)
                return
            except DeviceError as exc:
                self.not_opened.add(device.name)
                if attempt == 0:
                    self.alarms.raise_(f"device/{device.name}", f"cannot open: {exc.text}", kind="unreachable")
                    if failed is not None:
                        failed(f"cannot open: {exc.text}")
                else:
                    log.debug("%s: open attempt %d failed: %s", device.name, attempt + 1, exc.text)
                await self._pause(OPEN_BACKOFF_S[min(attempt, len(OPEN_BACKOFF_S) - 1)])

    async def _watch_sim(self) -> None:
        """The simulated devices' child exiting on its own is alarmed once, and reaped at once."""
        while not self.stopping.is_set():
            code = self.sim.poll()
            if code is not None:
                self.alarms.raise_("sim", f"simulated devices exited (code {code})", "critical", kind="exited")
                return
            await self._pause(SIM_WATCH_S)

    async def _water_loop(self) -> None:
        await self._open(self.water.device)
        await self.water.run(self.stopping)

    def _water_measured(self, tanks: list[str]) -> None:
        """Today's rations of tanks read at the configured temperature are planned again at the
        measured one (an operator's ration stands)."""
        now = self.clock.now()
        for tank in tanks:
            self.rations.replan(tank, now)
            self.publish_ration(tank)

    async def _cleaner_loop(self) -> None:
        # a camera or thrusters that do not open put the cleaner in fault (it said localising)
        await asyncio.gather(*(self._open(device, failed=lambda why, d=device: self.cleaner.unavailable(d.name, why))
                               for device in map(self._one, CLEANER_KINDS)))
        if not self.stopping.is_set():
            await self.cleaner.run()

    def _new_driver(self, device):
        """A driver like ``device`` (same backend, same section), not open: a lost link is lost for
        good on the old one."""
        return type(device)(device.name, type(device.config).model_validate(dict(device.config)), self.clock)

    async def _fresh(self, device):
        """A device whose link is lost for good (LinkDown) replaced by a fresh driver on the same
        section, its e-stop latch included; DeviceError when it does not open (the caller retries)."""
        with contextlib.suppress(Exception):
            await asyncio.wait_for(device.close(), shutdown.CLOSE_DEVICE_S)
        fresh = self._new_driver(device)
        await fresh.open()
        self.devices[device.name] = fresh
        self.lane.replace_device(device, fresh)
        log.info("%s reopened", device.name)
        return fresh

    def _requeue_open_demands(self) -> None:
        for row in self.store.open_demands():
            self.robot.on_demand(Job(row["tank"], row["t"], row["id"], row["source"], row["grams"]))

    # -- loops ------------------------------------------------------------------
    async def _housekeeping(self) -> None:
        last_date = None
        while not self.stopping.is_set():
            self._watch_ledger()
            now = self.clock.now()
            heard = self.contacts.stream_t
            self.hub_clock.heard(heard)
            for event in self.filter.on_time(now if heard is None else min(now, heard)):
                self._on_filter_event(event)
            self.surveys.check(now)
            date = self.rations.date(now)
            if date != last_date:
                last_date = date
                for tank in self.cfg.tanks:
                    self.publish_ration(tank.id)
            await self.clock.asleep(HOUSEKEEPING_S)

    def _watch_ledger(self) -> None:
        """The ``ledger`` alarm (kind ``unwritable``) while the ledger cannot be written (a full
        disk): raised once, in memory and on the bus, and cleared once what it held back (the
        alarms' changes) is written again. Nothing is fed meanwhile: no intent can be written."""
        store, standing = self.store, ("ledger", "unwritable") in self.alarms.active
        if store.unwritable is not None and not standing:
            self.alarms.raise_("ledger", f"the ledger cannot be written ({store.unwritable}): nothing is fed, "
                               "no survey or override is recorded until it can", "critical", kind="unwritable")
        elif standing and self.alarms.flush() and store.unwritable is None:
            self.overrides.flush_audit()
            self.alarms.clear("ledger", "the ledger is written again", kind="unwritable")
            self.alarms.flush()

    def publish_ration(self, tank_id: str) -> None:
        self.bus.publish(f"tank/{tank_id}/ration", self.rations.payload(tank_id, self.clock.now()))

    async def _state_loop(self) -> None:
        while not self.stopping.is_set():
            self.bus.publish("feeder/state", self.robot.snapshot())
            if self.cleaner is not None:              # periodic besides each frame's: frames may stop
                self.bus.publish("cleaner/state", self.cleaner.snapshot())
            await asyncio.sleep(STATE_EVERY_WALL_S)

    # -- what status and the console show ----------------------------------------
    def status(self) -> dict:
        return farm_status(self)


__all__ = ["Controller", "build_device", "check_farm", "install_signal_handlers"]
