"""The rail drive that carries the feeding robot between the food box and the tanks.

Interface: ``RailDrive``. Backends, chosen by ``driver`` through ``BACKENDS``:
- ``can``: a motor controller on CAN (python-can: ``virtual`` bus in one process, ``slcan``
           over a serial line/pty, or any python-can interface). Frames in README.md.
- ``sim``: the simulated motor controller (devices/sim) with travel dynamics, reached
           through the ``can`` backend over slcan on a pty.
"""
from __future__ import annotations

import abc
from dataclasses import dataclass

from devices.base import Device


@dataclass(frozen=True, slots=True)
class RailStatus:
    """Latest status the drive reported. ``t`` farm time of the report."""

    t: float
    position_m: float
    velocity_m_s: float
    state: str          # "unhomed" | "homing" | "idle" | "moving" | "fault" | "estop"
    homed: bool
    fault_code: int = 0
    at_target: bool = False     # idle at the last commanded target (or at home after homing)
    at_limit: bool = False      # on the home switch or at the far soft limit


class RailDrive(Device):
    kind = "rail"

    # Commands return once the drive has accepted them; motion is followed with status().
    async def home(self) -> None: await self._command("home")
    async def move_to(self, position_m: float) -> None: await self._command("move", position_m)
    async def stop(self) -> None: await self._command("stop")
    async def estop(self) -> None: await self._command("estop")
    async def clear_fault(self) -> None: await self._command("clear")

    def trip_estop(self) -> None:
        """The e-stop lane: send ESTOP now from the calling thread (any thread), waiting for no
        reply and for nothing queued; LinkDown when the link is gone."""
        raise NotImplementedError

    def estop_seen_since(self, t: float) -> bool:
        """Whether the drive has reported "estop" since ``t`` (``time.monotonic()``); callable
        from any thread, answered without the event loop."""
        raise NotImplementedError

    def status(self) -> RailStatus | None:
        """Latest status, or None before the first report. Raises DeviceTimeout when the drive
        has gone silent for longer than its timeout (wall seconds)."""
        return self._status()

    async def wait_until(self, predicate, timeout_s: float, *, stop_on_fault: bool = True) -> RailStatus:
        """Wait (farm seconds) until a status satisfies ``predicate``; DeviceTimeout otherwise.
        A status in "fault" or "estop" that does not satisfy it raises DeviceFault at once,
        unless ``stop_on_fault`` is False (e.g. to watch the carriage come to rest after an e-stop)."""
        return await self._wait_until(predicate, timeout_s, stop_on_fault)

    @abc.abstractmethod
    async def _command(self, what: str, arg: float | None = None) -> None: ...
    @abc.abstractmethod
    def _status(self) -> RailStatus | None: ...
    @abc.abstractmethod
    async def _wait_until(self, predicate, timeout_s: float, stop_on_fault: bool) -> RailStatus: ...


BACKENDS = {
    "can": "devices.rail.can_drive:CanRailDrive",
}
