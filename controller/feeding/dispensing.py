"""Dispensing through the ledger: exactly once, within the ration.

Every auger run is an intent committed (with the dispenser's run counter and a tag) before the
auger is told to start, and closed from the dispenser's own counters after — by the run that
started it, or, after a crash, an e-stop or a fault, by ``settle()``. The auger's delivery rate is
learned from the load cell and remembered in the ledger, so a restart does not forget it; until a
few runs have been measured the portion keeps a wider margin, since a guessed rate may be wrong.

What the counters cannot tell is never freed: such an intent becomes ``suspect`` (still counted
against the ration, alarmed under ``ledger``) until an operator settles it (``settle_suspect``).
Every read checks the counters against those last seen: counters that went backwards (a power
cut, a new PLC) are alarmed under ``dispenser_counters``.
"""
from __future__ import annotations

import asyncio
import collections
import logging
import math
import statistics

from controller.feed_outcome import SUSPECT, reconcile, went_backwards
from controller.feeding.estop import Halted
from controller.feeding.recovery import DriveEstopped
from devices.errors import DeviceFault, DeviceTimeout

log = logging.getLogger("fishfarm.feeder")

OVERSHOOT = 0.15        # the least room a portion capped by the ration leaves for the auger delivering more ...
SPREAD_SDS = 6.0        # ... or this many standard deviations of its measured delivery / aim above their mean
SPREAD_RUNS = 200       # ... over its last this many measured runs (from this many: MIN_SPREAD_RUNS)
MIN_SPREAD_RUNS = 20
UNMEASURED = 0.5        # ... and this much while its rate is still a guess (never less than the spread's)
FULL_SHARE = 0.98       # a refill fills the hopper to this share of hopper_capacity_g
MEASURED_RUNS = 3       # runs before the learned rate is trusted
POLL_WALL_S = 0.0005    # dispenser polling once a run should have ended
MEASURED = "measured"   # note of a run that ended as timed: its grams teach the rate
START_MARGIN_S = 5.0    # farm s past a run's planned end before "never started" is believed ...
START_MARGIN_WALL_S = 0.25   # ... and at least this much wall time (a START still on the wire)
LEDGER, COUNTERS = "ledger", "dispenser_counters"   # alarm sources


class Withdrawn(Exception):
    """The tank was paused before its portion's intent was written: nothing started."""


class AugerJammed(DeviceFault):
    """The run jammed part way; ``feed`` is closed with what the load cell saw leave."""

    def __init__(self, device: str, text: str, feed):
        super().__init__(device, text)
        self.feed = feed


class OutcomeUnknown(DeviceFault):
    """The run's outcome cannot be told from the counters; ``feed`` is held as suspect."""

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
        # delivery / aim of the last measured runs, newest last: the spread a capped portion leaves room for
        self.ratios = collections.deque(reversed(store.delivery_ratios(MEASURED, SPREAD_RUNS)), maxlen=SPREAD_RUNS)
        self.hopper_g: float | None = None
        self._seen = store.counters_seen(dispenser.name)     # (cycles, total_g) last seen
        self.halted = lambda: False             # the e-stop's token: the robot sets its own here
        self.withdrawn = lambda tank: False     # a tank paused since its portion was planned: the robot's

    @property
    def overshoot(self) -> float:
        """How much more than aimed a run may deliver (fraction), for the room a portion capped by
        the ration leaves. A fixed ±15 % was exceeded (a measured sd of 4.4 %, the learned rate's
        lag included, and 1 run in ~2,000 over +15 %: a tank fed 3.7 g over its ration in a 60-day
        grow-out): the room now follows the auger's measured spread, at 6 sd."""
        if self.measured_runs < MEASURED_RUNS:
            return UNMEASURED
        if len(self.ratios) < MIN_SPREAD_RUNS:
            return OVERSHOOT
        spread = statistics.fmean(self.ratios) + SPREAD_SDS * statistics.pstdev(self.ratios) - 1.0
        return min(max(OVERSHOOT, spread), UNMEASURED)

    def portion(self, tank: str, ask_g: float | None = None) -> float:
        """Grams to aim for now: never more than the ask, and room left for the auger's spread; none
        for a tank whose stock events took all its fish (an operator's feed asked before a harvest
        was served into the empty tank: an operator's ration of the day outlives the harvest)."""
        if self.rations.stock(tank) <= 0:
            return 0.0
        grams = self.rations.portion(tank, self.clock.now(), self.overshoot)
        return min(grams, ask_g) if ask_g is not None else grams

    async def read(self):
        state = await self.dispenser.read()
        self.hopper_g = state.hopper_g
        self._check_counters(state)
        return state

    def _check_counters(self, state) -> None:
        """Counters only move forward while the device is powered: alarm when they did not."""
        seen = (state.cycles, state.total_grams)
        if self._seen == seen:
            return
        if self._seen is not None:
            cycles, total = self._seen
            if went_backwards(cycles, state.cycles) or state.total_grams < total - 1e-6:
                self.alarms.raise_(COUNTERS, f"dispenser {self.dispenser.name} counters went backwards "
                                   f"(cycles {cycles} -> {state.cycles}, total {total:.1f} g -> "
                                   f"{state.total_grams:.1f} g): power cut or new PLC; open intents are "
                                   "held as suspect", "critical")
            elif state.cycles != cycles:
                self._landed_late(state)
        self._seen = seen
        self.store.see_counters(self.dispenser.name, state.cycles, state.total_grams, self.clock.now())

    def _landed_late(self, state) -> None:
        """A run finished under the tag of a feed closed as never started: its START was held on a
        stalled link (a TCP relay, a Modbus gateway's queue) past the wait a restart gives it, and
        landed. Booked done with the device's grams: the food went in (where the chute was then)."""
        note = (f"its START landed late, after it was given up as never started: {state.last_grams:.1f} g "
                "by the dispenser's counters, into wherever the chute was then")
        late = self.store.rebook_late(state.last_tag, state.last_grams, self.clock.now(), note)
        if late is not None:
            log.warning("feed %s for %s (tag %d): %s", late.id, late.tank, late.tag, note)
            self._publish_feed(late)
            self.publish_ration(late.tank)

    async def run(self, tank: str, grams: float, source: str, demand_id: int | None, raised_t: float,
                  on_intent=None):
        """One portion into the tank under the chute. Returns the closed feed. ``on_intent(feed)``
        is told the intent as soon as it is written, before the START."""
        state = await self.read()
        if state.refilling:                       # a gate left open (a crash mid-refill) blocks the auger
            await self.dispenser.set_refill(False)
            state = await self.read()
        if state.estop:                           # latched at its own panel: the START would be refused 04
            raise DriveEstopped(self.dispenser.name, "the dispenser reports an e-stop (its own button?)")
        if state.jammed or state.running:
            raise DeviceFault(self.dispenser.name, "jammed" if state.jammed else "auger already running")
        self._check_token("intent")
        if self.withdrawn(tank):                  # paused while the state was read: nothing is committed
            raise Withdrawn(tank)
        now = self.clock.now()
        run_s = grams / self.rate_g_s
        feed = self.store.add_intent(tank=tank, date=self.rations.date(now), t=now, target_g=grams, run_s=run_s,
                                     cycles_before=state.cycles, source=source, demand_id=demand_id,
                                     hopper_before=state.hopper_g, device_tags=(state.last_tag, state.run_tag))
        self._publish_feed(feed)
        if on_intent is not None:
            on_intent(feed)
        self._check_token("START")                # right before it, nothing awaited between
        log.info("auger on for %s: %.1f g, %.1f s after the ask", tank, grams, now - raised_t)
        await self.dispenser.run_auger(run_s, feed.tag)
        await self.clock.asleep(run_s)            # the device times the run; look when it should be over
        state, result = await self._wait_run_end(feed, accepted=True)
        closed = self._close(result, demand_id, MEASURED if not state.jammed else "")
        if closed.phase == SUSPECT:
            raise OutcomeUnknown(self.dispenser.name, f"outcome of auger run {feed.tag} unknown: {result.note}",
                                 closed)
        if closed.phase == "done" and not state.jammed and run_s > 1.0 and closed.grams > 0 \
                and not self.halted():
            self._learn(closed.grams / run_s)
            self.ratios.append(closed.grams / grams)
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
            _, result = await self._wait_run_end(feed, accepted=False)
            demand = feed.demand_id if feed.demand_id in serving else None
            closed.append(self._close(result, demand, "settled from the dispenser's counters"))
        return closed

    async def _wait_run_end(self, feed, *, accepted: bool):
        """Poll until the counters decide ``feed``. Unless the device acknowledged our START
        (``accepted``), "never started" is believed only once the run's planned end plus a margin
        has passed with no sign of it: a START sent by a controller that died may still land."""
        now = self.clock.now()
        deadline = max(now, feed.t_intent + feed.run_s) + self.feeding.dispense_timeout_s
        margin = START_MARGIN_S
        if math.isfinite(self.clock.speed):
            margin = max(margin, START_MARGIN_WALL_S * self.clock.speed)
        believe_from = feed.t_intent + feed.run_s + margin
        poll = max(POLL_WALL_S, self.clock.wall(0.05))
        while True:
            state = await self.read()
            result = reconcile(feed, state, accepted=accepted)
            if result.phase != "wait" and (not result.no_run_seen or self.clock.now() >= believe_from):
                return state, result
            if self.clock.now() > deadline:
                raise DeviceTimeout(self.dispenser.name, f"auger run {feed.tag} did not end")
            await asyncio.sleep(poll)

    def _close(self, result, demand_id: int | None, note: str):
        feed = result.feed
        if result.phase == SUSPECT:
            closed = self.store.mark_suspect(feed.id, result.note)
            self._publish_feed(closed)
            self._alarm_suspects()
            return closed
        phase = result.phase
        served = demand_id if phase == "done" else None
        closed = self.store.close_feed(feed.id, phase, result.grams, self.clock.now(),
                                       note if phase == "done" else result.note, served)
        self._publish_feed(closed)
        if phase == "done":
            self.publish_ration(feed.tank)
            if COUNTERS in self.alarms.active:
                self.alarms.clear(COUNTERS, "dispenser counters moving forward again")
        return closed

    def settle_suspect(self, feed_id: str, grams: float, operator: str, reason: str):
        """An operator's word on a suspect feed: ``grams`` went in (0: none). Returns the feed.
        LookupError when ``feed_id`` is not a suspect feed."""
        closed = self.store.settle_suspect(feed_id, grams, self.clock.now(), operator, reason)
        log.warning("feed %s to %s settled by %s: %.1f g (%s)", feed_id, closed.tank, operator, grams, reason)
        self._alarm_suspects()
        self._publish_feed(closed)
        try:
            self.publish_ration(closed.tank)
        except KeyError:
            # a tank taken out of the config since: no ration of it to publish. (This KeyError, a
            # LookupError, was answered "not suspect" of a feed settled in the ledger, and the alarm
            # naming it stood for good.)
            log.info("feed %s settled for tank %s, which the config no longer has", feed_id, closed.tank)
        return closed

    def _alarm_suspects(self) -> None:
        suspects = self.store.suspects()
        if not suspects:
            self.alarms.clear(LEDGER, "no feed of unknown outcome left")
            return
        ids = ", ".join(f"{f.id} ({f.tank} {f.target_g:.0f} g)" for f in suspects[:10])
        more = f" and {len(suspects) - 10} more" if len(suspects) > 10 else ""
        self.alarms.raise_(LEDGER, f"{len(suspects)} feed(s) of unknown outcome held against the ration: "
                           f"{ids}{more}; settle with `fishfarm override settle id=ID grams=G`", "critical")

    def _learn(self, rate: float) -> None:
        self.measured_runs += 1
        weight = 1.0 / self.measured_runs if self.measured_runs < MEASURED_RUNS else 0.3
        self.rate_g_s += weight * (rate - self.rate_g_s)

    def _publish_feed(self, feed) -> None:
        # The contract's phases are intent | done | aborted: a suspect feed stays an intent (flagged)
        # until an operator settles it.
        grams = feed.grams if feed.phase == "done" else feed.target_g
        payload = {"t": self.clock.iso(feed.t_closed or feed.t_intent), "grams": round(grams or 0.0, 1),
                   "phase": "intent" if feed.phase == SUSPECT else feed.phase, "id": feed.id}
        if feed.phase == SUSPECT:
            payload["suspect"] = True
        self.publish(f"tank/{feed.tank}/feed", payload, reliable=True)

    def publish_ration(self, tank: str) -> None:
        self.publish(f"tank/{tank}/ration", self.rations.payload(tank, self.clock.now()))
