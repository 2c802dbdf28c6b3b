"""The dispenser on the feeding robot: hopper on a load cell, an auger, a refill gate.

Interface: ``Dispenser``. Backends, chosen by ``driver`` through ``BACKENDS``:
- ``modbus``: the real dispenser PLC over Modbus TCP (pymodbus). Register map in README.md.
- ``sim``:    the simulated twin, a pymodbus server (devices/sim) reached by ``modbus``.

Exactly-once dispensing rests on the device's own counters: every auger run carries a
``tag`` chosen by the controller; the device counts completed runs and keeps the tag and
load-cell grams of the last one, so after a restart the controller can tell whether an
intent it wrote ran, is running, or never started: ``DispenserState.fate(tag)``.
The whole state, counters included, is read in one request, so it is one consistent
snapshot. Tags must differ from one run to the next (the device refuses a start whose tag
is the running or the last run's), which makes ``run_auger`` idempotent per tag: calling
it again with the tag the device is running or ran last starts nothing and returns normally
(so a start resent after a lost reply, or by a restarted controller, never runs twice).

E-stop: the device holds a latch (``trip_estop``) that stops the auger, closes the refill gate and
refuses every START and GATE_OPEN until ``reset_estop``. ``trip_estop`` is synchronous and goes
over a path of its own that no queued request can delay; call it from any thread but the loop's.
"""
from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import Literal

from devices.base import Device


@dataclass(frozen=True, slots=True)
class DispenserState:
    hopper_g: float         # load cell, resolution ``resolution_g``
    running: bool           # auger turning
    jammed: bool            # device tripped on motor current / no flow
    refilling: bool         # refill gate open
    cycles: int             # completed auger runs since power-on (wraps at 2**32)
    last_tag: int           # tag of the last completed (or jammed) run
    last_grams: float       # load-cell grams delivered by that run
    total_grams: float      # load-cell grams delivered since power-on
    resolution_g: float
    run_tag: int = 0        # tag of the run in progress, 0 when the auger is idle
    estop: bool = False     # the device's e-stop latch is set: it refuses START and GATE_OPEN

    def fate(self, tag: int) -> Literal["running", "done", "not_started"]:
        """What became of the run ``tag`` (an intent's tag), judged from this snapshot.

        "done": it finished (completed, stopped or jammed) and ``last_grams`` is what it
        delivered. Valid for the latest intent only, which is all a restart has to settle.
        """
        if self.running and self.run_tag == tag:
            return "running"
        return "done" if self.last_tag == tag else "not_started"


class Dispenser(Device):
    kind = "dispenser"

    async def read(self) -> DispenserState:
        return await self._read()

    async def run_auger(self, run_s: float, tag: int) -> None:
        """Start one auger run of ``run_s`` farm seconds, timed by the device itself.

        Returns once the device has accepted (or had already accepted) the run ``tag``;
        follow it with ``read()``. DeviceFault when the auger is jammed or busy."""
        if not 0 < run_s <= 600:
            raise ValueError(f"{self.name}: auger run of {run_s} s is out of range")
        if not 0 < tag < 65536:
            raise ValueError(f"{self.name}: tag {tag} is out of range 1..65535")
        await self._run_auger(run_s, tag)

    async def stop(self) -> None: await self._stop()
    async def set_refill(self, open_gate: bool) -> None: await self._set_refill(open_gate)
    async def clear_fault(self) -> None: await self._clear_fault()
    async def reset_estop(self) -> None: await self._reset_estop()

    def trip_estop(self) -> DispenserState:
        """Set the e-stop latch now and read the state back (``estop`` True: confirmed). Blocks
        the calling thread for at most about ``estop_timeout_s``; DeviceError when unreachable."""
        return self._trip_estop()

    @abc.abstractmethod
    async def _read(self) -> DispenserState: ...
    @abc.abstractmethod
    async def _run_auger(self, run_s: float, tag: int) -> None: ...
    @abc.abstractmethod
    async def _stop(self) -> None: ...
    @abc.abstractmethod
    async def _set_refill(self, open_gate: bool) -> None: ...
    @abc.abstractmethod
    async def _clear_fault(self) -> None: ...
    @abc.abstractmethod
    async def _reset_estop(self) -> None: ...
    @abc.abstractmethod
    def _trip_estop(self) -> DispenserState: ...


BACKENDS = {
    "modbus": "devices.dispenser.modbus_dispenser:ModbusDispenser",
}
