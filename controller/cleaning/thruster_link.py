"""The pond cleaner's thrusters as its coordinator (``controller.cleaning.cleaner``) drives them:
every drive checks the e-stop lane and the state machine first, with nothing awaited between the
check and the send, and passes the geofence; a failure is an e-stop heard or a device down; a
driver whose link is lost for good is replaced, backing off. A mixin of ``Cleaner``.
"""
from __future__ import annotations

import logging
import math
import time

from devices.errors import DeviceError, LinkDown

log = logging.getLogger("fishfarm.cleaner")

REOPEN_WALL_S = (0.5, 1.0, 2.0, 5.0)   # wall seconds between fresh drivers for lost thrusters


class ThrusterLink:
    # -- actuators: state and e-stop first ----------------------------------------
    async def _drive(self, left: float, right: float) -> None:
        backing = self.state == "lost" and self.recovery is not None and self.recovery.active   # its trail
        if self.fence is not None and not backing:     # the body's predicted footprint, not the follower's word
            left, right = self.fence.check(self.track, (left, right), self.clock.now())
        if self._must_stop and not backing:
            await self._halt()
        if self.lane.tripped or not (self.machine.moving or backing):   # nothing awaited between this and the send
            return
        try:
            await self.thrusters.drive(left, right)
        except DeviceError as exc:
            self._thrusters_failed(exc)
            return
        if left != 0 or right != 0:
            self._drove_t = self.clock.now()
        self._must_stop = self._must_stop or backing   # the recovery's end stops them
        status = self._thruster_status()
        if status is not None and (status.estop or status.fault is not None):
            self._thrusters_failed(DeviceError(self.thrusters.name, status.fault or "e-stop latched"))

    async def _halt(self) -> None:
        """Stop the thrusters once per entry into a still state (and when asked again)."""
        if not self._must_stop or self.lane.tripped:   # latched: the device holds them stopped
            return
        try:
            await self.thrusters.stop()
            self._must_stop = False
            self._drove_t = -math.inf
        except DeviceError as exc:
            self._thrusters_failed(exc)

    def _thrusters_failed(self, exc: DeviceError) -> None:
        status = self._thruster_status()
        if self.lane.tripped:
            self._hear_estop()
        elif status is not None and status.estop:   # its own button, or latched before a restart
            self.lane.trip(f"{self.thrusters.name} reports an e-stop")
            self._hear_estop()
        else:
            self._device_down(self.thrusters.name, exc.text)

    async def _try_thrusters(self) -> None:
        """In fault with the thrusters out: a stop that goes through and a clean state say they are back."""
        try:
            await self.thrusters.stop()
        except LinkDown as exc:
            self._device_down(self.thrusters.name, exc.text)
            await self._reopen_thrusters()
            return
        except DeviceError as exc:
            self._device_down(self.thrusters.name, exc.text)
            return
        status = self._thruster_status()
        if status is None or status.fault is None:
            self._must_stop = False
            self._reopen_tries = 0
            self._device_up(self.thrusters.name)

    async def _reopen_thrusters(self) -> None:
        """A driver whose link went is replaced by a fresh one, backing off: the next frame's stop
        then says whether they are back."""
        now = time.monotonic()
        if self.reopen is None or now < self._reopen_at:
            return
        self._reopen_at = now + REOPEN_WALL_S[min(self._reopen_tries, len(REOPEN_WALL_S) - 1)]
        self._reopen_tries += 1
        try:
            self.thrusters = await self.reopen(self.thrusters)
        except DeviceError as exc:
            log.debug("cleaner: reopening %s failed: %s", self.thrusters.name, exc.text)

    def _thruster_status(self):
        try:
            return self.thrusters.status()
        except DeviceError:
            return None

    def _latch_released(self) -> bool:
        status = self._thruster_status()
        return not self.lane.tripped and status is not None and not status.estop

    # -- devices going and coming ---------------------------------------------------
    def unavailable(self, name: str, why: str) -> None:
        """A device of the cleaner's that has not opened yet: ``fault`` until it is up (its first
        frame or status brings it back), as for one lost while running."""
        self._device_down(name, why)

    def _device_down(self, name: str, why: str) -> None:
        self._down[name] = why
        self.alarms.raise_(f"device/{name}", why, kind="unreachable")   # logged once, repeats counted
        self._must_stop = True
        self.machine.fire("device_fault")

    def _device_up(self, name: str) -> None:
        if name not in self._down:
            return
        del self._down[name]
        self.alarms.clear(f"device/{name}", "back", kind="unreachable")
        if not self._down:
            self.machine.fire("device_recovered")
