"""The feeding robot's faults and their recovery (a mixin of ``robot.FeedingRobot``).

A device error puts the robot in ``fault`` (one alarm, counted); recovery waits out a back-off
that grows with the failures in a row, then clears what the devices latched — a jam, a refill
cut short, a drive fault once the carriage is at rest — and an e-stop only after an operator
released it here. A device reporting an e-stop nobody here commanded (its own button, or one from
before a restart) is an e-stop: the lane latches the other device too.
"""
from __future__ import annotations

import asyncio
import logging
import time

from controller.ledger_writes import LedgerUnwritable
from devices.errors import DeviceError, LinkDown

log = logging.getLogger("fishfarm.feeder")

WATCH_WALL_S = 0.1            # wall s between looks at the drive's latest status (no I/O: the CAN reader's)
IDLE_SILENCE_WALL_S = 2.0     # wall s a waiting robot's drive stays unheard before that is a fault (a loaded
                              # machine's simulator may stall past status_timeout_s: no fault for a blink)
WATCHED = ("idle", "moving", "dispensing", "refilling", "surveying")


class DriveEstopped(DeviceError):
    """A device reports an e-stop nobody here commanded: its own button, or one before a restart."""


class Recovering:
    """Needs the robot's state machine (``state``, ``fail()``, ``recover()``), ``lane``, ``alarms``,
    ``feeding``, ``failures``, ``dispensing``, ``dispenser``, ``rail``, ``_estop_released``,
    ``_operator``, ``_wait()``, ``_stopped()``, ``_halt_if_tripped()`` and ``_rail_status()``."""

    def _fault(self, exc: BaseException) -> None:
        if self.state in ("estop", "manual") or self.lane.tripped:
            return                            # an e-stop explains it: run() puts us in estop
        if isinstance(exc, DriveEstopped):
            self.lane.trip(exc.text)          # latch the other device too
            self._stopped(exc.text)
            return
        if not isinstance(exc, DeviceError | LedgerUnwritable):   # the ledger alarm tells that one
            log.error("feeder: unexpected error", exc_info=exc)
        if self.state != "fault":
            self.fail()
        self.failures += 1
        self.alarms.raise_("feeder", f"fault: {exc}", "warning", kind="fault")

    async def _watch_rail(self) -> None:
        """Between the robot's own looks at the drive: a drive e-stopped at its own panel trips the
        lane at once (the auger ran its whole portion: the robot heard of it at its next move), and
        a drive gone silent or unplugged while the robot waits is a fault now, not at the next job."""
        unheard_since = None
        while True:
            await asyncio.sleep(WATCH_WALL_S)
            if self.state not in WATCHED or self.lane.tripped:
                unheard_since = None
                continue
            try:
                status = self.rail.status()
            except DeviceError as exc:
                now = time.monotonic()
                unheard_since = now if unheard_since is None else unheard_since
                if self.state == "idle" and now - unheard_since >= IDLE_SILENCE_WALL_S:
                    self._fault(exc)              # a busy robot meets it within its own bounds
                    self._cancel_action()
                continue
            except Exception:  # noqa: BLE001 - a watch that died of a bug would watch nothing, unseen
                log.exception("feeder: looking at the drive's status failed")
                continue
            unheard_since = None
            if status is not None and status.state == "estop":
                text = f"{self.rail.name}: the drive reports an e-stop (its own button?)"
                self.lane.trip(text)              # the dispenser's latch too: the auger stops
                self._stopped(text)

    async def _reopen_rail(self) -> None:
        """A drive whose CAN link is lost for good (an adapter unplugged and plugged back) opened
        anew; a DeviceError when it does not open keeps the robot in fault, tried after the next
        back-off (it stayed in fault until the controller was restarted)."""
        try:
            self.rail.status()
        except LinkDown:
            if self.reopen is not None:
                self.rail = await self.reopen(self.rail)
        except DeviceError:
            pass

    async def _recover(self) -> None:
        backoff = self.feeding.retry_backoff_s
        delay = backoff[min(self.failures, len(backoff)) - 1] if self.failures else 0.0
        await self._wait(self._operator, delay)
        if self.state != "fault":
            return
        await self._reopen_rail()
        state = await self.dispensing.read()
        if state.jammed:
            await self.dispenser.clear_fault()
        if state.refilling:
            await self.dispenser.set_refill(False)
        await self._clear_rail()
        self.recover()

    async def _clear_rail(self):
        """Clear a latched drive fault once the carriage has come to rest; an e-stop (the drive's
        or the dispenser's) only when an operator has released it here."""
        if (await self.dispensing.read()).estop:
            if not self._estop_released:
                raise DriveEstopped(self.dispenser.name, "the dispenser reports an e-stop")
            self._halt_if_tripped()
            await self.dispenser.reset_estop()
        status = await self._rail_status()
        if status.state == "estop" and not self._estop_released:
            raise DriveEstopped(self.rail.name, "the drive reports an e-stop")
        if status.state in ("fault", "estop"):
            await self.rail.wait_until(lambda s: s.velocity_m_s == 0, 30.0, stop_on_fault=False)
            self._halt_if_tripped()
            await self.rail.clear_fault()
            status = await self.rail.wait_until(lambda s: s.state not in ("fault", "estop"), 30.0,
                                                stop_on_fault=False)
        self._estop_released = False
        return status
