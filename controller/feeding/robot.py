"""The rail feeding robot: serves validated demands tank by tank, within each tank's ration.

The legal moves are the table below (``transitions``); one supervisor task performs the
action of the current state. An e-stop cancels that action, stops auger and drive at once,
and wins from any state. Every dispense goes through the ledger (``controller.store``):
intent committed before the auger starts, closed from the dispenser's own counters after,
so neither a crash nor an e-stop can lose or repeat one.
"""
from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass

from transitions import Machine

from controller.feeding.planner import Stop, next_stop
from controller.store import reconcile
from devices.errors import DeviceError, DeviceFault, DeviceTimeout

log = logging.getLogger("fishfarm.feeder")

STATES = ["idle", "homing", "moving", "dispensing", "refilling", "fault", "estop", "manual"]
ACTIVE = ["idle", "homing", "moving", "dispensing", "refilling"]
TRANSITIONS = [
    # trigger            source                      dest
    ["homed",            "homing",                   "idle"],
    ["go",               "idle",                     "moving"],
    ["arrive_tank",      "moving",                   "dispensing"],
    ["arrive_box",       "moving",                   "refilling"],
    ["dispensed",        "dispensing",               "idle"],
    ["refilled",         "refilling",                "idle"],
    ["fail",             ACTIVE,                     "fault"],
    ["recover",          "fault",                    "homing"],
    ["estop",            "*",                        "estop"],
    ["reset",            "estop",                    "homing"],
    ["take_manual",      ["idle", "fault"],          "manual"],
    ["release_manual",   "manual",                   "homing"],
]
OVERSHOOT = 0.15        # auger runs deliver within ±15 % of aim: portions leave that much room
POLL_WALL_S = 0.0005    # dispenser polling once a run should have ended


@dataclass
class Job:
    tank: str
    t: float                     # when the demand was raised (farm s)
    demand_id: int | None
    source: str = "demand"       # demand | operator
    grams: float | None = None   # operator's asked portion


class FeedingRobot:
    def __init__(self, cfg, clock, rail, dispenser, store, rations, alarms, publish):
        self.cfg, self.feeding = cfg, cfg.feeding
        self.clock, self.rail, self.dispenser = clock, rail, dispenser
        self.store, self.rations, self.alarms, self.publish = store, rations, alarms, publish
        self.pending: dict[str, Job] = {}
        self.rate_g_s = self.feeding.auger_rate_g_s
        self.hopper_g: float | None = None
        self.failures = 0
        self._wake = asyncio.Event()
        self._action: asyncio.Task | None = None
        Machine(model=self, states=STATES, transitions=TRANSITIONS, initial="homing",
                auto_transitions=False, after_state_change="_state_changed")

    # -- what the rest of the controller calls ---------------------------------
    def on_demand(self, job: Job) -> None:
        if job.tank in self.pending:         # fish still waiting: the older raise sets the deadline
            if job.demand_id is not None:
                self.store.close_demand(job.demand_id, "merged")
            return
        self.pending[job.tank] = job
        self._wake.set()

    async def emergency_stop(self, reason: str) -> None:
        """Stop auger and drive now, from any state; safe to call twice."""
        first = self.state != "estop"
        self.estop()
        if self._action is not None and not self._action.done():
            self._action.cancel()
        results = await asyncio.gather(self._guarded(self.dispenser.stop()), self._guarded(self.rail.estop()))
        for name, err in zip(("dispenser", "rail"), results, strict=True):
            if err is not None:
                log.error("e-stop: %s did not confirm: %s", name, err)
        if first:
            self.alarms.raise_("estop", f"emergency stop: {reason}", "critical")

    def operator_reset(self) -> str | None:
        """Release an e-stop or cut a fault's back-off short. Returns an error text or None."""
        if self.state == "estop":
            self.reset()
            self.alarms.clear("estop", "e-stop released")
        elif self.state == "fault":
            self.failures = 0
        else:
            return f"nothing to reset in state {self.state}"
        self._wake.set()
        return None

    def set_manual(self, on: bool) -> str | None:
        if on and self.state in ("idle", "fault"):
            self.take_manual()
        elif not on and self.state == "manual":
            self.release_manual()
        elif on != (self.state == "manual"):
            return f"cannot {'take' if on else 'release'} manual control in state {self.state}"
        self._wake.set()
        return None

    def snapshot(self) -> dict:
        try:
            status = self.rail.status()
        except DeviceError:
            status = None
        return {"t": self.clock.iso(), "state": self.state,
                "position_m": None if status is None else round(status.position_m, 3),
                "hopper_g": None if self.hopper_g is None else round(self.hopper_g, 1)}

    # -- the supervisor ---------------------------------------------------------
    async def run(self) -> None:
        while True:
            self._action = asyncio.create_task(self._step())
            await asyncio.wait({self._action})
            if self._action.cancelled():
                continue                      # an e-stop took over; the state says what next
            exc = self._action.exception()
            if exc is not None:
                self._fault(exc)

    async def _step(self) -> None:
        if self.state == "homing":
            await self._home()
        elif self.state == "idle":
            await self._idle()
        elif self.state == "fault":
            await self._recover()
        else:                                  # estop, manual: wait for the operator
            await self._sleep_or_wake(3600.0)

    def _fault(self, exc: BaseException) -> None:
        if self.state in ("estop", "manual"):
            return
        if not isinstance(exc, DeviceError):
            log.error("feeder: unexpected error", exc_info=exc)
        if self.state != "fault":
            self.fail()
        self.failures += 1
        self.alarms.raise_("feeder", f"fault: {exc}", "warning")

    async def _recover(self) -> None:
        backoff = self.feeding.retry_backoff_s
        delay = backoff[min(max(self.failures, 1) - 1, len(backoff) - 1)] if self.failures else 0.0
        await self._sleep_or_wake(delay)
        if self.state != "fault":
            return
        state = await self.dispenser.read()
        if state.jammed:
            await self.dispenser.clear_fault()
        await self._clear_rail()
        self.recover()

    async def _clear_rail(self):
        """Clear a latched drive fault or e-stop once the carriage has come to rest."""
        status = await self._rail_status()
        if status.state in ("fault", "estop"):
            await self.rail.wait_until(lambda s: s.velocity_m_s == 0, 30.0, stop_on_fault=False)
            await self.rail.clear_fault()
            status = await self.rail.wait_until(lambda s: s.state not in ("fault", "estop"), 30.0,
                                                stop_on_fault=False)
        return status

    async def _home(self) -> None:
        self.hopper_g = None                     # hands may have been on the hopper: look again
        status = await self._clear_rail()
        if not status.homed or status.state == "homing":
            if status.state != "homing":
                await self.rail.home()
            await self.rail.wait_until(lambda s: s.homed and s.state == "idle", self.feeding.move_timeout_s)
        await self.settle_open_intents()
        self.homed()
        self.alarms.clear("feeder", "feeder back in service")

    async def _idle(self) -> None:
        self._wake.clear()
        self._expire()
        job = await self._next_job()
        if self.hopper_g is None:      # afterwards every run and refill leaves its reading here
            self.hopper_g = (await self.dispenser.read()).hopper_g
        if job is not None:
            portion = self._portion(job)
            if portion <= 0:
                self._finish(job, "ration_reached")
            elif self.hopper_g < portion * (1 + OVERSHOOT):
                await self._refill()
            else:
                await self._serve(job)
                self.failures = 0
        elif self.hopper_g < self.feeding.refill_below_g:
            await self._refill()
        else:
            await self._sleep_or_wake(30.0)

    # -- jobs -----------------------------------------------------------------
    async def _next_job(self) -> Job | None:
        if len(self.pending) <= 1:
            return next(iter(self.pending.values()), None)
        now, f = self.clock.now(), self.feeding
        stops = {job.tank: Stop(job.tank, self.cfg.tank(job.tank).position_m, job.t,
                                f.portion_g / self.rate_g_s) for job in self.pending.values()}
        here = (await self._rail_status()).position_m
        best = next_stop(list(stops.values()), here, now, deadline_s=f.serve_within_s - f.plan_margin_s,
                         speed_m_s=f.rail_speed_m_s, accel_m_s2=f.rail_accel_m_s2)
        return self.pending[best.tank]

    async def _serve(self, job: Job) -> None:
        self.go()
        await self._move_to(self.cfg.tank(job.tank).position_m)
        self.arrive_tank()
        portion = self._portion(job)          # the day may have turned while travelling
        if portion > 0:
            await self._dispense(job, portion)
        else:
            self._finish(job, "ration_reached")
        self.dispensed()

    async def _dispense(self, job: Job, portion: float) -> None:
        state = await self.dispenser.read()
        self.hopper_g = state.hopper_g
        if state.jammed or state.running:
            raise DeviceFault(self.dispenser.name, "jammed" if state.jammed else "auger already running")
        now = self.clock.now()
        run_s = portion / self.rate_g_s
        feed = self.store.add_intent(tank=job.tank, date=self.rations.date(now), t=now, target_g=portion,
                                     run_s=run_s, cycles_before=state.cycles, source=job.source,
                                     demand_id=job.demand_id)
        self._publish_feed(feed)
        log.info("auger on for %s: %.1f g, %.1f s after the demand", job.tank, portion, now - job.t)
        await self.dispenser.run_auger(run_s, feed.tag)
        await self.clock.asleep(run_s)          # the device times the run; look when it should be over
        state = await self._wait_run_end(feed, self.feeding.dispense_timeout_s)
        if self._close(feed, state, job) == "done":
            if not state.jammed and run_s > 1.0 and state.last_grams > 0:
                self.rate_g_s = 0.7 * self.rate_g_s + 0.3 * state.last_grams / run_s
        if state.jammed:
            raise DeviceFault(self.dispenser.name, "auger jammed")

    async def _refill(self) -> None:
        self.go()
        await self._move_to(self.feeding.food_box_m)
        self.arrive_box()
        full = self.feeding.hopper_capacity_g * 0.98
        await self.dispenser.set_refill(True)
        try:
            deadline = self.clock.now() + self.feeding.refill_timeout_s
            while (state := await self.dispenser.read()).hopper_g < full:
                self.hopper_g = state.hopper_g
                if self.pending and state.hopper_g >= self.feeding.refill_below_g:
                    break                      # enough for the fish waiting now; top up later
                if self.clock.now() > deadline:
                    raise DeviceTimeout(self.dispenser.name,
                                        f"hopper not full after refill: {state.hopper_g:.0f} g")
                await asyncio.sleep(max(POLL_WALL_S, self.clock.wall(0.5)))
            self.hopper_g = state.hopper_g
        finally:
            await self.dispenser.set_refill(False)
        self.refilled()

    async def _move_to(self, position_m: float) -> None:
        tol = self.feeding.position_tolerance_m
        status = await self._rail_status()
        if status.state == "idle" and abs(status.position_m - position_m) <= tol:
            return
        await self.rail.move_to(position_m)
        await self.rail.wait_until(lambda s: s.state == "idle" and abs(s.position_m - position_m) <= tol,
                                   self.feeding.move_timeout_s)

    # -- the ledger -----------------------------------------------------------
    async def settle_open_intents(self) -> None:
        """Close every open intent from the dispenser's counters (after a restart, fault or e-stop)."""
        for feed in self.store.open_intents():
            state = await self._wait_run_end(feed, self.feeding.dispense_timeout_s)
            job = self.pending.get(feed.tank)
            self._close(feed, state, job if job is not None and job.demand_id == feed.demand_id else None)

    async def _wait_run_end(self, feed, timeout_s: float):
        deadline = self.clock.now() + timeout_s
        while True:
            state = await self.dispenser.read()
            self.hopper_g = state.hopper_g
            if reconcile(feed, state).phase != "wait":
                return state
            if self.clock.now() > deadline:
                raise DeviceTimeout(self.dispenser.name, f"auger run {feed.tag} did not end")
            await asyncio.sleep(POLL_WALL_S)

    def _close(self, feed, state, job: Job | None = None) -> str:
        """Close ``feed`` from the dispenser's counters; a done feed also serves ``job``."""
        result = reconcile(feed, state)
        phase = "done" if result.phase == "done" else "aborted"
        if result.phase == "unknown":
            self.alarms.raise_("ledger", f"feed {feed.id} to {feed.tank}: outcome unknown: {result.note}",
                               "critical")
        served = job.demand_id if job is not None and phase == "done" else None
        closed = self.store.close_feed(feed.id, phase, result.grams, self.clock.now(), result.note, served)
        if job is not None and phase == "done" and self.pending.get(job.tank) is job:
            del self.pending[job.tank]
        self._publish_feed(closed)
        return phase

    def _publish_feed(self, feed) -> None:
        grams = feed.grams if feed.phase == "done" else feed.target_g
        self.publish(f"tank/{feed.tank}/feed", {"t": self.clock.iso(feed.t_closed or feed.t_intent),
                                                "grams": round(grams or 0.0, 1), "phase": feed.phase,
                                                "id": feed.id}, reliable=True)

    # -- helpers --------------------------------------------------------------
    def _portion(self, job: Job) -> float:
        portion = self.rations.portion(job.tank, self.clock.now(), OVERSHOOT)
        return min(portion, job.grams) if job.grams is not None else portion

    def _finish(self, job: Job, outcome: str, feed_id: str | None = None) -> None:
        if self.pending.get(job.tank) is job:
            del self.pending[job.tank]
        if job.demand_id is not None:
            self.store.close_demand(job.demand_id, outcome, feed_id)

    def _expire(self) -> None:
        horizon = self.clock.now() - self.feeding.demand_expiry_s
        for job in [j for j in self.pending.values() if j.t < horizon]:
            log.warning("demand of %s at %s expired unserved", job.tank, self.clock.iso(job.t))
            self._finish(job, "expired")

    async def _rail_status(self):
        status = self.rail.status()
        if status is None:
            status = await self.rail.wait_until(lambda s: True, self.feeding.move_timeout_s)
        return status

    async def _sleep_or_wake(self, farm_s: float) -> None:
        try:
            await asyncio.wait_for(self._wake.wait(), timeout=self.clock.wall(farm_s))
        except TimeoutError:
            pass
        self._wake.clear()

    @staticmethod
    async def _guarded(coro):
        try:
            await asyncio.wait_for(coro, timeout=1.0)
        except Exception as exc:  # each stop is isolated: one failing must not skip the other
            return exc
        return None

    def _state_changed(self) -> None:
        log.info("feeder: %s", self.state)
        self.publish("feeder/state", self.snapshot(), reliable=True)
