"""The feeding robot's journeys (a mixin of ``robot.FeedingRobot``): to a tank to serve a portion,
to a tank to survey it, to the food box to refill the hopper; each a move and the work at its end,
each actuator command after the e-stop token's check (``_halt_if_tripped``).
"""
from __future__ import annotations

import asyncio
import logging
from typing import TYPE_CHECKING

from controller.feeding.dispensing import FULL_SHARE, AugerJammed, OutcomeUnknown, Withdrawn
from devices.errors import DeviceTimeout

if TYPE_CHECKING:
    from controller.feeding.robot import Job

log = logging.getLogger("fishfarm.feeder")


class Trips:
    """Needs the robot's state machine (``go()``, ``arrive_tank()``, ``arrive_survey()``,
    ``arrive_box()``, ``dispensed()``, ``surveyed()``, ``refilled()``), ``cfg``, ``feeding``,
    ``clock``, ``rail``, ``dispenser``, ``dispensing``, ``surveys``, ``pending``, ``manual_asked``,
    ``_wake``, ``_served()``, ``_finish()``, ``_unfed()``, ``_servable()``, ``_in_service()`` and
    ``_halt_if_tripped()``."""

    async def _serve(self, job: Job) -> None:
        # the dispenser's own e-stop is read at the tank, before the START (dispensing.run): a read
        # here, before the move, held every feed a round trip to the PLC (at 360x, up to 54 farm s)
        self.go()
        await self._move_to(self.cfg.tank(job.tank).position_m)
        self.arrive_tank()
        portion = self.dispensing.portion(job.tank, job.grams)   # the day may have turned on the way
        if portion > 0:
            try:
                self._served(job, await self.dispensing.run(job.tank, portion, job.source, job.demand_id, job.t,
                                                            on_intent=lambda feed: setattr(job, "intent", feed.id)))
            except (AugerJammed, OutcomeUnknown) as fault:   # food went in, or may have: the ask was served
                self._served(job, fault.feed)
                raise
            except Withdrawn:                 # paused on the way or at the tank: not fed after all
                log.info("portion for %s not started: the tank was paused", job.tank)
                self._finish(job, "paused")
        else:
            self._finish(job, self._unfed(job.tank))
        self.dispensed()
        self._in_service()

    async def _survey(self, session) -> None:
        """A survey stop (controller/surveys/stop.py): it leaves for any demand it would serve."""
        self.go()
        await self._move_to(self.cfg.tank(session.tank).position_m)
        self.arrive_survey()
        await self.surveys.visit(session, lambda: self._servable() or self.manual_asked, self._wake)
        self.surveyed()

    async def _refill(self) -> None:
        self.go()
        await self._move_to(self.feeding.food_box_m)
        self.arrive_box()
        full = self.feeding.hopper_capacity_g * FULL_SHARE
        # what a portion needs: a refill cut short for the fish waiting always holds one (cut at
        # refill_below_g alone, a portion above it sent the robot back to the box for good)
        enough = max(self.feeding.refill_below_g, self.feeding.portion_g * (1 + self.dispensing.overshoot))
        self._halt_if_tripped()
        await self.dispenser.set_refill(True)
        try:
            deadline = self.clock.now() + self.feeding.refill_timeout_s
            while (state := await self.dispensing.read()).hopper_g < full:
                if (self.pending or self.manual_asked) and state.hopper_g >= enough:
                    break                      # enough for the fish waiting now; top up later
                if self.clock.now() > deadline:
                    raise DeviceTimeout(self.dispenser.name,
                                        f"hopper not full after refill: {state.hopper_g:.0f} g")
                await asyncio.sleep(max(0.0005, self.clock.wall(0.5)))
        finally:
            await self.dispenser.set_refill(False)
        self.refilled()
        self._in_service()

    async def _move_to(self, position_m: float) -> None:
        tol = self.feeding.position_tolerance_m
        status = await self._rail_status()
        if status.state == "idle" and abs(status.position_m - position_m) <= tol:
            return
        self._halt_if_tripped()
        await self.rail.move_to(position_m)
        await self.rail.wait_until(lambda s: s.state == "idle" and abs(s.position_m - position_m) <= tol,
                                   self.feeding.move_timeout_s)

    async def _rail_status(self):
        status = self.rail.status()
        if status is None:
            status = await self.rail.wait_until(lambda s: True, self.feeding.move_timeout_s)
        return status
