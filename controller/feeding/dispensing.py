"""Dispensing through the ledger: exactly once, within the ration.

Every auger run is an intent committed (with the dispenser's run counter and a tag) before the
auger is told to start, and closed from the dispenser's own counters after — by the run that
started it, or, after a crash, an e-stop or a fault, by ``settle()``. The auger's delivery rate is
learned from the load cell and remembered in the ledger, so a restart does not forget it; until a
few runs have been measured the portion keeps a wider margin, since a guessed rate may be wrong.
"""
from __future__ import annotations

import asyncio
import logging

from controller.feeding.estop import Halted
from controller.feeding.rations import ration_payload
from controller.store import reconcile
from devices.errors import DeviceFault, DeviceTimeout

log = logging.getLogger("fishfarm.feeder")

OVERSHOOT = 0.15        # a measured auger delivers within ±15 % of aim: portions leave that much room
UNMEASURED = 0.5        # ... and this much while its rate is still a guess
MEASURED_RUNS = 3       # runs before the learned rate is trusted
POLL_WALL_S = 0.0005    # dispenser polling once a run should have ended
MEASURED = "measured"   # note of a run that ended as timed: its grams teach the rate


class AugerJammed(DeviceFault):
    """The run jammed part way; ``feed`` is closed with what the load cell saw leave."""

    def __init__(self, device: str, text: str, feed):
        super().__init__(device, text)
        self.feed = feed


class Dispensing:
    def __init__(self, cfg, clock, dispenser, store, rations, alarms, publish):
        self.feeding, self.clock, self.dispenser = cfg.feeding, clock, dispenser
        self.store, self.rations, self.alarms, self.publish = store, rations, alarms, publish
        rate, runs = store.learned_rate(MEASURED)
        self.rate_g_s = rate if rate is not None else self.feeding.auger_rate_g_s
        self.measured_runs = runs
        self.hopper_g: float | None = None
        self.halted = lambda: False             # the e-stop's token: the robot sets its own here

    @property
    def overshoot(self) -> float:
        return OVERSHOOT if self.measured_runs >= MEASURED_RUNS else UNMEASURED

    def portion(self, tank: str, ask_g: float | None = None) -> float:
        """Grams to aim for now: never more than the ask, and room left for the auger's spread."""
        grams = self.rations.portion(tank, self.clock.now(), self.overshoot)
        return min(grams, ask_g) if ask_g is not None else grams

    async def read(self):
        state = await self.dispenser.read()
        self.hopper_g = state.hopper_g
        return state

    async def run(self, tank: str, grams: float, source: str, demand_id: int | None, raised_t: float):
        """One portion into the tank under the chute. Returns the closed feed."""
        state = await self.read()
        if state.refilling:                       # a gate left open (a crash mid-refill) blocks the auger
            await self.dispenser.set_refill(False)
            state = await self.read()
        if state.jammed or state.running:
            raise DeviceFault(self.dispenser.name, "jammed" if state.jammed else "auger already running")
        self._check_token("intent")
        now = self.clock.now()
        run_s = grams / self.rate_g_s
        feed = self.store.add_intent(tank=tank, date=self.rations.date(now), t=now, target_g=grams, run_s=run_s,
                                     cycles_before=state.cycles, source=source, demand_id=demand_id)
        self._publish_feed(feed)
        self._check_token("START")                # right before it, nothing awaited between
        log.info("auger on for %s: %.1f g, %.1f s after the ask", tank, grams, now - raised_t)
        await self.dispenser.run_auger(run_s, feed.tag)
        await self.clock.asleep(run_s)            # the device times the run; look when it should be over
        state = await self._wait_run_end(feed)
        closed = self._close(feed, state, demand_id, MEASURED if not state.jammed else "")
        if closed.phase == "done" and not state.jammed and run_s > 1.0 and closed.grams > 0 and not self.halted():
            self._learn(closed.grams / run_s)
        if state.jammed:
            raise AugerJammed(self.dispenser.name, "auger jammed", closed)
        return closed

    def _check_token(self, step: str) -> None:
        """An e-stop tripped (on any thread) stops a dispense before its next step; an intent
        already committed is settled from the counters after the reset (it never started)."""
        if self.halted():
            raise Halted(f"e-stop tripped: {step} not done")

    async def settle(self, serving: dict[int, object]) -> list:
        """Close every open intent from the dispenser's counters; ``serving`` maps demand ids still
        waiting, so a run that did happen also closes its demand. Returns the closed feeds."""
        closed = []
        for feed in self.store.open_intents():
            await self.clock.asleep(feed.t_intent + feed.run_s - self.clock.now())
            state = await self._wait_run_end(feed)
            demand = feed.demand_id if feed.demand_id in serving else None
            closed.append(self._close(feed, state, demand, "settled from the dispenser's counters"))
        return closed

    async def _wait_run_end(self, feed):
        deadline = self.clock.now() + self.feeding.dispense_timeout_s
        poll = max(POLL_WALL_S, self.clock.wall(0.05))
        while True:
            state = await self.read()
            if reconcile(feed, state).phase != "wait":
                return state
            if self.clock.now() > deadline:
                raise DeviceTimeout(self.dispenser.name, f"auger run {feed.tag} did not end")
            await asyncio.sleep(poll)

    def _close(self, feed, state, demand_id: int | None, note: str):
        result = reconcile(feed, state)
        phase = "done" if result.phase == "done" else "aborted"
        if result.phase == "unknown":
            self.alarms.raise_("ledger", f"feed {feed.id} to {feed.tank}: outcome unknown: {result.note}",
                               "critical")
        served = demand_id if phase == "done" else None
        closed = self.store.close_feed(feed.id, phase, result.grams, self.clock.now(),
                                       note if phase == "done" else result.note, served)
        self._publish_feed(closed)
        if phase == "done":
            self.publish_ration(feed.tank)
        return closed

    def _learn(self, rate: float) -> None:
        self.measured_runs += 1
        weight = 1.0 / self.measured_runs if self.measured_runs < MEASURED_RUNS else 0.3
        self.rate_g_s += weight * (rate - self.rate_g_s)

    def _publish_feed(self, feed) -> None:
        grams = feed.grams if feed.phase == "done" else feed.target_g
        self.publish(f"tank/{feed.tank}/feed", {"t": self.clock.iso(feed.t_closed or feed.t_intent),
                                                "grams": round(grams or 0.0, 1), "phase": feed.phase,
                                                "id": feed.id}, reliable=True)

    def publish_ration(self, tank: str) -> None:
        ration = self.rations.today(tank, self.clock.now())
        self.publish(f"tank/{tank}/ration", ration_payload(ration))
