"""The rail feeding robot: serves validated demands tank by tank, within each tank's ration.

The legal moves are the table below (``transitions``); one supervisor task performs the
action of the current state. An e-stop wins from any state — across restarts too: a
controller that starts while the e-stop alarm stands, or finds the drive or the dispenser
e-stopped (their own buttons), starts in ``estop``, and only an operator's reset releases it.
Dispensing goes through the ledger (``dispensing.Dispensing``).

The e-stop is the devices' own latches, set by the e-stop lane (``estop.EstopLane``) on a thread
of its own, and a stop token the lane sets before anything else: every actuator command here
(HOME, MOVE, gate open, START) checks the token first and is not sent while it is set; a START
that slips past the check is refused by the latched device. Cancelling the running action is a
courtesy that saves a wasted wait, never what stops the robot.
"""
from __future__ import annotations

import asyncio
import contextlib
import logging
from dataclasses import dataclass

from transitions import Machine

from controller.feeding.dispensing import Dispensing
from controller.feeding.estop import EstopLane, Halted, log_latch
from controller.feeding.planner import Stop, next_stop
from controller.feeding.recovery import Recovering
from controller.feeding.trips import Trips
from devices.errors import DeviceError

log = logging.getLogger("fishfarm.feeder")

STATES = ["idle", "homing", "moving", "dispensing", "refilling", "surveying", "fault", "estop", "manual"]
ACTIVE = ["idle", "homing", "moving", "dispensing", "refilling", "surveying"]
TRANSITIONS = [
    # trigger            source                      dest
    ["homed",            "homing",                   "idle"],
    ["go",               "idle",                     "moving"],
    ["arrive_tank",      "moving",                   "dispensing"],
    ["arrive_box",       "moving",                   "refilling"],
    ["dispensed",        "dispensing",               "idle"],
    ["refilled",         "refilling",                "idle"],
    ["arrive_survey",    "moving",                   "surveying"],
    ["surveyed",         "surveying",                "idle"],
    ["fail",             ACTIVE,                     "fault"],
    ["recover",          "fault",                    "homing"],
    ["estop",            "*",                        "estop"],
    ["reset",            "estop",                    "homing"],
    ["take_manual",      ["idle", "fault"],          "manual"],
    ["release_manual",   "manual",                   "homing"],
]


@dataclass
class Job:
    tank: str
    t: float                     # when the demand was raised (farm s)
    demand_id: int | None
    source: str = "demand"       # demand | operator
    grams: float | None = None   # operator's asked portion
    intent: str | None = None    # the feed row written for it: once settled, the job is done whatever failed


CONFIRM_WAIT_S = 1.0    # wall seconds an e-stop's caller waits for both latches to confirm


class FeedingRobot(Recovering, Trips):
    def __init__(self, cfg, clock, rail, dispenser, store, rations, alarms, publish, lane: EstopLane | None = None,
                 reopen=None):
        self.reopen = reopen                  # async (device) -> a fresh driver: a lost CAN link is lost for good
        self.cfg, self.feeding = cfg, cfg.feeding
        self.clock, self.rail, self.dispenser = clock, rail, dispenser
        self.store, self.rations, self.alarms, self.publish = store, rations, alarms, publish
        self.lane = lane if lane is not None else EstopLane(rail, dispenser)
        self._loop = asyncio.get_running_loop()
        self.lane.listen(self._lane_report)
        self.dispensing = Dispensing(cfg, clock, dispenser, store, rations, alarms, publish)
        self.dispensing.halted = lambda: self.lane.tripped
        self.dispensing.withdrawn = lambda tank: tank in self.paused
        self.pending: dict[str, Job] = {}
        self.paused: set[str] = set(store.paused_tanks())   # tanks whose demands are not served
        self.failures = 0
        self._wake = asyncio.Event()          # a demand came, or an operator acted
        self._operator = asyncio.Event()      # an operator acted: only this cuts a back-off short
        self._estop_released = False
        self.manual_asked = False             # an operator asked for manual while the robot was busy
        self._action: asyncio.Task | None = None
        self.surveys = None                   # controller/surveys/wiring.py's SurveyStops, when a camera is set up
        initial = "estop" if "estop" in alarms.active else "homing"
        Machine(model=self, states=STATES, transitions=TRANSITIONS, initial=initial,
                auto_transitions=False, after_state_change="_state_changed")
        if initial == "estop":                # the latches may be gone (a power cut): set them again
            self.lane.trip(alarms.active["estop"].text)

    @property
    def hopper_g(self) -> float | None:
        return self.dispensing.hopper_g

    # -- what the rest of the controller calls ---------------------------------
    def on_demand(self, job: Job) -> None:
        if self.state == "estop" and self._withdrawable(job):   # a restart under a standing e-stop
            self._withdraw(job)
            return
        if job.tank in self.paused:          # an operator paused the tank: its demands are not served
            if job.demand_id is not None:
                self.store.close_demand(job.demand_id, "paused")
            return
        if job.tank in self.pending:         # fish still waiting: the older raise sets the deadline
            if job.demand_id is not None:
                self.store.close_demand(job.demand_id, "merged")
            return
        self.pending[job.tank] = job
        self._wake.set()

    def pause(self, tank: str) -> None:
        """Serve the tank no more (its waiting demand is closed ``paused``); a portion already on its
        way finishes."""
        self.paused.add(tank)
        job = self.pending.get(tank)
        if job is not None:
            self._finish(job, "paused")

    def resume(self, tank: str) -> None:
        self.paused.discard(tank)

    async def emergency_stop(self, reason: str) -> bool:
        """Latch auger, refill gate and drive stopped now, from any state; safe to call twice.
        True once both devices have confirmed their latches (waits ``CONFIRM_WAIT_S`` at most;
        the lane keeps retrying after that, and the ``estop`` alarm says which did not)."""
        confirmed = self.lane.trip(reason)   # token and latches first; the rest is bookkeeping
        self._stopped(reason)
        # the loop may have heard of the trip first, under the provisional reason (an override's
        # e-stop trips on the Zenoh thread before its payload is read): the alarm names the operator
        text = self.lane.alarm_text(self.lane.reason or reason)
        self.alarms.retext("estop", text, kind="latched")        # the provisional reason refined
        done, _ = await asyncio.wait({asyncio.wrap_future(confirmed)}, timeout=CONFIRM_WAIT_S)
        return bool(done)

    def _stopped(self, reason: str) -> None:
        """The robot's side of an e-stop already tripped: state, courtesy cancel, alarm."""
        self._cancel_action()
        self.manual_asked = False             # a reset starts afresh: no hands-on asked before the stop
        if self.state != "estop":
            self.estop()
            # the lane's reason: whoever tripped it first (a later e-stop does not rename it)
            self.alarms.raise_("estop", self.lane.alarm_text(self.lane.reason or reason), "critical",
                               kind="latched")
        for job in [j for j in self.pending.values() if self._withdrawable(j)]:
            self._withdraw(job)

    def _withdrawable(self, job: Job) -> bool:
        """An operator's feed not started: an e-stop withdraws it. Whoever stopped the farm may have
        hands in a tank; an ask of before the stop is asked again after the reset, not served by it.
        The fish's demands stay: a reset serves fish still waiting (their filter asks again anyway)."""
        if job.source != "operator" or job.intent is not None:
            return False
        return job.demand_id is None or not any(f.demand_id == job.demand_id for f in self.store.open_intents())

    def _withdraw(self, job: Job) -> None:
        log.warning("operator feed for %s withdrawn by the e-stop: ask again after the reset", job.tank)
        self._finish(job, "estop")

    def _lane_report(self, device: str, why: str | None) -> None:
        """From the lane's thread: a latch unconfirmed past the bound, or confirmed after all."""
        def on_loop():
            log_latch(device, why)
            if self.lane.tripped:
                self.alarms.retext("estop", self.lane.alarm_text(self.lane.reason or "e-stop"), kind="latched")
        with contextlib.suppress(RuntimeError):     # the loop is closed: the process is ending
            self._loop.call_soon_threadsafe(on_loop)

    def operator_reset(self) -> str | None:
        """Release an e-stop or cut a fault's back-off short. Returns an error text or None."""
        if self.state == "estop":
            self.lane.release()               # no ESTOP in flight once this returns
            self._estop_released = True
            self.reset()
            self.alarms.clear("estop", "e-stop released")
        elif self.state == "fault":
            self.failures = 0
        else:
            return f"nothing to reset in state {self.state}"
        self._poke()
        return None

    def set_manual(self, on: bool) -> str | None:
        """Hands on (``on``) or off; an error, or None. Asked while the robot is busy (homing, moving,
        dispensing, refilling, surveying), manual comes once that job ends: a move or a portion is not
        cut short (a survey or a refill is: they leave as they do for a demand), and nothing else
        starts meanwhile. ``manual_asked`` says it is coming; hands off before it withdraws it."""
        if on and self.state in ("idle", "fault"):
            self._cancel_action()            # hands on: nothing of ours may move
            self.manual_asked = False
            self.take_manual()
        elif on and self.state in ACTIVE:
            self.manual_asked = True
        elif not on and self.state == "manual":
            self.release_manual()
        elif not on and self.manual_asked:
            self.manual_asked = False
        elif on != (self.state == "manual"):
            return f"cannot {'take' if on else 'release'} manual control in state {self.state}"
        self._poke()
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
        watch = asyncio.create_task(self._watch_rail())
        try:
            while True:
                self._action = asyncio.create_task(self._step())
                await asyncio.wait({self._action})
                if self._action.cancelled():
                    continue                  # an e-stop or the operator took over; the state says what next
                exc = self._action.exception()
                if exc is not None and not isinstance(exc, Halted):
                    self._fault(exc)
                if self.lane.tripped and self.state != "estop":
                    self._stopped(self.lane.reason or "e-stop")   # the loop hears of it late
        finally:                              # cancelled: our action must not outlive us
            watch.cancel()
            self._cancel_action()
            if self._action is not None:
                await asyncio.gather(self._action, return_exceptions=True)

    async def _step(self) -> None:
        if self.state == "homing":
            await self._home()
        elif self.state == "idle" and self.manual_asked:
            self.manual_asked = False        # the job under way when it was asked is done
            self.take_manual()
        elif self.state == "idle":
            await self._idle()
        elif self.state == "fault":
            await self._recover()
        else:                                  # estop, manual: wait for the operator
            await self._wait(self._operator, 3600.0)

    async def _home(self) -> None:
        self.dispensing.hopper_g = None          # hands may have been on the hopper: look again
        released = self._estop_released          # hands may have been on the carriage too: home it
        status = await self._clear_rail()
        if released or not status.homed or status.state == "homing":
            if status.state != "homing":
                self._halt_if_tripped()
                await self.rail.home()
            await self.rail.wait_until(lambda s: s.homed and s.state == "idle", self.feeding.move_timeout_s)
        if (await self.dispensing.read()).refilling:   # a refill cut short by a crash or an e-stop
            await self.dispenser.set_refill(False)
        waiting = {job.demand_id: job for job in self.pending.values() if job.demand_id is not None}
        for feed in await self.dispensing.settle(waiting):
            if feed.demand_id in waiting:
                self._served(waiting[feed.demand_id], feed)
        for job in [j for j in self.pending.values() if j.intent is not None]:
            # an operator's portion has no demand to close: its own intent says whether it went in
            # (a START whose reply was lost, settled done from the counters, was fed again)
            self._served(job, self.store.feed(job.intent))
        self.homed()

    async def _idle(self) -> None:
        self._wake.clear()
        self._expire()
        job = await self._next_job()
        hopper = self.hopper_g if self.hopper_g is not None else (await self.dispensing.read()).hopper_g
        if job is not None:
            portion = self.dispensing.portion(job.tank, job.grams)
            if portion <= 0:
                self._finish(job, self._unfed(job.tank))
            elif hopper < portion * (1 + self.dispensing.overshoot):
                await self._refill()
            else:
                await self._serve(job)
        elif hopper < self.feeding.refill_below_g:
            await self._refill()
        elif (survey := self._survey_due()) is not None:
            await self._survey(survey)
        else:
            await self._wait(self._wake, 30.0)

    def _in_service(self) -> None:
        """A job done: whatever failed before works again."""
        self.failures = 0
        self.alarms.clear("feeder", "feeder back in service")

    # -- jobs -----------------------------------------------------------------
    async def _next_job(self) -> Job | None:
        if len(self.pending) <= 1:
            return next(iter(self.pending.values()), None)
        now, f = self.clock.now(), self.feeding
        stops = {job.tank: Stop(job.tank, self.cfg.tank(job.tank).position_m, job.t,
                                f.portion_g / self.dispensing.rate_g_s) for job in self.pending.values()}
        here = (await self._rail_status()).position_m
        best = next_stop(list(stops.values()), here, now, deadline_s=f.serve_within_s - f.plan_margin_s,
                         speed_m_s=f.rail_speed_m_s, accel_m_s2=f.rail_accel_m_s2)
        return self.pending[best.tank]

    def _survey_due(self):
        return None if self.surveys is None else self.surveys.next(self.paused, self.clock.now())

    def _servable(self) -> bool:
        """Whether a demand waits that would be fed. One of a tank that has had its ration is closed
        ``ration_reached`` here, as the idle robot closes it, and does not end a survey visit (in an
        afternoon of such demands every visit ended within its settle wait, the cameras started and
        stopped once a wall second, and no survey was made)."""
        for job in list(self.pending.values()):
            if self.dispensing.portion(job.tank, job.grams) <= 0:
                self._finish(job, "ration_reached")
        return bool(self.pending)

    # -- helpers --------------------------------------------------------------
    def _halt_if_tripped(self) -> None:
        """Before every actuator command: the e-stop's token, checked with nothing awaited after."""
        if self.lane.tripped:
            raise Halted("e-stop tripped: command not sent")

    def _served(self, job: Job, feed) -> None:
        # a suspect run served its ask too: what it gave is unknown, and fish still hungry ask again
        if feed.phase in ("done", "suspect") and self.pending.get(job.tank) is job:
            del self.pending[job.tank]

    def _unfed(self, tank: str) -> str:
        """Why a demand gets no portion: its tank holds no fish any more, or its ration is given."""
        return "emptied" if self.rations.stock(tank) <= 0 else "ration_reached"

    def _finish(self, job: Job, outcome: str) -> None:
        if self.pending.get(job.tank) is job:
            del self.pending[job.tank]
        if job.demand_id is not None:
            self.store.close_demand(job.demand_id, outcome)

    def _expire(self) -> None:
        horizon = self.clock.now() - self.feeding.demand_expiry_s
        for job in [j for j in self.pending.values() if j.t < horizon]:
            log.warning("demand of %s at %s expired unserved", job.tank, self.clock.iso(job.t))
            self._finish(job, "expired")

    def poke(self) -> None:
        """Something to do may have come (an operator's survey): look again now."""
        self._wake.set()

    def _poke(self) -> None:
        self._operator.set()
        self._wake.set()

    async def _wait(self, event: asyncio.Event, farm_s: float) -> None:
        try:
            await asyncio.wait_for(event.wait(), timeout=self.clock.wall(farm_s))
        except TimeoutError:
            pass
        event.clear()

    def _cancel_action(self) -> None:
        if self._action is not None and not self._action.done() and self._action is not asyncio.current_task():
            self._action.cancel()

    def _state_changed(self) -> None:
        log.info("feeder: %s", self.state)
        try:                                  # news, not the record: never let it delay or stop a move
            self.publish("feeder/state", self.snapshot())
        except Exception as exc:
            log.warning("feeder state not published: %s", exc)
