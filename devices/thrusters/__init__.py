"""The pond-cleaning robot's two thrusters (left, right) and their motor controller.

Interface: ``Thrusters``. Backends, chosen by ``driver`` through ``BACKENDS``:
- ``serial``: the motor controller on a serial line (pyserial); line protocol in README.md
              ("Thrusters line protocol") and devices/thrusters/protocol.py.
- ``sim``:    the simulated controller (devices/sim/thrusters.py) on a pseudo-terminal, reached
              through the ``serial`` backend.

Safety lives in the device: it holds the e-stop latch (every drive refused until reset) and a
watchdog (Klipper's max_duration): no drive for ``watchdog_s`` farm seconds and it stops both
thrusters itself, so a controller that dies, hangs or loses the line leaves them stopped.
"""
from __future__ import annotations

import abc
from dataclasses import dataclass

from devices.base import Device
from devices.errors import DeviceFault
from devices.thrusters.protocol import thrust_ok


@dataclass(frozen=True, slots=True)
class ThrusterState:
    """The latest status the device reported. ``t``: the device's farm time of the report;
    ``left``/``right``: the thrust it actually gives (ramping), fraction of full, + forward;
    ``watchdog``: its watchdog stopped the thrusters (cleared by the next drive)."""

    t: float
    left: float
    right: float
    estop: bool
    watchdog: bool
    fault: str | None


class EstopLatched(DeviceFault):
    """A drive refused: the e-stop latch is set (by us or by the device); only ``reset_estop`` clears it."""


class Thrusters(Device):
    kind = "thrusters"

    async def drive(self, left: float, right: float) -> None:
        """Command thrust (fractions of full, in [-1, 1], + forward); returns once the device
        accepted it. EstopLatched while latched, DeviceFault while in fault. The device stops
        both by itself unless the next drive comes within its watchdog."""
        if not (thrust_ok(left) and thrust_ok(right)):
            raise ValueError(f"{self.name}: drive({left!r}, {right!r}): thrust must lie in [-1, 1]")
        self._check_open()
        await self._drive(float(left), float(right))

    async def stop(self) -> None:
        """Both thrusters to zero (ramped); accepted in every state."""
        self._check_open()
        await self._stop()

    def trip_estop(self) -> ThrusterState:
        """The e-stop lane: write the latch frame now from the calling thread (any thread but
        the loop's), then wait a bounded time (``estop_timeout_s``, wall) for a status showing it.
        Returns that status (``estop`` True: confirmed); DeviceError when the line is down or the
        device silent. Never waits behind a command in flight."""
        return self._trip_estop()

    def estop_seen_since(self, t: float) -> bool:
        """Whether a status showing the latch arrived at or after ``t`` (``time.monotonic()``);
        from any thread, without the event loop."""
        return self._estop_seen_since(t)

    async def reset_estop(self) -> None:
        """Release the latch (and a fault): the operator's reset. The thrusters stay at zero."""
        self._check_open()
        await self._reset_estop()

    async def set_watchdog(self, watchdog_s: float) -> None:
        """The device's max_duration between drives, farm seconds (0.05..600)."""
        if not 0.05 <= watchdog_s <= 600:
            raise ValueError(f"{self.name}: watchdog of {watchdog_s!r} s is out of range 0.05..600")
        self._check_open()
        await self._set_watchdog(watchdog_s)

    def status(self) -> ThrusterState | None:
        """Latest status, None before the first. LinkDown when the line is gone, DeviceTimeout
        when the device has been silent longer than its ``status_timeout_s`` (wall)."""
        return self._status()

    def _check_open(self) -> None:
        if not self._opened or self._closed:
            raise RuntimeError(f"{self.name}: device is not open")

    @abc.abstractmethod
    async def _drive(self, left: float, right: float) -> None: ...
    @abc.abstractmethod
    async def _stop(self) -> None: ...
    @abc.abstractmethod
    def _trip_estop(self) -> ThrusterState: ...
    @abc.abstractmethod
    def _estop_seen_since(self, t: float) -> bool: ...
    @abc.abstractmethod
    async def _reset_estop(self) -> None: ...
    @abc.abstractmethod
    async def _set_watchdog(self, watchdog_s: float) -> None: ...
    @abc.abstractmethod
    def _status(self) -> ThrusterState | None: ...


BACKENDS = {
    "serial": "devices.thrusters.serial_thrusters:SerialThrusters",
}
